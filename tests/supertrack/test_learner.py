"""Tests of the learner on the debug preset: frame alignment in the buffer, the W-only start, NaN recovery."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

from common.buffer import CyclicBuffer
from common.config import load_config
from common.humanoid import Humanoid, hinges_to_joint_rotations
from common.motion_dataset import load_motions
from supertrack.config import SuperTrackConfig
from supertrack.learner import SuperTrackLearner, buffer_fields
from supertrack.state import pack_character_state

DEBUG = str(Path(__file__).resolve().parents[2] / "configs" / "supertrack" / "debug.yaml")


@pytest.fixture()
def learner() -> Iterator[SuperTrackLearner]:
    cfg = load_config(SuperTrackConfig, DEBUG)
    humanoid = Humanoid(cfg.gym.physics)
    torch.manual_seed(0)
    built = SuperTrackLearner(cfg, humanoid, load_motions(["walk"], humanoid), np.random.default_rng(0))
    yield built
    built.close()


def test_a_frame_holds_the_state_the_targets_and_the_reference_they_aim_for(learner: SuperTrackLearner) -> None:
    learner.collect()
    prev = learner.collector.source.res
    learner.collect()
    n = learner.cfg.train_envs
    row = {k: v[-1] for k, v in learner.train_buffer.latest(1).items()}
    np.testing.assert_array_equal(row["sim"], pack_character_state(prev.sim)[:n])
    np.testing.assert_array_equal(row["kin_next"], pack_character_state(prev.ref_next)[:n])
    np.testing.assert_array_equal(row["episode_id"], prev.episode_id[:n])
    kin_rot = hinges_to_joint_rotations(learner.humanoid, prev.ref_next.qpos[:n])
    np.testing.assert_allclose(row["kin_next_joint_rot"], kin_rot, atol=1e-6)
    # The untrained policy's offsets are tiny: T_i is k_{i+1} turned by the exploration noise only.
    angle = 2 * np.arccos(np.clip(np.abs(np.sum(row["target_rot"] * kin_rot, axis=-1)), 0, 1))
    noise = math.radians(learner.cfg.policy.alpha_deg) * learner.cfg.policy.sigma
    assert 0.1 * noise < np.median(angle) < 5 * noise
    # The next frame starts with the state this step reached (S_{i+1}; a reset state where the episode ended).
    now = learner.collector.source.res
    learner.collect()
    np.testing.assert_array_equal(learner.train_buffer.latest(1)["sim"][-1], pack_character_state(now.sim)[:n])


def test_policy_steps_start_after_the_world_model_only_iterations(learner: SuperTrackLearner) -> None:
    assert learner.cfg.policy.start_iteration == 1
    learner.collect()
    first = learner.update()
    learner.collect()
    second = learner.update()
    assert "losses/world_model" in first and "losses/policy" not in first
    assert "losses/policy" in second


def test_buffer_state_round_trip_samples_the_same_windows(learner: SuperTrackLearner) -> None:
    learner.collect()
    copy = CyclicBuffer(learner.train_buffer.capacity, learner.cfg.train_envs, buffer_fields(15, 12))
    copy.load_state_dict(learner.train_buffer.state_dict())
    a = learner.train_buffer.sample_windows(5, 8, np.random.default_rng(4))
    b = copy.sample_windows(5, 8, np.random.default_rng(4))
    for name in learner.train_buffer.fields:
        np.testing.assert_array_equal(a[name], b[name])
    assert copy.total_pushed == learner.train_buffer.total_pushed


def test_nan_loss_restores_the_last_good_weights_and_training_continues(
    learner: SuperTrackLearner, capsys: pytest.CaptureFixture
) -> None:
    learner.collect()
    good = {k: v.clone() for k, v in learner.world_model.state_dict().items()}
    with torch.no_grad():
        next(learner.world_model.parameters()).fill_(math.nan)
    metrics = learner.update()
    assert not math.isfinite(metrics["losses/world_model"])
    assert "non-finite loss ['world_model'" in capsys.readouterr().err
    for name, value in learner.world_model.state_dict().items():
        assert torch.equal(value, good[name])
    learner.collect()
    assert math.isfinite(learner.update()["losses/world_model"])


def test_the_evaluated_policy_is_the_weight_average_of_the_live_one(learner: SuperTrackLearner) -> None:
    decay = learner.cfg.policy.average_decay
    assert decay == 0.5 and learner.policy_average is not None
    expected = {k: v.clone() for k, v in learner.policy_net.named_parameters()}
    for _ in range(4):
        learner.collect()
        learner.update()
        # The recursion by hand: avg <- decay * avg + (1 - decay) * live, after every policy step (not the W-only one).
        if learner.updates > learner.cfg.policy.start_iteration:
            live = dict(learner.policy_net.named_parameters())
            expected = {k: decay * expected[k] + (1 - decay) * v.detach() for k, v in live.items()}
    for k, v in learner.policy_average.module.named_parameters():
        torch.testing.assert_close(v, expected[k])
    live_out = learner.actor.deterministic(learner.collector.source.res)
    avg_out = learner.eval_actor.deterministic(learner.collector.source.res)
    assert not np.allclose(live_out, avg_out)
    np.testing.assert_array_equal(learner.policy()(learner.collector.source.res), avg_out)
