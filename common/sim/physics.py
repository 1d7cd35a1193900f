"""N characters stepped together in MuJoCo with ``mujoco.rollout`` (C++ threads, no Python loop per substep).

Each character is one batch entry of a rollout of ``substeps`` physics steps with a constant control (the PD targets
of the position actuators). All arrays are preallocated and contiguous so that the rollout runs with
``skip_checks``. With ``applied=True`` every step also takes an external generalised force per character (MuJoCo's
``qfrc_applied``, held over the substeps like the targets); the gym applies none. A character whose simulation
raised a MuJoCo warning (e.g. bad accelerations) has the rest of its rollout frozen, so its time stops advancing:
that, or a non-finite or absurd velocity, marks it as diverged.
"""

from __future__ import annotations

import mujoco
import numpy as np
from mujoco import rollout

from common.character.humanoid import Humanoid

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
_CTRL = int(mujoco.mjtState.mjSTATE_CTRL)
_CTRL_AND_FORCE = _CTRL | int(mujoco.mjtState.mjSTATE_QFRC_APPLIED)  # the control vector: ctrl (nu), then qfrc (nv)


class BatchedSim:
    """The physics of N characters.

    Args:
        humanoid: The model (its timestep and substeps from the physics config).
        num_envs: Number of characters N.
        threads: Rollout threads; 0 or 1 runs on the calling thread.
        max_speed: A generalised velocity above this (m/s or rad/s) counts as a blown-up simulation.
        applied: :meth:`step` also takes an external generalised force (``qfrc_applied``, nv values: forces on
            translational and torques on rotational dofs) per character.
        model: The model every character starts in (``humanoid.model`` when None); :meth:`set_models` puts
            characters in others of the same sizes (:mod:`common.sim.terrain`).
    """

    def __init__(self, humanoid: Humanoid, num_envs: int, threads: int = 2, max_speed: float = 1e3,
                 applied: bool = False, model: mujoco.MjModel | None = None) -> None:  # fmt: skip
        m = humanoid.model if model is None else model
        self.model = m
        self.num_envs = num_envs
        self.substeps = humanoid.physics.substeps
        self.dt = humanoid.physics.control_dt
        self.max_speed = max_speed
        nstate = mujoco.mj_stateSize(m, _FULL.value)
        expected = 1 + m.nq + m.nv + m.na
        if nstate != expected:
            raise ValueError(f"full physics state has {nstate} values, expected time+qpos+qvel+act = {expected}")
        self._qpos = slice(1, 1 + m.nq)
        self._qvel = slice(1 + m.nq, 1 + m.nq + m.nv)
        self.state = np.zeros((num_envs, nstate))
        self.applied = applied
        self._spec = _CTRL_AND_FORCE if applied else _CTRL
        self._ctrl = np.zeros((num_envs, self.substeps, m.nu + (m.nv if applied else 0)))
        self._out = np.zeros((num_envs, self.substeps, nstate))
        self._sensor = np.zeros((num_envs, self.substeps, m.nsensordata))
        threads = max(0, int(threads))
        self._datas = [mujoco.MjData(m) for _ in range(max(1, threads))]
        self._models = [m] * num_envs
        self._pool = rollout.Rollout(nthread=threads if threads > 1 else 0)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool = None

    @property
    def qpos(self) -> np.ndarray:
        """View of every character's qpos. Shape: (N, nq)."""
        return self.state[:, self._qpos]

    @property
    def qvel(self) -> np.ndarray:
        """View of every character's qvel. Shape: (N, nv)."""
        return self.state[:, self._qvel]

    @property
    def models(self) -> tuple[mujoco.MjModel, ...]:
        """The model each character is stepped in. Length N."""
        return tuple(self._models)

    def set_models(self, ids: np.ndarray, models: list[mujoco.MjModel]) -> None:
        """Steps characters ``ids`` in ``models`` from now on (each with the sizes of the model it started in)."""
        for i, model in zip(np.asarray(ids, dtype=np.int64).tolist(), models, strict=True):
            if model.ngeom != self.model.ngeom or model.nbody != self.model.nbody or model.nv != self.model.nv:
                raise ValueError("a character's model must have the sizes of the model the simulator was built for")
            self._models[i] = model

    def set_state(self, ids: np.ndarray, qpos: np.ndarray, qvel: np.ndarray) -> None:
        """Places characters ``ids`` at the given coordinates, at rest time 0 and with no actuator state."""
        self.state[ids] = 0.0
        self.state[ids, self._qpos] = qpos
        self.state[ids, self._qvel] = qvel

    def step(self, ctrl: np.ndarray, force: np.ndarray | None = None) -> np.ndarray:
        """Advances every character by one control step.

        Args:
            ctrl: Position actuator targets. Shape: (N, nu).
            force: With ``applied``: the generalised force held over the step (None: 0). Shape: (N, nv) or (nv,).

        Returns:
            diverged: characters whose simulation blew up (their state is left as it is; the caller resets them).
            Shape: (N,).
        """
        nu = self.model.nu
        self._ctrl[:, :, :nu] = ctrl[:, None, :]
        if force is not None:
            if not self.applied:
                raise ValueError("this BatchedSim was built without applied=True: it takes no force")
            self._ctrl[:, :, nu:] = np.broadcast_to(force, (self.num_envs, self.model.nv))[:, None, :]
        elif self.applied:
            self._ctrl[:, :, nu:] = 0.0
        t0 = self.state[:, 0].copy()
        self._pool.rollout(
            self._models, self._datas, self.state, self._ctrl, state=self._out, sensordata=self._sensor,
            nstep=self.substeps, control_spec=self._spec, skip_checks=True,
        )  # fmt: skip
        final = self._out[:, -1]
        self.state[:] = final
        advanced = np.abs(final[:, 0] - (t0 + self.dt)) < 0.25 * self.dt / self.substeps
        finite = np.isfinite(final).all(axis=1)
        calm = np.abs(final[:, self._qvel]).max(axis=1) < self.max_speed  # false for NaN: the max propagates it
        return ~(advanced & finite & calm)
