"""The gymnasium VectorEnv wrapper (skipped when gymnasium is not installed)."""

from __future__ import annotations

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

from common.character.humanoid import Humanoid  # noqa: E402
from common.motion.dataset import load_motions  # noqa: E402
from common.sim.gym import GymConfig  # noqa: E402
from common.sim.gym_wrapper import TrackingVectorEnv  # noqa: E402
from common.sim.observation import ObservationConfig, Observer  # noqa: E402
from common.sim.rewards import TerminationConfig  # noqa: E402

# parc: 6 simulated features (15 x (3 + 6 + 3 + 3) + 28 + 28 = 281), per future frame 15 x (3 + 6) + 28 = 163, and
# the first frame's velocity errors 15 x 6 + 28 = 118: 281 + 5 x 163 + 118 = 1,214. local: 2 x 243 + 3 + 6 + 2 = 497.
PARC_SIZE, LOCAL_SIZE = 1214, 497


@pytest.mark.parametrize(("kind", "size"), [("local", LOCAL_SIZE), ("parc", PARC_SIZE)])
def test_vector_env_api(kind: str, size: int) -> None:
    lib = load_motions(["walk"], Humanoid())
    env = TrackingVectorEnv(GymConfig(num_envs=3, threads=1, termination=TerminationConfig(max_episode_frames=4)), lib,
                            observation=ObservationConfig(kind=kind))  # fmt: skip
    obs, info = env.reset(seed=1)
    assert obs.shape == (3, size) and env.observation_space.shape == (3, size)
    assert env.action_space.shape == (3, 28)
    assert env.single_observation_space.contains(obs[0])
    truncated_seen = False
    for _ in range(4):
        obs, reward, terminated, truncated, infos = env.step(np.zeros((3, 28)))
        assert obs.shape == (3, size) and reward.shape == (3,) and np.isfinite(obs).all()
        assert infos["final_obs"].shape == (3, size)
        truncated_seen |= bool(truncated.any())
    # Same-step autoreset: after the 4-frame limit the returned observation starts a new episode.
    assert truncated_seen
    assert not np.array_equal(obs, infos["final_obs"])
    env.close()


def test_default_observation_is_the_ppo_trackers() -> None:
    humanoid = Humanoid()
    lib = load_motions(["walk", "run"], humanoid)
    env = TrackingVectorEnv(GymConfig(num_envs=4, threads=1), lib)
    observe = Observer(ObservationConfig(), humanoid, lib)
    obs, _ = env.reset(seed=3)
    np.testing.assert_array_equal(obs, observe(env._last))  # the gym's result the observation was made from
    obs, *_ = env.step(np.zeros((4, 28)))
    np.testing.assert_array_equal(obs, observe(env._last))
    assert obs.shape == (4, PARC_SIZE)
    env.close()
