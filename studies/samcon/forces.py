"""External forces for the SAMCON studies: forces held whatever the state, and a replay that records what a force gave.

Both are :class:`samcon.search.ExternalForce` users: the product's search, replay, linearisation and polish take
such a force (MuJoCo's ``qfrc_applied``); the studies here make and record them.
"""

from __future__ import annotations

import numpy as np

from common.character.humanoid import Humanoid
from common.sim.physics import BatchedSim
from samcon.search import ExternalForce


class HeldForces:
    """An :class:`samcon.search.ExternalForce` that gives recorded forces whatever the state: ``forces[f]`` at frame
    f, to every character, with a zero Jacobian.

    Args:
        forces: Shape: (F, nv).
    """

    def __init__(self, forces: np.ndarray) -> None:
        self.forces = np.asarray(forces, dtype=np.float64)

    def __call__(self, frame: int, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        return np.tile(self.forces[frame], (len(qpos), 1))

    def jacobian(self, frame: int, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        nv = self.forces.shape[1]
        return np.zeros((len(qpos), nv, 2 * nv))


def assisted_replay(humanoid: Humanoid, start: np.ndarray, targets: np.ndarray, force: ExternalForce, first: int = 0,
                    max_speed: float = 1000.0) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Plays PD targets (F, nu) open loop from a full state (nstate,) at clip frame ``first`` with ``force`` (as
    :func:`samcon.search.replay` does): the state after every step (F, nstate) and the force of every step (F, nv)."""
    sim = BatchedSim(humanoid, 1, 0, max_speed, applied=True)
    out, forces = np.zeros((len(targets), len(start))), np.zeros((len(targets), humanoid.nv))
    try:
        sim.state[0] = start
        for f, target in enumerate(targets):
            forces[f] = force(first + f, sim.qpos, sim.qvel)[0]
            sim.step(target[None], forces[f])
            out[f] = sim.state[0]
    finally:
        sim.close()
    return out, forces
