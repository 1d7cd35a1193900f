"""Tests for common.maths.rotations (numpy) and common.maths.torch_rotations (torch)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from common.maths import rotations as rot
from common.maths import torch_rotations as trot

C45 = np.sqrt(0.5)
# 120 degrees about (1, 1, 1): the cyclic permutation x -> y -> z -> x.
Q_CYCLIC = np.array([0.5, 0.5, 0.5, 0.5])
M_CYCLIC = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def random_quats(n: int, seed: int = 0) -> np.ndarray:
    """Uniformly random unit quaternions, shape (n, 4)."""
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def same_rotation(a: np.ndarray, b: np.ndarray, atol: float = 1e-9) -> None:
    np.testing.assert_allclose(rot.quat_geodesic_angle(a, b), 0.0, atol=atol)


# ----------------------------------------------------------------------------------- hand-computed values


def test_rotate_90_about_z() -> None:
    q = rot.quat_from_axis_angle([0.0, 0.0, 2.0], np.pi / 2)  # axis need not be unit
    np.testing.assert_allclose(q, [C45, 0.0, 0.0, C45], atol=1e-15)
    np.testing.assert_allclose(rot.quat_rotate(q, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(rot.quat_rotate(q, [0.0, 1.0, 0.0]), [-1.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(rot.quat_rotate_inv(q, [0.0, 1.0, 0.0]), [1.0, 0.0, 0.0], atol=1e-15)


def test_two_90_about_x_make_180_about_x() -> None:
    qx90 = np.array([C45, C45, 0.0, 0.0])
    np.testing.assert_allclose(rot.quat_mul(qx90, qx90), [0.0, 1.0, 0.0, 0.0], atol=1e-15)
    # Non-commuting factors: 90 about X then 90 about Z differs from the reverse order.
    qz90 = np.array([C45, 0.0, 0.0, C45])
    np.testing.assert_allclose(rot.quat_mul(qz90, qx90), [0.5, 0.5, 0.5, 0.5], atol=1e-15)
    np.testing.assert_allclose(rot.quat_mul(qx90, qz90), [0.5, 0.5, -0.5, 0.5], atol=1e-15)


def test_quat_to_matrix_known() -> None:
    np.testing.assert_allclose(rot.quat_to_matrix(Q_CYCLIC), M_CYCLIC, atol=1e-15)
    rx90 = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    np.testing.assert_allclose(rot.quat_to_matrix([C45, C45, 0.0, 0.0]), rx90, atol=1e-15)
    np.testing.assert_allclose(rot.quat_to_matrix(3.0 * Q_CYCLIC), M_CYCLIC, atol=1e-15)  # non-unit input


def test_two_axis_takes_columns() -> None:
    np.testing.assert_allclose(rot.quat_to_two_axis([C45, 0, 0, C45]), [0, 1, 0, -1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(rot.quat_to_two_axis(Q_CYCLIC), [0, 1, 0, 0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(rot.two_axis_to_matrix([0, 2, 0, -1, 5, 0]), [[0, -1, 0], [1, 0, 0], [0, 0, 1]])


def test_euler_known() -> None:
    np.testing.assert_allclose(rot.euler_xyz_to_quat([np.pi / 2, 0, 0]), [C45, C45, 0, 0], atol=1e-15)
    np.testing.assert_allclose(rot.euler_xyz_to_quat([0, np.pi / 2, 0]), [C45, 0, C45, 0], atol=1e-15)
    # Rx(90) @ Ry(90) is the cyclic permutation matrix.
    np.testing.assert_allclose(rot.euler_xyz_to_quat([np.pi / 2, np.pi / 2, 0]), Q_CYCLIC, atol=1e-15)
    np.testing.assert_allclose(rot.quat_to_euler_xyz([C45, 0, 0, -C45]), [0, 0, -np.pi / 2], atol=1e-15)


def test_y_up_to_z_up() -> None:
    r = np.array([0.7071, 0.7071, 0.0, 0.0])
    np.testing.assert_allclose(rot.quat_rotate(rot.quat_normalize(r), [0, 1, 0]), [0, 0, 1], atol=1e-15)


def test_yaw_of_heading_times_tilt() -> None:
    heading = rot.quat_from_yaw(np.deg2rad(30.0))
    np.testing.assert_allclose(heading, [np.cos(np.pi / 12), 0, 0, np.sin(np.pi / 12)], atol=1e-15)
    tilt = rot.quat_mul(rot.quat_from_axis_angle([0, 1, 0], 0.7), rot.quat_from_axis_angle([1, 0, 0], 0.3))
    np.testing.assert_allclose(rot.quat_yaw(rot.quat_mul(heading, tilt)), np.deg2rad(30.0), atol=1e-14)
    np.testing.assert_allclose(rot.quat_yaw([0.0, 0.0, 0.0, 1.0]), np.pi, atol=1e-15)  # 180 about Z


def test_rotvec_known() -> None:
    np.testing.assert_allclose(rot.quat_from_rotvec([0, 0, np.pi / 2]), [C45, 0, 0, C45], atol=1e-15)
    np.testing.assert_allclose(rot.quat_from_rotvec(np.zeros(3)), [1, 0, 0, 0])
    np.testing.assert_allclose(rot.quat_from_rotvec([2e-4, 0, 0]), [np.cos(1e-4), np.sin(1e-4), 0, 0], rtol=1e-15)
    np.testing.assert_allclose(rot.quat_to_rotvec([-C45, 0, 0, -C45]), [0, 0, np.pi / 2], atol=1e-15)
    # 270 about +Z is 90 about -Z along the shorter path.
    q270 = rot.quat_from_axis_angle([0, 0, 1], 1.5 * np.pi)
    np.testing.assert_allclose(rot.quat_to_rotvec(q270), [0, 0, -np.pi / 2], atol=1e-14)
    tiny = np.array([np.cos(1e-9), 0, np.sin(1e-9), 0])
    np.testing.assert_allclose(rot.quat_to_rotvec(tiny), [0, 2e-9, 0], rtol=1e-15)
    np.testing.assert_allclose(rot.quat_to_rotvec([1, 0, 0, 0]), [0, 0, 0])
    np.testing.assert_allclose(np.linalg.norm(rot.quat_to_rotvec([0.0, 1.0, 0, 0])), np.pi)


def test_geodesic_angle_known() -> None:
    qz90 = np.array([C45, 0, 0, C45])
    np.testing.assert_allclose(rot.quat_geodesic_angle(qz90, [1, 0, 0, 0]), np.pi / 2, atol=1e-15)
    np.testing.assert_allclose(rot.quat_geodesic_angle(qz90, -qz90), 0.0, atol=1e-15)
    np.testing.assert_allclose(rot.quat_geodesic_angle([0, 1.0, 0, 0], [1.0, 0, 0, 0]), np.pi)
    # arccos(1 - 5e-21) would round to 0; the atan2 form keeps the tiny angle.
    near = rot.quat_from_rotvec([1e-10, 0, 0])
    np.testing.assert_allclose(rot.quat_geodesic_angle(near, [1, 0, 0, 0]), 1e-10, rtol=1e-12)


def test_identity_inverse_normalize() -> None:
    assert rot.quat_identity((2, 3)).shape == (2, 3, 4)
    np.testing.assert_array_equal(rot.quat_identity(), [1, 0, 0, 0])
    q = np.array([1.0, 2.0, -2.0, 4.0])  # |q|^2 = 25
    np.testing.assert_allclose(rot.quat_inv(q), [0.04, -0.08, 0.08, -0.16])
    np.testing.assert_allclose(rot.quat_mul(q, rot.quat_inv(q)), [1, 0, 0, 0], atol=1e-15)
    np.testing.assert_allclose(rot.quat_normalize(q), q / 5.0)
    with pytest.raises(ValueError):
        rot.quat_normalize(np.array([[1.0, 0, 0, 0], [0, 0, 0, 0]]))
    with pytest.raises(ValueError):
        rot.quat_from_axis_angle([0.0, 0.0, 0.0], 1.0)


def test_matrix_to_quat_half_turns_and_sign() -> None:
    np.testing.assert_allclose(rot.matrix_to_quat(np.diag([1.0, -1, -1])), [0, 1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(rot.matrix_to_quat(np.diag([-1.0, -1, 1])), [0, 0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(rot.matrix_to_quat(M_CYCLIC), Q_CYCLIC, atol=1e-15)
    assert np.all(rot.matrix_to_quat(rot.quat_to_matrix(random_quats(500)))[:, 0] >= 0.0)


def test_fix_hemisphere() -> None:
    q = np.array([C45, 0, 0, C45])
    seq = np.stack([q, -q, -q, q, -q])
    np.testing.assert_array_equal(rot.quat_fix_hemisphere(seq), np.stack([q] * 5))
    np.testing.assert_array_equal(seq[1], -q)  # input untouched
    batch = np.stack([seq, -seq])  # sequence along axis 1
    np.testing.assert_array_equal(rot.quat_fix_hemisphere(batch, axis=1), np.stack([[q] * 5, [-q] * 5]))
    noisy = random_quats(200, seed=3).reshape(50, 4, 4)
    fixed = rot.quat_fix_hemisphere(noisy)
    assert np.all(np.sum(fixed[1:] * fixed[:-1], axis=-1) >= 0.0)
    np.testing.assert_allclose(np.abs(fixed), np.abs(noisy))


def test_angular_velocity_known() -> None:
    qz90 = rot.quat_from_axis_angle([0, 0, 1], np.pi / 2)
    np.testing.assert_allclose(rot.angular_velocity([1, 0, 0, 0], qz90, 0.5), [0, 0, np.pi], atol=1e-14)
    qz270 = rot.quat_from_axis_angle([0, 0, 1], 1.5 * np.pi)
    np.testing.assert_allclose(rot.angular_velocity(qz90, qz270, 2.0), [0, 0, np.pi / 2], atol=1e-14)
    np.testing.assert_allclose(rot.angular_velocity(qz90, qz90 * -1, 0.1), [0, 0, 0], atol=1e-14)


def test_float32_preserved() -> None:
    q = random_quats(4).astype(np.float32)
    assert rot.quat_mul(q, q).dtype == np.float32
    assert rot.quat_rotate(q, np.ones(3, np.float32)).dtype == np.float32
    assert rot.quat_to_rotvec(q).dtype == np.float32
    assert rot.quat_from_rotvec(np.zeros((2, 3), np.float32)).dtype == np.float32
    assert rot.quat_to_matrix(q).dtype == np.float32
    assert rot.angular_velocity(q, q, 0.1).dtype == np.float32
    assert rot.quat_from_axis_angle(np.ones(3, np.float32), 0.5).dtype == np.float32
    assert rot.quat_to_rotvec([1, 0, 0, 0]).dtype == np.float64  # integer input goes to float64


# ------------------------------------------------------------------------------- round trips on random input


def test_matrix_quat_round_trip() -> None:
    q = random_quats(1000).reshape(10, 100, 4)
    m = rot.quat_to_matrix(q)
    np.testing.assert_allclose(m @ np.swapaxes(m, -1, -2), np.broadcast_to(np.eye(3), m.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(m), 1.0, atol=1e-14)
    back = rot.matrix_to_quat(m)
    np.testing.assert_allclose(back, q * np.sign(q[..., :1]), atol=1e-14)


def test_rotvec_round_trip() -> None:
    rng = np.random.default_rng(1)
    axes = rng.normal(size=(600, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    # Angles spanning tiny (Taylor branch), threshold-adjacent and large, all below pi.
    angles = np.concatenate([10.0 ** rng.uniform(-12, -2, 200), rng.uniform(0.0, 3.1, 400)])
    r = axes * angles[:, None]
    np.testing.assert_allclose(rot.quat_to_rotvec(rot.quat_from_rotvec(r)), r, rtol=1e-12, atol=1e-15)
    q = random_quats(500, seed=2)
    back = rot.quat_from_rotvec(rot.quat_to_rotvec(q))
    np.testing.assert_allclose(back, q * np.sign(q[..., :1]), atol=1e-14)
    assert np.all(np.linalg.norm(rot.quat_to_rotvec(q), axis=-1) <= np.pi)


def test_euler_round_trip() -> None:
    q = random_quats(1000, seed=4)
    e = rot.quat_to_euler_xyz(q)
    assert np.all(np.abs(e[:, 1]) <= np.pi / 2) and np.all(np.abs(e) <= np.pi)
    same_rotation(rot.euler_xyz_to_quat(e), q)
    e_any = np.random.default_rng(5).uniform(-4.0, 4.0, size=(1000, 3))
    same_rotation(
        rot.euler_xyz_to_quat(rot.quat_to_euler_xyz(rot.euler_xyz_to_quat(e_any))),
        rot.euler_xyz_to_quat(e_any),
    )
    # Exactly at gimbal lock only a + c is determined, but the rotation must survive.
    locked = rot.euler_xyz_to_quat(np.array([[0.3, np.pi / 2, 0.2], [0.3, -np.pi / 2, -0.4]]))
    e_locked = rot.quat_to_euler_xyz(locked)
    same_rotation(rot.euler_xyz_to_quat(e_locked), locked)
    np.testing.assert_allclose(e_locked[0, 0] + e_locked[0, 2], 0.5, atol=1e-7)


def test_two_axis_round_trip() -> None:
    q = random_quats(300, seed=6)
    m = rot.two_axis_to_matrix(rot.quat_to_two_axis(q))
    np.testing.assert_allclose(m, rot.quat_to_matrix(q), atol=1e-14)
    # Scaled and skewed input: column 0 keeps its direction, column 1 loses its column-0 part.
    x = rot.quat_to_two_axis(q)
    skewed = np.concatenate([3.0 * x[:, :3], 0.5 * x[:, 3:] + 2.0 * x[:, :3]], axis=-1)
    np.testing.assert_allclose(rot.two_axis_to_matrix(skewed), m, atol=1e-13)


def test_slerp() -> None:
    q0, q1 = random_quats(200, seed=7), random_quats(200, seed=8)
    same_rotation(rot.quat_slerp(q0, q1, 0.0), q0)
    same_rotation(rot.quat_slerp(q0, q1, np.ones(200)), q1)
    full = rot.quat_geodesic_angle(q0, q1)
    mid = rot.quat_slerp(q0, -q1, 0.5)  # sign of q1 must not matter
    np.testing.assert_allclose(rot.quat_geodesic_angle(q0, mid), 0.5 * full, atol=1e-12)
    np.testing.assert_allclose(rot.quat_geodesic_angle(mid, q1), 0.5 * full, atol=1e-12)
    qz = rot.quat_slerp([1, 0, 0, 0], rot.quat_from_yaw(2.0), np.array([0.25, 0.5]))
    np.testing.assert_allclose(rot.quat_yaw(qz), [0.5, 1.0], atol=1e-14)
    nearly = rot.quat_from_rotvec([1e-9, 0, 0])
    np.testing.assert_allclose(rot.quat_slerp([1, 0, 0, 0], nearly, 0.5), rot.quat_from_rotvec([5e-10, 0, 0]))


def test_split_heading_recomposes() -> None:
    q = random_quats(500, seed=9)
    heading, tilt = rot.quat_split_heading(q)
    np.testing.assert_allclose(rot.quat_mul(heading, tilt), q, atol=1e-14)
    np.testing.assert_allclose(rot.quat_yaw(tilt), 0.0, atol=1e-12)
    np.testing.assert_allclose(heading[:, 1:3], 0.0)
    np.testing.assert_allclose(rot.quat_yaw(heading), rot.quat_yaw(q), atol=1e-12)


# ------------------------------------------------------------------------- consistency between functions


def test_rotate_matches_matrix_and_inverse() -> None:
    q = random_quats(400, seed=10).reshape(20, 20, 4)
    v = np.random.default_rng(11).normal(size=(20, 20, 3))
    rotated = rot.quat_rotate(q, v)
    np.testing.assert_allclose(rotated, np.einsum("...ij,...j->...i", rot.quat_to_matrix(q), v), atol=1e-14)
    np.testing.assert_allclose(rot.quat_rotate_inv(q, rotated), v, atol=1e-14)
    # Broadcasting one quaternion over many vectors.
    np.testing.assert_allclose(rot.quat_rotate(q[0, 0], v), v @ rot.quat_to_matrix(q[0, 0]).T, atol=1e-14)


def test_geodesic_equals_rotvec_norm() -> None:
    a, b = random_quats(500, seed=12), random_quats(500, seed=13)
    expected = np.linalg.norm(rot.quat_to_rotvec(rot.quat_mul(a, rot.quat_inv(b))), axis=-1)
    np.testing.assert_allclose(rot.quat_geodesic_angle(a, b), expected, atol=1e-13)
    np.testing.assert_allclose(rot.quat_geodesic_angle(-a, b), expected, atol=1e-13)


def test_angular_velocity_recovers_omega() -> None:
    rng = np.random.default_rng(14)
    q0, omega, dt = random_quats(300, seed=15), rng.normal(scale=3.0, size=(300, 3)), 1.0 / 30.0
    q1 = rot.quat_mul(rot.quat_from_rotvec(omega * dt), q0)
    np.testing.assert_allclose(rot.angular_velocity(q0, q1, dt), omega, atol=1e-11)
    dts = rng.uniform(0.01, 0.05, size=300)
    q1 = rot.quat_mul(rot.quat_from_rotvec(omega * dts[:, None]), q0)
    np.testing.assert_allclose(rot.angular_velocity(q0, -q1, dts), omega, atol=1e-11)


# ------------------------------------------------------------------------------------------ Euler continuity


def test_euler_continuous_through_gimbal_lock() -> None:
    angles = np.deg2rad(np.arange(0.0, 170.5, 1.0))
    q = rot.quat_from_axis_angle([0.0, 1.0, 0.0], angles)
    e = rot.quat_to_euler_xyz_continuous(q)
    assert np.max(np.abs(np.diff(e, axis=0))) < np.deg2rad(1.0) + 1e-9
    np.testing.assert_allclose(e[:, 1], angles, atol=1e-7)  # b passes pi/2 instead of folding back
    same_rotation(rot.euler_xyz_to_quat(e), q, atol=1e-9)
    # The principal solution folds back at b = pi/2 and jumps by pi in a and c.
    assert np.max(np.abs(np.diff(rot.quat_to_euler_xyz(q), axis=0))) > 3.0


def test_euler_continuous_carries_2pi() -> None:
    angles = np.linspace(0.0, 3.0 * np.pi, 301)
    q = rot.quat_from_axis_angle([1.0, 0.0, 0.0], angles)
    e = rot.quat_to_euler_xyz_continuous(q)
    assert np.all(np.diff(e[:, 0]) > 0.0)
    np.testing.assert_allclose(e[:, 0], angles, atol=1e-12)
    np.testing.assert_allclose(e[:, 1:], 0.0, atol=1e-12)


def test_euler_continuous_batched() -> None:
    # Smooth random trajectories in a (T, 2, 3) batch: Euler rates bounded by the per-frame rotation.
    rng = np.random.default_rng(16)
    omega = rng.normal(scale=0.05, size=(400, 2, 3))
    q = np.empty((400, 2, 4))
    q[0] = random_quats(2, seed=17)
    for t in range(1, 400):
        q[t] = rot.quat_mul(rot.quat_from_rotvec(omega[t]), q[t - 1])
    e = rot.quat_to_euler_xyz_continuous(q)
    assert e.shape == (400, 2, 3)
    same_rotation(rot.euler_xyz_to_quat(e), q)
    np.testing.assert_allclose(e[:, 1], rot.quat_to_euler_xyz_continuous(q[:, 1]))
    frame_angles = rot.quat_geodesic_angle(q[1:], q[:-1])
    jumps = np.linalg.norm(np.diff(e, axis=0), axis=-1)
    near_lock = np.abs(np.cos(e[1:, :, 1])) < 0.2
    assert np.all(jumps[~near_lock] < 10.0 * frame_angles[~near_lock] + 1e-9)


# --------------------------------------------------------------------------------------------- against MuJoCo


def test_against_mujoco() -> None:
    rng = np.random.default_rng(18)
    qa, qb = random_quats(5, seed=19), random_quats(5, seed=20)
    for a, b, v in zip(qa, qb, rng.normal(size=(5, 3)), strict=True):
        res4, res3, res9 = np.zeros(4), np.zeros(3), np.zeros(9)
        mujoco.mju_mulQuat(res4, a, b)
        np.testing.assert_allclose(rot.quat_mul(a, b), res4, atol=1e-14)
        mujoco.mju_rotVecQuat(res3, v, a)
        np.testing.assert_allclose(rot.quat_rotate(a, v), res3, atol=1e-14)
        mujoco.mju_quat2Mat(res9, a)
        np.testing.assert_allclose(rot.quat_to_matrix(a), res9.reshape(3, 3), atol=1e-14)
        axis, angle = v / np.linalg.norm(v), rng.uniform(-np.pi, np.pi)
        mujoco.mju_axisAngle2Quat(res4, axis, angle)
        np.testing.assert_allclose(rot.quat_from_axis_angle(v, angle), res4, atol=1e-14)
        mujoco.mju_quat2Vel(res3, rot.quat_mul(b, rot.quat_conj(a)), 0.02)
        np.testing.assert_allclose(rot.angular_velocity(a, b, 0.02), res3, atol=1e-11)


# ------------------------------------------------------------------------------------------------------ torch

Q_NP, Q2_NP = random_quats(64, seed=21), random_quats(64, seed=22)
V_NP = np.random.default_rng(23).normal(size=(64, 3))
R_NP = np.concatenate([np.random.default_rng(24).normal(size=(60, 3)), 1e-5 * np.ones((4, 3))])
SIX_NP = np.random.default_rng(25).normal(size=(64, 6))
YAW_NP = np.random.default_rng(26).uniform(-4.0, 4.0, size=64)

TORCH_CASES = {
    "quat_mul": (Q_NP, Q2_NP),
    "quat_conj": (Q_NP,),
    "quat_normalize": (3.0 * Q_NP,),
    "quat_rotate": (Q_NP, V_NP),
    "quat_rotate_inv": (Q_NP, V_NP),
    "quat_from_rotvec": (R_NP,),
    "quat_to_rotvec": (Q_NP,),
    "quat_geodesic_angle": (Q_NP, Q2_NP),
    "quat_to_matrix": (Q_NP,),
    "quat_to_two_axis": (Q_NP,),
    "two_axis_to_matrix": (SIX_NP,),
    "quat_from_yaw": (YAW_NP,),
    "quat_yaw": (Q_NP,),
    "angular_velocity": (Q_NP, Q2_NP, 0.04),
}


@pytest.mark.parametrize("name", sorted(TORCH_CASES))
def test_torch_matches_numpy(name: str) -> None:
    args = TORCH_CASES[name]
    expected = getattr(rot, name)(*args)
    t_args = [torch.from_numpy(a) if isinstance(a, np.ndarray) else a for a in args]
    got = getattr(trot, name)(*t_args)
    assert got.dtype == torch.float64
    np.testing.assert_allclose(got.numpy(), expected, atol=1e-12)
    got32 = getattr(trot, name)(*[a.float() if isinstance(a, torch.Tensor) else a for a in t_args])
    assert got32.dtype == torch.float32
    np.testing.assert_allclose(got32.numpy(), expected, atol=2e-5)


def test_torch_angular_velocity_tensor_dt() -> None:
    dt = torch.linspace(0.01, 0.05, 64, dtype=torch.float64)
    got = trot.angular_velocity(torch.from_numpy(Q_NP), torch.from_numpy(Q2_NP), dt)
    np.testing.assert_allclose(got.numpy(), rot.angular_velocity(Q_NP, Q2_NP, dt.numpy()), atol=1e-12)


def test_torch_gradients_finite_at_identity() -> None:
    zero = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    jac = torch.autograd.functional.jacobian(trot.quat_from_rotvec, zero)
    np.testing.assert_allclose(jac.numpy(), np.vstack([np.zeros(3), 0.5 * np.eye(3)]))
    ident = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    jac = torch.autograd.functional.jacobian(trot.quat_to_rotvec, ident)
    np.testing.assert_allclose(jac.numpy(), np.hstack([np.zeros((3, 1)), 2.0 * np.eye(3)]))
    # Round trip through both maps and a geodesic loss, evaluated exactly at the identity.
    r = torch.zeros(2, 3, requires_grad=True)
    q = trot.quat_from_rotvec(r)
    loss = trot.quat_to_rotvec(q).sum() + trot.quat_geodesic_angle(q, torch.tensor([1.0, 0, 0, 0])).sum()
    loss.backward()
    assert torch.isfinite(r.grad).all()
    np.testing.assert_allclose(r.grad.numpy(), np.ones((2, 3)), atol=1e-6)  # d sum(r)/dr; geodesic adds 0
    q = torch.tensor(Q_NP[:4], requires_grad=True)
    trot.quat_geodesic_angle(q, q.detach()).sum().backward()
    assert torch.isfinite(q.grad).all()


def test_torch_gradcheck() -> None:
    # Stay away from w = 0, where the shortest-path sign flip makes the log map discontinuous.
    q_np = Q_NP[np.abs(Q_NP[:, 0]) > 0.2][:6]
    q = torch.tensor(q_np * np.sign(q_np[:, :1]), requires_grad=True)
    assert torch.autograd.gradcheck(trot.quat_to_rotvec, (q,))
    near_identity = torch.tensor(
        [[1.0, 1e-5, -2e-5, 3e-6], [0.9, 0.1, 0.2, 0.3]], dtype=torch.float64, requires_grad=True
    )
    assert torch.autograd.gradcheck(trot.quat_to_rotvec, (near_identity,))
    v = torch.tensor(V_NP[:6], requires_grad=True)
    assert torch.autograd.gradcheck(trot.quat_rotate, (q, v))
