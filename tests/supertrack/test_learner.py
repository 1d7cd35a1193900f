"""Tests of the learner on the debug preset: frame alignment in the buffer, the W-only start, NaN recovery."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

from common.character.humanoid import Humanoid, hinges_to_joint_rotations
from common.config import load_config
from common.motion.dataset import load_motions
from common.sim.buffer import CyclicBuffer
from supertrack.config import SuperTrackConfig
from supertrack.learner import SuperTrackLearner, buffer_fields
from supertrack.rollout import make_steps
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


def test_bf16_and_float32_losses_on_one_batch_agree_within_bf16_rounding(learner: SuperTrackLearner) -> None:
    """bf16 keeps 8 mantissa bits: each rounding is a relative error of at most 2^-9, and a network output carries a
    few of them (inputs, weights, each layer's result), so about 2^-8. Every loss term is a mean of absolute errors
    over thousands of values whose rounding errors are independent and partly cancel; bounding each term by a
    relative 2^-8, the error of a single rounding of the term itself, is therefore loose but not vacuous (measured
    here: 2e-5 to 8e-4, the largest on the offset terms, which read the network's output directly)."""
    learner.collect()
    windows = learner.train_buffer.sample_windows(16, 8, np.random.default_rng(1))
    noise = 0.1 * torch.randn(16, 8, 12, 3, generator=torch.Generator().manual_seed(2))
    terms = {}
    for name, steps in (("fp32", make_steps()), ("bf16", make_steps(bf16_world=True, bf16_policy=True)),
                        ("bf16 traced", make_steps(True, True, True, True, backend="eager"))):  # fmt: skip
        learner.steps = steps
        (w_loss, w_terms), (p_loss, p_terms) = learner.world_model_loss(windows), learner.policy_loss(windows, noise)
        assert w_loss.dtype == p_loss.dtype == torch.float32
        terms[name] = {k: float(v) for k, v in {**w_terms, **p_terms}.items()}
    assert len(terms["fp32"]) == 18  # 4 world-model terms + loss, 12 policy terms + loss
    for k, exact in terms["fp32"].items():
        assert terms["bf16"][k] == pytest.approx(exact, rel=2**-8, abs=0), k
        assert terms["bf16 traced"][k] == pytest.approx(terms["bf16"][k], rel=1e-6), k  # graph capture: same numbers
    assert terms["bf16"] != terms["fp32"]  # the networks did run in bf16


def test_the_warm_up_compiles_every_graph_training_uses_and_leaves_the_state_alone() -> None:
    cfg = load_config(SuperTrackConfig, DEBUG, ["world_model.compile=true", "policy.compile=true",
                                                "policy.start_iteration=0"])  # fmt: skip
    humanoid = Humanoid(cfg.gym.physics)
    torch.manual_seed(0)
    learner = SuperTrackLearner(cfg, humanoid, load_motions(["walk"], humanoid), np.random.default_rng(0))
    try:
        learner.steps = make_steps(True, True, backend="eager")  # graph capture without code generation: fast
        weights = {k: v.clone() for k, v in learner.world_model.state_dict().items()}
        torch_rng, numpy_rng = torch.get_rng_state(), learner.rng.bit_generator.state
        torch._dynamo.reset()
        learner.warm_up()
        captured = torch._dynamo.utils.counters["frames"]["ok"]
        assert captured >= 2  # both step functions
        assert torch.equal(torch.get_rng_state(), torch_rng) and learner.rng.bit_generator.state == numpy_rng
        assert all(p.grad is None for p in [*learner.world_model.parameters(), *learner.policy_net.parameters()])
        for k, v in learner.world_model.state_dict().items():
            assert torch.equal(v, weights[k])
        for _ in range(2):
            learner.collect()
            metrics = learner.update()
        assert "losses/policy" in metrics
        assert torch._dynamo.utils.counters["frames"]["ok"] == captured  # training recompiled nothing
    finally:
        learner.close()
