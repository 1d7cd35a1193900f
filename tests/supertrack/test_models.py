"""Tests of the networks and rollouts: W fits a fixed batch; the policy loss trains the policy, not W."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from common.character.humanoid import Humanoid, hinges_to_joint_rotations
from common.maths import torch_rotations as R
from common.motion.dataset import load_motions
from common.motion.library import MotionLibrary
from common.sim.gym import GymConfig, TrackingGym
from supertrack.config import PolicyLossWeights, WorldLossWeights
from supertrack.losses import policy_loss, world_model_loss
from supertrack.models import ROOT_OFFSET_POS_SCALE, Policy, WorldModel, root_offset_features
from supertrack.normalizer import acceleration_normalizer, local_normalizer, target_normalizer
from supertrack.rollout import compile_steps, policy_rollout, world_model_rollout
from supertrack.state import BodyState, pack_character_state, target_rotations


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


@pytest.fixture(scope="module")
def library(humanoid: Humanoid) -> MotionLibrary:
    return load_motions(["walk"], humanoid)


def _networks(humanoid: Humanoid, library: MotionLibrary, hidden: tuple[int, ...]) -> tuple[WorldModel, Policy]:
    torch.manual_seed(0)
    local_norm = local_normalizer(library, 0.05)
    revolute = torch.tensor([g.kind == "revolute" for g in humanoid.joint_groups])
    world_model = WorldModel(humanoid.num_bodies, revolute, hidden, local_norm,
                             target_normalizer(library, humanoid, 0.05), acceleration_normalizer(library, 1.0),
                             humanoid.physics.control_dt)  # fmt: skip
    return world_model, Policy(len(humanoid.joint_groups), hidden, local_norm, init_scale=0.01)


@pytest.fixture(scope="module")
def windows(humanoid: Humanoid, library: MotionLibrary) -> dict[str, torch.Tensor]:
    """4 windows of 8 simulated frames, the gym following the reference: sim (4, 8, N, 13), targets (4, 8, J, 4)."""
    gym = TrackingGym(GymConfig(num_envs=4, threads=1, seed=3), library, humanoid)
    res = gym.reset()
    sim, kin_next, targets = [], [], []
    for _ in range(8):
        sim.append(pack_character_state(res.sim))
        kin_next.append(pack_character_state(res.ref_next))
        targets.append(hinges_to_joint_rotations(humanoid, res.ref_next.qpos).astype(np.float32))
        res = gym.step(gym.reference_targets())
    gym.close()
    return {k: torch.as_tensor(np.stack(v, axis=1)) for k, v in
            (("sim", sim), ("kin_next", kin_next), ("target_rot", targets))}  # fmt: skip


def test_world_model_overfits_a_fixed_batch(humanoid: Humanoid, library: MotionLibrary,
                                            windows: dict[str, torch.Tensor]) -> None:  # fmt: skip
    world_model, _ = _networks(humanoid, library, (64, 64))
    # 4 windows of 4 frames: 12 predicted frames to fit.
    sim = BodyState.unpack(windows["sim"][:, :4])
    optimizer = torch.optim.Adam(world_model.parameters(), lr=3e-3)
    weights = WorldLossWeights()
    losses = []
    for _ in range(80):
        predicted = world_model_rollout(world_model, sim, windows["target_rot"][:, :4])
        loss, _ = world_model_loss(predicted, sim.map(lambda x: x[:, 1:]), weights)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    # An untrained W starts near the mean reference acceleration; 80 steps cut the loss by over 3x (4x measured).
    assert losses[-1] < 0.3 * losses[0], f"W did not fit 12 frames: loss {losses[0]:.3g} -> {losses[-1]:.3g}"


def test_policy_loss_trains_the_policy_through_a_frozen_world_model(
    humanoid: Humanoid, library: MotionLibrary, windows: dict[str, torch.Tensor]
) -> None:
    world_model, policy = _networks(humanoid, library, (32,))
    sim = BodyState.unpack(windows["sim"])
    kin_next = BodyState.unpack(windows["kin_next"])
    kin_rot = windows["target_rot"]
    inputs = [t.clone() for t in (windows["sim"], windows["kin_next"], kin_rot)]
    rollout = policy_rollout(policy, world_model, sim.time(0), kin_next, kin_rot, torch.zeros(4, 8, 12, 3), alpha=2.0)
    # Without the offset regularisers the loss reaches the policy only through W's predictions.
    loss, _ = policy_loss(rollout.predicted, kin_next, rollout.offsets, PolicyLossWeights(offset_l1=0, offset_l2=0))
    loss.backward()
    policy_grads = [p.grad for p in policy.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in policy_grads)
    assert sum(float(g.abs().sum()) for g in policy_grads) > 0.0
    assert all(p.grad is None for p in world_model.parameters())
    assert all(p.requires_grad for p in world_model.parameters()), "W must be trainable again after the rollout"
    for before, after in zip(inputs, (windows["sim"], windows["kin_next"], kin_rot), strict=True):
        assert torch.equal(before, after)


def test_policy_rollout_first_step_by_hand(humanoid: Humanoid, library: MotionLibrary,
                                           windows: dict[str, torch.Tensor]) -> None:  # fmt: skip
    world_model, policy = _networks(humanoid, library, (16,))
    sim0 = BodyState.unpack(windows["sim"]).time(0)
    kin_next = BodyState.unpack(windows["kin_next"])
    kin_rot = windows["target_rot"]
    noise = 0.1 * torch.randn(4, 8, 12, 3)
    with torch.no_grad():
        rollout = policy_rollout(policy, world_model, sim0, kin_next, kin_rot, noise, alpha=2.0)
        # P_1 = W(S_0, quat_from_rotvec(alpha (o_0 + noise_0)) * k_1) with o_0 = Pi(S_0, K_1).
        offsets = policy(sim0, kin_next.time(0))
        first = world_model(sim0, target_rotations(offsets + noise[:, 0], kin_rot[:, 0], 2.0))
    assert rollout.predicted.pos.shape == (4, 8, 15, 3) and rollout.offsets.shape == (4, 8, 12, 3)
    torch.testing.assert_close(rollout.offsets[:, 0], offsets)
    torch.testing.assert_close(rollout.predicted.time(0).pos, first.pos)
    torch.testing.assert_close(rollout.predicted.time(0).rot, first.rot)


def test_normalizers_from_the_motion_dataset(humanoid: Humanoid, library: MotionLibrary) -> None:
    local_norm = local_normalizer(library, 0.05)
    assert local_norm.size == 243 and bool((local_norm.std >= 0.05).all())
    assert target_normalizer(library, humanoid, 0.05).size == 72
    assert acceleration_normalizer(library, 1.0).size == 90
    x = torch.randn(3, 243)
    torch.testing.assert_close(local_norm.denormalize(local_norm.normalize(x)), x)
    # Saved in the state dict of any network holding it, so a checkpoint carries it.
    assert "local_norm.mean" in Policy(12, (8,), local_norm, 0.01).state_dict()


def _yaw(angle: float) -> torch.Tensor:
    return torch.tensor([math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)])


def test_root_offset_features_by_hand_and_invariant_to_world_shift_and_yaw(
    windows: dict[str, torch.Tensor],
) -> None:
    sim = BodyState.unpack(windows["sim"][:, 0])
    torch.testing.assert_close(root_offset_features(sim, sim), torch.zeros(4, 9), atol=1e-6, rtol=0)
    # A root at the origin facing +y (yaw 90 deg); the reference root 0.5 m along world +x = its right (-y local),
    # and turned a further 90 deg: local two-axis columns (0, 1, 0) and (-1, 0, 0).
    pos, rot = torch.zeros(1, 2, 3), torch.zeros(1, 2, 4)
    pos[..., 2] = 0.9
    rot[:, :] = _yaw(math.pi / 2)
    s = BodyState(pos, rot, torch.zeros(1, 2, 3), torch.zeros(1, 2, 3))
    k = BodyState(pos.clone(), rot.clone(), torch.zeros(1, 2, 3), torch.zeros(1, 2, 3))
    k.pos[:, 0, 0] = 0.5
    k.rot[:, 0] = _yaw(math.pi)
    expected = torch.tensor([[0.0, -0.5 / ROOT_OFFSET_POS_SCALE, 0.0, -1.0, 1.0, 0.0, -1.0, -1.0, 0.0]])
    torch.testing.assert_close(root_offset_features(s, k), expected, atol=1e-6, rtol=0)
    # Moving and turning the world under both characters changes nothing.
    kin = BodyState.unpack(windows["kin_next"][:, 0])
    q = _yaw(0.7).expand(4, 15, 4)
    shift = torch.tensor([3.0, -1.0, 0.0])

    def moved(x: BodyState) -> BodyState:
        return BodyState(R.quat_rotate(q, x.pos) + shift, R.quat_mul(q, x.rot), x.vel, x.angvel)

    torch.testing.assert_close(root_offset_features(moved(sim), moved(kin)), root_offset_features(sim, kin),
                               atol=1e-5, rtol=0)  # fmt: skip


def test_traced_rollout_steps_match_the_plain_ones(humanoid: Humanoid, library: MotionLibrary,
                                                   windows: dict[str, torch.Tensor]) -> None:  # fmt: skip
    """torch.compile's graph capture (eager backend: no C++ compiler needed) gives the plain rollout's numbers."""
    world_model, _ = _networks(humanoid, library, (16,))
    policy = Policy(len(humanoid.joint_groups), (16,), world_model.local_norm, 0.01, root_offset=True)
    sim = BodyState.unpack(windows["sim"])
    kin_next = BodyState.unpack(windows["kin_next"])
    noise = 0.1 * torch.randn(4, 8, 12, 3, generator=torch.Generator().manual_seed(0))
    traced = compile_steps(backend="eager")
    results = []
    for steps in (None, traced):
        policy.zero_grad()
        rollout = policy_rollout(policy, world_model, sim.time(0), kin_next, windows["target_rot"], noise, 2.0, steps)
        loss, _ = policy_loss(rollout.predicted, kin_next, rollout.offsets, PolicyLossWeights(root_pos=1.0))
        loss.backward()
        grads = torch.cat([p.grad.flatten() for p in policy.parameters()])
        predicted = world_model_rollout(world_model, sim, windows["target_rot"], steps)
        results.append((loss.detach(), grads, predicted.pos.detach()))
    for plain, compiled in zip(*results, strict=True):
        torch.testing.assert_close(compiled, plain)


def test_revolute_joints_get_a_hinge_offset_only(humanoid: Humanoid, library: MotionLibrary,
                                                 windows: dict[str, torch.Tensor]) -> None:  # fmt: skip
    world_model, _ = _networks(humanoid, library, (16,))
    revolute = torch.tensor([g.kind == "revolute" for g in humanoid.joint_groups])
    policy = Policy(len(humanoid.joint_groups), (16,), world_model.local_norm, 1.0, revolute=revolute)
    sim, kin = BodyState.unpack(windows["sim"][:, 0]), BodyState.unpack(windows["kin_next"][:, 0])
    offsets = policy(sim, kin)
    assert bool((offsets[:, revolute][..., [0, 2]] == 0).all()) and bool((offsets[:, revolute][..., 1] != 0).all())
    assert bool((offsets[:, ~revolute] != 0).all())
    # A knee's target is then its reference hinge angle plus alpha * o_y: a pure +y rotation, as the hinge applies.
    noise = torch.randn(4, 12, 3) * policy.dof_mask
    target = target_rotations(offsets + noise, windows["target_rot"][:, 0], 2.0)[:, revolute]
    torch.testing.assert_close(target[..., [1, 3]], torch.zeros_like(target[..., [1, 3]]), atol=1e-6, rtol=0)
    ref = windows["target_rot"][:, 0][:, revolute]
    angle = 2 * torch.atan2(target[..., 2], target[..., 0])
    expected = 2 * torch.atan2(ref[..., 2], ref[..., 0]) + 2.0 * (offsets + noise)[:, revolute][..., 1]
    torch.testing.assert_close(torch.remainder(angle - expected + math.pi, 2 * math.pi) - math.pi,
                               torch.zeros_like(angle), atol=1e-5, rtol=0)  # fmt: skip
    # Not part of the state dict: checkpoints from before the mask still load.
    assert "dof_mask" not in policy.state_dict()
