"""Tests of supertrack.losses with hand-computed numbers."""

from __future__ import annotations

import math

import pytest
import torch

from supertrack.config import PolicyLossWeights, WorldLossWeights
from supertrack.losses import POLICY_TERMS, policy_loss, rotation_error, step_weights, world_model_loss
from supertrack.state import BodyState


def _still(batch: int = 1, time: int = 1, bodies: int = 2) -> BodyState:
    """Upright bodies at rest, 1 m apart on x, at 1 m height."""
    pos = torch.zeros(batch, time, bodies, 3, dtype=torch.float64)
    pos[..., 0] = torch.arange(bodies, dtype=torch.float64)
    pos[..., 2] = 1.0
    rot = torch.zeros(batch, time, bodies, 4, dtype=torch.float64)
    rot[..., 0] = 1.0
    zeros = torch.zeros(batch, time, bodies, 3, dtype=torch.float64)
    return BodyState(pos=pos, rot=rot, vel=zeros, angvel=zeros.clone())


def test_rotation_error_is_the_log_and_sign_invariant() -> None:
    a = torch.tensor([math.cos(0.15), 0.0, 0.0, math.sin(0.15)], dtype=torch.float64)
    one = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    torch.testing.assert_close(rotation_error(a, one), torch.tensor([0.0, 0.0, 0.3], dtype=torch.float64))
    torch.testing.assert_close(rotation_error(-a, one), torch.tensor([0.0, 0.0, 0.3], dtype=torch.float64))
    torch.testing.assert_close(rotation_error(a, a), torch.zeros(3, dtype=torch.float64))


def test_world_model_loss_by_hand() -> None:
    true = _still()
    pred = _still()
    pred.pos = pred.pos.clone()
    pred.pos[0, 0, 1, 2] += 0.6  # one of 6 position components off by 0.6 -> mean 0.1
    pred.vel = pred.vel + torch.tensor([0.3, 0.0, 0.0], dtype=torch.float64)  # 2 of 6 off by 0.3 -> mean 0.1
    pred.rot = pred.rot.clone()
    pred.rot[0, 0, 0] = torch.tensor([math.cos(0.3), math.sin(0.3), 0.0, 0.0])  # 0.6 rad about x -> mean 0.1
    weights = WorldLossWeights(pos=1.0, vel=2.0, rot=3.0, angvel=4.0)
    loss, metrics = world_model_loss(pred, true, weights)
    assert metrics["losses/world_model_pos"].item() == pytest.approx(0.1)
    assert metrics["losses/world_model_vel"].item() == pytest.approx(0.1)
    assert metrics["losses/world_model_rot"].item() == pytest.approx(0.1)
    assert metrics["losses/world_model_angvel"].item() == 0.0
    assert loss.item() == pytest.approx(0.1 * 1.0 + 0.1 * 2.0 + 0.1 * 3.0)
    assert metrics["losses/world_model"].item() == pytest.approx(loss.item())


def test_policy_loss_is_zero_on_the_reference_and_regularises_offsets() -> None:
    kin = _still(bodies=3)
    offsets = torch.zeros(1, 1, 12, 3, dtype=torch.float64)
    offsets[0, 0, 0] = torch.tensor([0.3, -0.6, 0.0])  # mean |o| = 0.9 / 36 = 0.025, mean o^2 = 0.45 / 36
    weights = PolicyLossWeights(offset_l1=2.0, offset_l2=4.0)
    loss, metrics = policy_loss(kin, kin, offsets, weights)
    for term in POLICY_TERMS:
        assert metrics[f"losses/policy_{term}"].item() == 0.0
    assert loss.item() == pytest.approx(2.0 * 0.025 + 4.0 * 0.45 / 36)


def test_policy_loss_is_local_a_shift_of_the_whole_character_costs_only_height() -> None:
    kin = _still(bodies=3)
    pred = _still(bodies=3)
    pred.pos = pred.pos + torch.tensor([5.0, -2.0, 0.3], dtype=torch.float64)
    weights = PolicyLossWeights(offset_l1=0.0, offset_l2=0.0)
    loss, metrics = policy_loss(pred, kin, torch.zeros(1, 1, 12, 3, dtype=torch.float64), weights)
    assert metrics["losses/policy_pos"].item() == pytest.approx(0.0, abs=1e-12)
    assert metrics["losses/policy_height"].item() == pytest.approx(0.3)
    assert loss.item() == pytest.approx(weights.height * 0.3)


def test_root_terms_see_the_drift_that_the_local_terms_miss() -> None:
    kin = _still(bodies=3)
    pred = _still(bodies=3)
    pred.pos = pred.pos + torch.tensor([0.5, -0.2, 0.0], dtype=torch.float64)
    # The root turned 0.6 rad about +z: log = (0, 0, 0.6), mean |component| = 0.2.
    pred.rot = pred.rot.clone()
    pred.rot[..., 0, :] = torch.tensor([math.cos(0.3), 0.0, 0.0, math.sin(0.3)], dtype=torch.float64)
    weights = PolicyLossWeights(pos=0, vel=0, rot=0, angvel=0, height=0, up=0, offset_l1=0, offset_l2=0,
                                root_pos=2.0, root_rot=5.0)  # fmt: skip
    loss, metrics = policy_loss(pred, kin, torch.zeros(1, 1, 12, 3, dtype=torch.float64), weights)
    assert metrics["losses/policy_root_pos"].item() == pytest.approx(0.7 / 3)
    assert metrics["losses/policy_root_rot"].item() == pytest.approx(0.2)
    assert loss.item() == pytest.approx(2.0 * 0.7 / 3 + 5.0 * 0.2)
    assert metrics["losses/policy_root_heading"].item() == pytest.approx(0.6)  # all of it a turn about +z


def test_root_heading_is_the_turn_about_vertical_alone() -> None:
    kin = _still(bodies=3)
    weights = PolicyLossWeights(pos=0, vel=0, rot=0, angvel=0, height=0, up=0, offset_l1=0, offset_l2=0,
                                root_heading=10.0)  # fmt: skip
    zeros = torch.zeros(1, 1, 12, 3, dtype=torch.float64)
    tilted, turned = _still(bodies=3), _still(bodies=3)
    tilted.rot, turned.rot = tilted.rot.clone(), turned.rot.clone()
    # 0.4 rad about +x (a lean): no heading error. 0.4 rad about -z: a heading error of 0.4 rad.
    tilted.rot[..., 0, :] = torch.tensor([math.cos(0.2), math.sin(0.2), 0.0, 0.0], dtype=torch.float64)
    turned.rot[..., 0, :] = torch.tensor([math.cos(0.2), 0.0, 0.0, -math.sin(0.2)], dtype=torch.float64)
    loss, metrics = policy_loss(tilted, kin, zeros, weights)
    assert metrics["losses/policy_root_heading"].item() == pytest.approx(0.0, abs=1e-12)
    assert metrics["losses/policy_root_rot"].item() == pytest.approx(0.4 / 3)
    assert loss.item() == pytest.approx(0.0, abs=1e-12)
    loss, metrics = policy_loss(turned, kin, zeros, weights)
    assert metrics["losses/policy_root_heading"].item() == pytest.approx(0.4)
    assert loss.item() == pytest.approx(10.0 * 0.4)


def test_offset_rate_is_the_mean_frame_to_frame_change() -> None:
    kin = _still(time=3, bodies=3)
    offsets = torch.zeros(1, 3, 12, 3, dtype=torch.float64)
    offsets[0, 1, 4] = torch.tensor([0.2, 0.0, -0.4])  # frame 0 -> 1 changes by 0.6 in total, 1 -> 2 by 0.6 back
    weights = PolicyLossWeights(offset_l1=0.0, offset_l2=0.0, offset_rate=3.0)
    loss, metrics = policy_loss(kin, kin, offsets, weights)
    # 2 frame pairs x 12 joints x 3 components = 72 values summing to 1.2
    assert metrics["losses/policy_offset_rate"].item() == pytest.approx(1.2 / 72)
    assert loss.item() == pytest.approx(3.0 * 1.2 / 72)
    # A constant offset has no rate, and one frame has no pair.
    steady = torch.full((1, 3, 12, 3), 0.3, dtype=torch.float64)
    assert policy_loss(kin, kin, steady, weights)[1]["losses/policy_offset_rate"].item() == 0.0
    one = policy_loss(_still(bodies=3), _still(bodies=3), offsets[:, :1], weights)[1]
    assert one["losses/policy_offset_rate"].item() == 0.0


def test_step_decay_weighs_later_rollout_steps_less_and_logs_the_plain_mean() -> None:
    kin = _still(time=2, bodies=3)
    pred = _still(time=2, bodies=3)
    pred.pos = pred.pos.clone()
    pred.pos[0, 1, :, 0] += 0.3  # the whole character 0.3 m along x at step 1: only the world root term sees it
    offsets = torch.zeros(1, 2, 12, 3, dtype=torch.float64)
    weights = PolicyLossWeights(offset_l1=0.0, offset_l2=0.0, root_pos=1.0)
    plain, metrics = policy_loss(pred, kin, offsets, weights)
    # Root position error per step: 0 and 0.3 / 3 = 0.1 (x, y, z components); the plain mean 0.05.
    assert plain.item() == pytest.approx(0.05)
    decayed, decayed_metrics = policy_loss(pred, kin, offsets, weights, step_decay=0.5)
    # Weights 1 and 0.5 scaled to mean 1: 4/3 and 2/3 -> (0 * 4/3 + 0.1 * 2/3) / 2 = 1/30.
    assert decayed.item() == pytest.approx(1.0 / 30.0)
    assert decayed_metrics["losses/policy_root_pos"].item() == pytest.approx(0.05)
    for term in POLICY_TERMS:
        assert decayed_metrics[f"losses/policy_{term}"].item() == pytest.approx(0.0, abs=1e-12)


def test_step_weights_are_powers_scaled_to_mean_one() -> None:
    w = step_weights(3, 0.95, torch.zeros((), dtype=torch.float64))
    scale = 3.0 / (1.0 + 0.95 + 0.95**2)
    torch.testing.assert_close(w, torch.tensor([1.0, 0.95, 0.95**2], dtype=torch.float64) * scale)
    torch.testing.assert_close(step_weights(4, 1.0, w), torch.ones(4, dtype=torch.float64))
