"""Tests of supertrack.state: the integrator against hand-computed steps, packing, target rotations."""

from __future__ import annotations

import math

import numpy as np
import torch

from common.character.humanoid import Humanoid, joint_rotations_to_hinges
from common.character.state import CharacterState
from common.maths.rotations import quat_from_axis_angle
from supertrack.state import (
    STATE_LAYOUT,
    BodyState,
    applied_rotations,
    integrate,
    pack_character_state,
    target_rotations,
)

DT = 0.1
SQRT_HALF = math.sqrt(0.5)


def _z_quat(angle: float) -> list[float]:
    return [math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)]


def _two_bodies() -> BodyState:
    """Body 0 turned 0.2 rad about z, body 1 turned 90 deg about x; shapes (1, 2, k) in float64."""
    return BodyState(
        pos=torch.tensor([[[0.0, 0.0, 1.0], [1.0, 2.0, 3.0]]], dtype=torch.float64),
        rot=torch.tensor([[_z_quat(0.2), [SQRT_HALF, SQRT_HALF, 0.0, 0.0]]], dtype=torch.float64),
        vel=torch.tensor([[[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]], dtype=torch.float64),
        angvel=torch.tensor([[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]], dtype=torch.float64),
    )


def test_integrate_one_step_by_hand() -> None:
    state = _two_bodies()
    lin_acc = torch.tensor([[[0.0, 0.0, -10.0], [0.0, 0.0, 0.0]]], dtype=torch.float64)
    ang_acc = torch.tensor([[[0.0, 0.0, 10.0], [0.0, 0.0, 10.0]]], dtype=torch.float64)
    nxt = integrate(state, lin_acc, ang_acc, DT)
    # v' = v + dt a = (1, 0, -1); x' = x + dt v' (the NEW velocity: semi-implicit) = (0.1, 0, 0.9).
    torch.testing.assert_close(nxt.vel[0, 0], torch.tensor([1.0, 0.0, -1.0], dtype=torch.float64))
    torch.testing.assert_close(nxt.pos[0, 0], torch.tensor([0.1, 0.0, 0.9], dtype=torch.float64))
    torch.testing.assert_close(nxt.pos[0, 1], torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    # w' = (0, 0, 1); q' = quat_from_rotvec(dt w') q: body 0 turns from 0.2 to 0.3 rad about z.
    torch.testing.assert_close(nxt.angvel[0, 0], torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    torch.testing.assert_close(nxt.rot[0, 0], torch.tensor(_z_quat(0.3), dtype=torch.float64))
    # Body 1: Rz(0.1) * Rx(90 deg) = (cz c, cz s, sz s, sz c) with cz, sz = cos, sin 0.05 and c = s = sqrt(1/2).
    cz, sz = math.cos(0.05), math.sin(0.05)
    expected = [cz * SQRT_HALF, cz * SQRT_HALF, sz * SQRT_HALF, sz * SQRT_HALF]
    torch.testing.assert_close(nxt.rot[0, 1], torch.tensor(expected, dtype=torch.float64))


def test_integrate_two_steps_by_hand() -> None:
    state = _two_bodies()
    lin_acc = torch.tensor([[[0.0, 0.0, -10.0], [2.0, 0.0, 0.0]]], dtype=torch.float64)
    ang_acc = torch.zeros(1, 2, 3, dtype=torch.float64)
    p1 = integrate(state, lin_acc, ang_acc, DT)
    p2 = integrate(p1, lin_acc, ang_acc, DT)
    # Body 0: v1 = (1, 0, -1), x1 = (0.1, 0, 0.9); v2 = (1, 0, -2), x2 = (0.2, 0, 0.7).
    torch.testing.assert_close(p2.vel[0, 0], torch.tensor([1.0, 0.0, -2.0], dtype=torch.float64))
    torch.testing.assert_close(p2.pos[0, 0], torch.tensor([0.2, 0.0, 0.7], dtype=torch.float64))
    # Body 1 from rest with a = 2: v1 = 0.2, x1 = 1.02; v2 = 0.4, x2 = 1.06.
    torch.testing.assert_close(p2.pos[0, 1], torch.tensor([1.06, 2.0, 3.0], dtype=torch.float64))
    torch.testing.assert_close(p2.rot, state.rot)


def test_integrate_does_not_modify_inputs() -> None:
    state = _two_bodies()
    before = {name: getattr(state, name).clone() for name, _, _ in STATE_LAYOUT}
    acc = torch.ones(1, 2, 3, dtype=torch.float64)
    integrate(state, acc, acc, DT)
    for name, value in before.items():
        assert torch.equal(getattr(state, name), value)


def test_integrate_gradient_is_finite_at_zero_angular_velocity() -> None:
    state = _two_bodies()
    ang_acc = torch.zeros(1, 2, 3, dtype=torch.float64, requires_grad=True)
    integrate(state, torch.zeros(1, 2, 3, dtype=torch.float64), ang_acc, DT).rot.sum().backward()
    assert torch.isfinite(ang_acc.grad).all()


def test_pack_and_unpack_round_trip() -> None:
    rng = np.random.default_rng(0)
    state = CharacterState(
        qpos=np.zeros((2, 35)), qvel=np.zeros((2, 34)), body_pos=rng.normal(size=(2, 15, 3)),
        body_rot=rng.normal(size=(2, 15, 4)), body_linvel=rng.normal(size=(2, 15, 3)),
        body_angvel=rng.normal(size=(2, 15, 3)),
    )  # fmt: skip
    packed = pack_character_state(state)
    assert packed.shape == (2, 15, 13) and packed.dtype == np.float32
    unpacked = BodyState.unpack(torch.as_tensor(packed))
    for name, src, _ in STATE_LAYOUT:
        np.testing.assert_allclose(getattr(unpacked, name).numpy(), getattr(state, src), rtol=1e-6)


def test_target_rotations_compose_offset_on_the_left() -> None:
    k = torch.tensor([[SQRT_HALF, SQRT_HALF, 0.0, 0.0]], dtype=torch.float64)
    torch.testing.assert_close(target_rotations(torch.zeros(1, 3, dtype=torch.float64), k, 2.0), k)
    # o = (0, 0, 0.05), alpha = 2: a 0.1 rad turn about z applied after k.
    t = target_rotations(torch.tensor([[0.0, 0.0, 0.05]], dtype=torch.float64), k, 2.0)
    cz, sz = math.cos(0.05), math.sin(0.05)
    expected = torch.tensor([[cz * SQRT_HALF, cz * SQRT_HALF, sz * SQRT_HALF, sz * SQRT_HALF]], dtype=torch.float64)
    torch.testing.assert_close(t, expected)


def test_applied_rotations_match_the_gym_hinge_conversion() -> None:
    humanoid = Humanoid()
    revolute = torch.tensor([g.kind == "revolute" for g in humanoid.joint_groups])
    rng = np.random.default_rng(1)
    rot = rng.normal(size=(5, 12, 4))
    rot /= np.linalg.norm(rot, axis=-1, keepdims=True)
    applied = applied_rotations(torch.as_tensor(rot), revolute).numpy()
    hinges = joint_rotations_to_hinges(humanoid, rot, near_qpos=np.zeros((5, humanoid.nq)))
    for j, group in enumerate(humanoid.joint_groups):
        if group.kind == "revolute":
            expected = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), hinges[:, group.actuators[0]])
            # Same rotation up to the quaternion sign.
            np.testing.assert_allclose(np.abs(np.sum(applied[:, j] * expected, axis=-1)), 1.0, atol=1e-9)
        else:
            np.testing.assert_array_equal(applied[:, j], rot[:, j])
