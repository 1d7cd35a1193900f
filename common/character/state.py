"""The state of N characters (or T frames), simulated or reference: shared by the gym, the reference and learners."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np


@dataclass
class CharacterState:
    """The state of N characters (or T frames), simulated or reference. Leading shape: (...,).

    Attributes:
        qpos: Model generalised positions. Shape: (..., nq).
        qvel: Model generalised velocities (root angular velocity in the root frame, as MuJoCo). Shape: (..., nv).
        body_pos: Body frame origins, world. Shape: (..., B, 3).
        body_rot: Body rotations, world, (w, x, y, z). Shape: (..., B, 4).
        body_linvel: Linear velocity of each body frame origin, world. Shape: (..., B, 3).
        body_angvel: Angular velocity of each body, world. Shape: (..., B, 3).
    """

    qpos: np.ndarray
    qvel: np.ndarray
    body_pos: np.ndarray
    body_rot: np.ndarray
    body_linvel: np.ndarray
    body_angvel: np.ndarray

    def __getitem__(self, idx: object) -> CharacterState:
        return CharacterState(**{f.name: getattr(self, f.name)[idx] for f in fields(self)})


FRAME_FIELDS = tuple(f.name for f in fields(CharacterState))
