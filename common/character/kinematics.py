"""Body world states of N characters from generalised coordinates, with MuJoCo's own kinematics in C++ threads.

A copy of the model carries frame sensors (position, quaternion, linear and angular velocity of every body frame)
and has contacts, constraints and actuation disabled. One ``mujoco.rollout`` step of that model from the given
states computes the sensors *before* integrating (the integrated state is discarded), so the sensor data are
exactly MuJoCo's ``xpos``/``xquat`` and body-frame velocities of the input states, for all N characters, on the
rollout's threads and with no Python loop over characters.
"""

from __future__ import annotations

import mujoco
import numpy as np
from mujoco import rollout

from common.character.humanoid import Humanoid
from common.character.state import CharacterState

_SENSORS = (("framepos", 3), ("framequat", 4), ("framelinvel", 3), ("frameangvel", 3))
_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
# One kinematics step costs ~9 us per character; the rollout's thread pool costs ~50-100 us per call and ~10 us per
# chunk. Below this many characters (the gym's resets) the calling thread is faster than the pool; above it, two
# chunks per thread beat the rollout's default of ten (N = 256 on 2 threads: 0.96 instead of 1.24 ms).
SERIAL_BELOW = 32
CHUNKS_PER_THREAD = 2


def kinematics_model(humanoid: Humanoid) -> mujoco.MjModel:
    """The humanoid with frame sensors on every body and everything but kinematics switched off."""
    xml = humanoid.xml_path.read_text()
    sensors = "".join(
        f'<{kind} objtype="xbody" objname="{body}"/>' for body in humanoid.body_names for kind, _ in _SENSORS
    )
    end = xml.rindex("</mujoco>")
    model = mujoco.MjModel.from_xml_string(xml[:end] + f"<sensor>{sensors}</sensor>\n" + xml[end:])
    off = mujoco.mjtDisableBit
    for flag in (off.mjDSBL_CONTACT, off.mjDSBL_CONSTRAINT, off.mjDSBL_ACTUATION, off.mjDSBL_GRAVITY,
                 off.mjDSBL_LIMIT, off.mjDSBL_EQUALITY, off.mjDSBL_FRICTIONLOSS, off.mjDSBL_SPRING,
                 off.mjDSBL_DAMPER, off.mjDSBL_WARMSTART):  # fmt: skip
        model.opt.disableflags |= flag
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    return model


class ForwardKinematics:
    """Computes body positions, rotations and velocities for a batch of characters.

    Args:
        humanoid: The model.
        threads: Rollout threads (0 or 1: the calling thread).
    """

    def __init__(self, humanoid: Humanoid, threads: int = 1) -> None:
        self.model = kinematics_model(humanoid)
        self.num_bodies = humanoid.num_bodies
        self.nq, self.nv = humanoid.nq, humanoid.nv
        self.nstate = mujoco.mj_stateSize(self.model, _FULL.value)
        self.width = sum(n for _, n in _SENSORS)
        if self.model.nsensordata != self.num_bodies * self.width:
            raise ValueError(f"{humanoid.xml_path}: the model's own sensors are not supported by ForwardKinematics")
        threads = max(0, int(threads))
        self.threads = threads if threads > 1 else 0
        self._datas = [mujoco.MjData(self.model) for _ in range(max(1, threads))]
        self._pool = rollout.Rollout(nthread=self.threads)
        self._serial = rollout.Rollout(nthread=0) if self.threads else self._pool

    def close(self) -> None:
        for pool in (self._pool, self._serial):
            if pool is not None:
                pool.close()
        self._pool = self._serial = None

    def __call__(self, qpos: np.ndarray, qvel: np.ndarray) -> CharacterState:
        """Body states of N characters.

        Args:
            qpos: Shape: (N, nq).
            qvel: Shape: (N, nv).

        Returns:
            CharacterState with leading shape (N,), body quantities in the world frame at the body frame origins.
        """
        n = qpos.shape[0]
        state = np.zeros((n, self.nstate))
        state[:, 1 : 1 + self.nq] = qpos
        state[:, 1 + self.nq : 1 + self.nq + self.nv] = qvel
        out = np.empty((n, 1, self.nstate))
        sensor = np.empty((n, 1, self.model.nsensordata))
        if self._pool is None:
            raise RuntimeError("ForwardKinematics used after close()")
        if self.threads and n >= SERIAL_BELOW:
            pool, datas, chunk = self._pool, self._datas, -(-n // (CHUNKS_PER_THREAD * self.threads))
        else:
            pool, datas, chunk = self._serial, self._datas[:1], None
        pool.rollout(
            [self.model] * n, datas, state, np.zeros((n, 1, self.model.nu)), state=out, sensordata=sensor, nstep=1,
            skip_checks=True, chunk_size=chunk,
        )  # fmt: skip
        x = sensor[:, 0].reshape(n, self.num_bodies, self.width)
        return CharacterState(
            qpos=qpos, qvel=qvel, body_pos=x[..., 0:3].copy(), body_rot=x[..., 3:7].copy(),
            body_linvel=x[..., 7:10].copy(), body_angvel=x[..., 10:13].copy(),
        )  # fmt: skip
