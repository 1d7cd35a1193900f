"""BatchedSim's applied generalised force: the same physics as MuJoCo's own mj_step with qfrc_applied set."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.sim.physics import BatchedSim


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


def _start(humanoid: Humanoid, n: int) -> np.ndarray:
    """n copies of the model's default pose lifted 5 cm, every character with another small root velocity."""
    m = humanoid.model
    sim = BatchedSim(humanoid, n, threads=0)
    qpos = np.tile(m.qpos0, (n, 1))
    qpos[:, 2] += 0.05
    qvel = np.zeros((n, m.nv))
    qvel[:, 0] = np.linspace(0.0, 0.3, n)
    sim.set_state(np.arange(n), qpos, qvel)
    state = sim.state.copy()
    sim.close()
    return state


def test_no_force_is_the_plain_simulation_bit_for_bit(humanoid: Humanoid) -> None:
    start = _start(humanoid, 3)
    ctrl = np.tile(0.1 * np.sin(np.arange(humanoid.nu)), (3, 1))
    plain, forced = BatchedSim(humanoid, 3, threads=0), BatchedSim(humanoid, 3, threads=0, applied=True)
    plain.state[:], forced.state[:] = start, start
    for _ in range(4):
        plain.step(ctrl)
        forced.step(ctrl)  # no force given: 0
    np.testing.assert_array_equal(plain.state, forced.state)
    forced.step(ctrl, np.zeros(humanoid.nv))
    plain.step(ctrl)
    np.testing.assert_array_equal(plain.state, forced.state)
    with pytest.raises(ValueError, match="applied=True"):
        plain.step(ctrl, np.zeros(humanoid.nv))
    plain.close()
    forced.close()


def test_the_force_is_mujocos_qfrc_applied_held_over_the_substeps(humanoid: Humanoid) -> None:
    m = humanoid.model
    start = _start(humanoid, 2)
    ctrl = np.zeros((2, humanoid.nu))
    force = np.zeros((2, m.nv))
    force[0, 0:3] = [30.0, -20.0, 400.0]  # N on the root, world frame
    force[1, 6] = 5.0  # N m on the first hinge
    sim = BatchedSim(humanoid, 2, threads=0, applied=True)
    sim.state[:] = start
    sim.step(ctrl, force)
    data = mujoco.MjData(m)
    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    for i in range(2):
        mujoco.mj_setState(m, data, start[i], full)
        data.ctrl[:], data.qfrc_applied[:] = ctrl[i], force[i]
        for _ in range(humanoid.physics.substeps):
            mujoco.mj_step(m, data)
        expected = np.zeros(mujoco.mj_stateSize(m, full))
        mujoco.mj_getState(m, data, expected, full)
        np.testing.assert_allclose(sim.state[i], expected, rtol=0, atol=1e-12)
    unforced = BatchedSim(humanoid, 2, threads=0)
    unforced.state[:] = start
    unforced.step(ctrl)
    assert np.all(np.abs(unforced.state - sim.state).max(axis=1) > 1e-4)  # the force moved both characters
    unforced.close()
    sim.close()
