"""The PPO learner on the debug config: what a rollout stores, the bootstrap of truncated episodes, the normaliser
and the value after the rollout, the clip weights, the policy."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

from common.character.humanoid import Humanoid
from common.config import load_config
from common.motion.dataset import load_motions
from common.sim.collect import FrameSource, LocalCollector
from ppo.actor import pd_targets
from ppo.config import PPOTrackerConfig
from ppo.learner import PPOLearner

DEBUG = Path(__file__).resolve().parents[2] / "configs" / "ppo" / "debug.yaml"


@pytest.fixture(scope="module")
def learner() -> Iterator[PPOLearner]:
    # Episodes of at most 5 steps so that a rollout of 8 steps holds truncated episodes.
    cfg = load_config(PPOTrackerConfig, DEBUG, ["gym.termination.max_episode_frames=5"])
    humanoid = Humanoid(cfg.gym.physics)
    torch.manual_seed(0)
    out = PPOLearner(cfg, load_motions(["walk"], humanoid), humanoid, np.random.default_rng(0))
    yield out
    out.close()


def _source(learner: PPOLearner) -> FrameSource:
    """The in-process collector's gym and actor."""
    assert isinstance(learner.collector, LocalCollector)  # collect.processes = 0 in the debug config
    return learner.collector.source


def test_zero_action_follows_the_reference(learner: PPOLearner) -> None:
    reference = _source(learner).res.ref_next.qpos[:, learner.hinge_qpos]
    network = learner.config.network
    np.testing.assert_array_equal(pd_targets(reference, np.zeros_like(reference), network), reference)
    # action_scale 0.5 rad per unit, clipped at 4 units
    np.testing.assert_allclose(pd_targets(reference, np.full_like(reference, 9.0), network) - reference, 2.0)


def test_rollout_rows_and_truncated_bootstrap(learner: PPOLearner) -> None:
    source = _source(learner)
    first_ids = source.res.episode_id.copy()
    weights = learner.motion_weights.weights()
    assert learner.collect() == 8 * 8
    data = learner.buffer.latest(8)
    assert data["obs"].shape == (8, 8, learner.obs_size) and data["action"].shape == (8, 8, 28)
    np.testing.assert_array_equal(data["episode_id"][0], first_ids)  # row t: the episode the step started in
    truncated = data["truncated"]
    assert truncated.any(), "episodes of 5 steps must be truncated within 8 steps"
    assert np.all(data["bootstrap_value"][truncated] != 0.0) and np.all(data["bootstrap_value"][~truncated] == 0.0)
    # The stored log-probabilities are those of the stored actions under the policy that acted.
    with torch.no_grad():
        log_prob, _, _ = learner.net.evaluate(torch.as_tensor(data["obs"][-1]), torch.as_tensor(data["action"][-1]))
    np.testing.assert_allclose(log_prob.numpy(), data["log_prob"][-1], rtol=1e-5)
    np.testing.assert_array_equal(source.gym.clip_weights, weights)  # the weights sent with the rollout


def test_the_normaliser_and_the_value_after_the_rollout_are_the_actors(learner: PPOLearner) -> None:
    source = _source(learner)
    count = learner.normalizer.count
    learner.collect()
    # The learner merged the actor's per-step statistics: bit for bit the actor's own copy, 64 samples more.
    actor = source.actor.normalizer
    assert learner.normalizer.count == actor.count == count + 64
    assert np.array_equal(learner.normalizer.mean, actor.mean) and np.array_equal(learner.normalizer.var, actor.var)
    # GAE's value after the rollout: V of the state the gym is in now, under the statistics of the rollout's end.
    norm_obs = torch.as_tensor(learner.normalizer.normalize(learner.observe(source.res)))
    with torch.no_grad():
        np.testing.assert_array_equal(learner.last_value, learner.net.value(norm_obs).double().numpy())


def test_deterministic_policy_is_a_frozen_snapshot(learner: PPOLearner) -> None:
    policy = learner.policy()
    result = _source(learner).res
    targets = policy(result)
    count = learner.normalizer.count
    learner.collect()  # more statistics and a new state do not change the snapshot
    assert learner.normalizer.count == count + 64
    np.testing.assert_array_equal(policy(result), targets)
    # Near the reference: the last layer starts small, so the mean offset is tiny.
    reference = result.ref_next.qpos[:, learner.hinge_qpos]
    assert np.abs(targets - reference).max() < 0.05
    assert learner.observe(result).shape == (8, learner.obs_size)


def test_adaptive_schedule_moves_both_rates_by_the_measured_kl() -> None:
    # An actor rate far too high for desired_kl 1e-6: every minibatch after the first overshoots, so the rates fall by
    # 1.5 per minibatch step after the first of the update, the critic's keeping its ratio of 10.
    cfg = load_config(PPOTrackerConfig, DEBUG, ["ppo.schedule=adaptive", "ppo.desired_kl=1e-6", "ppo.actor_lr=1e-2",
                                                "ppo.critic_lr=1e-1"])  # fmt: skip
    humanoid = Humanoid(cfg.gym.physics)
    torch.manual_seed(0)
    learner = PPOLearner(cfg, load_motions(["walk"], humanoid), humanoid, np.random.default_rng(0))
    try:
        learner.collect()
        out = learner.update()
    finally:
        learner.close()
    steps = int(out["losses/steps"])
    assert steps == cfg.ppo.epochs * (cfg.ppo.rollout_length * cfg.gym.num_envs // cfg.ppo.minibatch_size) > 1
    assert out["losses/kl"] > 2e-6
    assert out["charts/learning_rate"] == pytest.approx(1e-2 / 1.5 ** (steps - 1))
    groups = learner.optimizer.param_groups
    assert groups[1]["lr"] == pytest.approx(10 * groups[0]["lr"])


def test_fixed_schedule_keeps_the_rates_and_logs_the_kl(learner: PPOLearner) -> None:
    learner.collect()
    out = learner.update()
    assert out["charts/learning_rate"] == learner.config.ppo.actor_lr
    assert out["losses/kl"] > 0.0 and np.isfinite(out["losses/approx_kl"])
