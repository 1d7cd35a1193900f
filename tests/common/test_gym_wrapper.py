"""The gymnasium VectorEnv wrapper (skipped when gymnasium is not installed)."""

from __future__ import annotations

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

from common.character.humanoid import Humanoid  # noqa: E402
from common.motion.dataset import load_motions  # noqa: E402
from common.sim.gym import GymConfig  # noqa: E402
from common.sim.gym_wrapper import TrackingVectorEnv  # noqa: E402
from common.sim.rewards import TerminationConfig  # noqa: E402


def test_vector_env_api() -> None:
    lib = load_motions(["walk"], Humanoid())
    env = TrackingVectorEnv(GymConfig(num_envs=3, threads=1, termination=TerminationConfig(max_episode_frames=4)), lib)
    obs, info = env.reset(seed=1)
    assert obs.shape == (3, 497) and env.observation_space.shape == (3, 497)
    assert env.action_space.shape == (3, 28)
    assert env.single_observation_space.contains(obs[0])
    truncated_seen = False
    for _ in range(4):
        obs, reward, terminated, truncated, infos = env.step(np.zeros((3, 28)))
        assert obs.shape == (3, 497) and reward.shape == (3,) and np.isfinite(obs).all()
        assert infos["final_obs"].shape == (3, 497)
        truncated_seen |= bool(truncated.any())
    # Same-step autoreset: after the 4-frame limit the returned observation starts a new episode.
    assert truncated_seen
    assert not np.array_equal(obs, infos["final_obs"])
    env.close()
