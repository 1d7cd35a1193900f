"""Batched forward kinematics: body velocities at the body origins, and agreement with mj_forward."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.character.kinematics import SERIAL_BELOW, ForwardKinematics
from common.maths.rotations import quat_normalize
from common.motion.library import body_states


def test_matches_mj_forward_on_random_states() -> None:
    h = Humanoid()
    rng = np.random.default_rng(0)
    n = 16
    qpos = np.zeros((n, h.nq))
    qpos[:, 0:3] = rng.normal(size=(n, 3))
    qpos[:, 3:7] = quat_normalize(rng.normal(size=(n, 4)))
    qpos[:, 7:] = rng.uniform(-2.5, 2.5, size=(n, h.nq - 7))
    qvel = rng.normal(scale=3.0, size=(n, h.nv))
    ours = ForwardKinematics(h)(qpos, qvel)
    d = mujoco.MjData(h.model)
    for i in range(n):
        d.qpos[:], d.qvel[:] = qpos[i], qvel[i]
        mujoco.mj_forward(h.model, d)
        np.testing.assert_allclose(ours.body_pos[i], d.xpos[1:], atol=1e-12)
        np.testing.assert_allclose(ours.body_rot[i], d.xquat[1:], atol=1e-12)
    # A batch gives the same as one character at a time (no state leaks between characters).
    one = ForwardKinematics(h)(qpos[3:4], qvel[3:4])
    np.testing.assert_array_equal(one.body_linvel[0], ours.body_linvel[3])
    assert body_states(h, qpos, qvel).body_pos.shape == (n, h.num_bodies, 3)


def test_body_velocity_equals_mujoco_object_velocity() -> None:
    """body_states' linear velocity is MuJoCo's velocity of the body frame origin (mjOBJ_XBODY)."""
    h = Humanoid()
    rng = np.random.default_rng(1)
    qpos = np.zeros(h.nq)
    qpos[3] = 1.0
    qpos[7:] = rng.uniform(-1, 1, h.nq - 7)
    qvel = rng.normal(size=h.nv)
    ours = body_states(h, qpos[None], qvel[None])
    d = mujoco.MjData(h.model)
    d.qpos[:], d.qvel[:] = qpos, qvel
    mujoco.mj_forward(h.model, d)
    v = np.zeros(6)
    for b in range(h.num_bodies):
        mujoco.mj_objectVelocity(h.model, d, mujoco.mjtObj.mjOBJ_XBODY, b + 1, v, 0)
        np.testing.assert_allclose(ours.body_angvel[0, b], v[:3], atol=1e-12)
        np.testing.assert_allclose(ours.body_linvel[0, b], v[3:], atol=1e-12)


def test_thread_pool_and_calling_thread_agree_to_the_bit() -> None:
    """Small batches run on the calling thread, large ones in chunks on the pool: the same numbers either way."""
    h = Humanoid()
    rng = np.random.default_rng(2)
    n = SERIAL_BELOW + 9
    qpos = np.tile(h.model.qpos0, (n, 1))
    qpos[:, 2] += 1.0
    qpos[:, 7:] += rng.uniform(-1, 1, size=(n, h.nq - 7))
    qvel = rng.normal(size=(n, h.nv))
    fk = ForwardKinematics(h, threads=2)
    pooled = fk(qpos, qvel)
    parts = [fk(qpos[i : i + 5], qvel[i : i + 5]) for i in range(0, n, 5)]
    serial = ForwardKinematics(h, threads=1)(qpos, qvel)
    for name in ("body_pos", "body_rot", "body_linvel", "body_angvel"):
        np.testing.assert_array_equal(np.concatenate([getattr(p, name) for p in parts]), getattr(pooled, name))
        np.testing.assert_array_equal(getattr(serial, name), getattr(pooled, name))
    fk.close()
    with pytest.raises(RuntimeError, match="close"):
        fk(qpos, qvel)
