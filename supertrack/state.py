"""Character states as torch tensors, their compact storage layout, and the semi-implicit Euler integrator.

SuperTrack represents the simulated (S, P) and kinematic (K) characters the same way: per rigid body the world
position, rotation, linear and angular velocity (Fussell et al. 2021, section 4). In the buffer one body is
stored as 13 float32 values laid out by :data:`STATE_LAYOUT`; fields are always reached by name.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np
import torch
from torch import Tensor

from common.character.state import CharacterState
from common.maths import torch_rotations as R
from common.sim.features import local_vector

# (BodyState field, CharacterState field, values per body): the packed per-body layout.
STATE_LAYOUT: tuple[tuple[str, str, int], ...] = (
    ("pos", "body_pos", 3),
    ("rot", "body_rot", 4),
    ("vel", "body_linvel", 3),
    ("angvel", "body_angvel", 3),
)
STATE_WIDTH = sum(n for _, _, n in STATE_LAYOUT)


@dataclass
class BodyState:
    """Per-body world state of characters. Leading shape (...,), e.g. (B,) or (B, T); N bodies.

    Attributes:
        pos: Body positions. Shape: (..., N, 3).
        rot: Body rotations, unit quaternions (w, x, y, z). Shape: (..., N, 4).
        vel: Body linear velocities. Shape: (..., N, 3).
        angvel: Body angular velocities. Shape: (..., N, 3).
    """

    pos: Tensor
    rot: Tensor
    vel: Tensor
    angvel: Tensor

    @classmethod
    def unpack(cls, packed: Tensor) -> BodyState:
        """Splits a packed state (..., N, 13) into its fields."""
        parts = torch.split(packed, [n for _, _, n in STATE_LAYOUT], dim=-1)
        return cls(**{name: part for (name, _, _), part in zip(STATE_LAYOUT, parts, strict=True)})

    @classmethod
    def from_character(cls, state: CharacterState, device: torch.device | str = "cpu") -> BodyState:
        """float32 tensors of a numpy CharacterState (leading shape (N,))."""
        return cls.unpack(torch.as_tensor(pack_character_state(state), device=device))

    def map(self, fn: Callable[[Tensor], Tensor]) -> BodyState:
        """The state with ``fn`` applied to every field, e.g. ``s.map(lambda x: x[:, 1:])`` drops frame 0."""
        return BodyState(**{f.name: fn(getattr(self, f.name)) for f in fields(self)})

    def time(self, i: int) -> BodyState:
        """Frame ``i`` of a (B, T, N, k) state -> (B, N, k)."""
        return self.map(lambda x: x[:, i])

    @staticmethod
    def stack(states: list[BodyState], dim: int = 1) -> BodyState:
        """Stacks (B, N, k) states along a new time axis -> (B, T, N, k)."""
        return BodyState(
            **{f.name: torch.stack([getattr(s, f.name) for s in states], dim=dim) for f in fields(BodyState)}
        )

    def local(self) -> Tensor:
        """SuperTrack's flat Local() features (common.sim.features layout). Shape: (..., 16 N + 3)."""
        return local_vector(self.pos, self.rot, self.vel, self.angvel)


def pack_character_state(state: CharacterState) -> np.ndarray:
    """The buffer layout of a numpy state: (..., N, 13) float32 in :data:`STATE_LAYOUT` order."""
    return np.concatenate([getattr(state, src) for _, src, _ in STATE_LAYOUT], axis=-1).astype(np.float32)


def integrate(state: BodyState, lin_acc: Tensor, ang_acc: Tensor, dt: float) -> BodyState:
    """Semi-implicit Euler step of every body (paper, section 4.1); never modifies its inputs.

    v' = v + dt a;  w' = w + dt alpha;  x' = x + dt v';  q' = quat_from_rotvec(dt w') * q.

    Args:
        state: Current state P_i. Shapes (..., N, k).
        lin_acc: World-frame linear accelerations a. Shape: (..., N, 3).
        ang_acc: World-frame angular accelerations alpha. Shape: (..., N, 3).
        dt: Control time step (s).

    Returns:
        P_{i+1}, rotations renormalised so that float32 round-off cannot accumulate over a rollout.
    """
    vel = state.vel + dt * lin_acc
    angvel = state.angvel + dt * ang_acc
    pos = state.pos + dt * vel
    rot = R.quat_normalize(R.quat_mul(R.quat_from_rotvec(dt * angvel), state.rot))
    return BodyState(pos=pos, rot=rot, vel=vel, angvel=angvel)


def target_rotations(offsets: Tensor, kin_joint_rot: Tensor, alpha: float) -> Tensor:
    """PD target rotations from offsets: t = quat_from_rotvec(alpha * o_hat) * k_{i+1} (exp(alpha/2 o_hat) k).

    Args:
        offsets: Axis-angle offsets o_hat (noise included). Shape: (..., J, 3).
        kin_joint_rot: Reference joint rotations of the next frame, k_{i+1}. Shape: (..., J, 4).
        alpha: Offset scale (rad per unit of o).

    Returns:
        Target joint rotations. Shape: (..., J, 4).
    """
    return R.quat_mul(R.quat_from_rotvec(alpha * offsets), kin_joint_rot)


def applied_rotations(target_rot: Tensor, revolute: Tensor) -> Tensor:
    """The rotations the PD controllers actually aim for: revolute joints keep only their hinge (+y) part.

    ``joint_rotations_to_hinges`` sets a knee or elbow to 2 atan2(q_y, q_w), i.e. the rotation normalise(w, 0, y, 0);
    spherical joints realise the rotation exactly.

    Args:
        target_rot: Joint target rotations. Shape: (..., J, 4).
        revolute: True for revolute joints. Shape: (J,).

    Returns:
        Shape: (..., J, 4).
    """
    hinge = target_rot * torch.tensor([1.0, 0.0, 1.0, 0.0], dtype=target_rot.dtype, device=target_rot.device)
    return torch.where(revolute[:, None], R.quat_normalize(hinge), target_rot)


def target_features(target_rot: Tensor, revolute: Tensor) -> Tensor:
    """Network form of PD targets: two-axis (first two matrix columns) of each applied joint rotation.

    Args:
        target_rot: Joint target rotations. Shape: (..., J, 4).
        revolute: True for revolute joints. Shape: (J,).

    Returns:
        Shape: (..., 6 J).
    """
    two_axis = R.quat_to_two_axis(applied_rotations(target_rot, revolute))
    return two_axis.reshape(*two_axis.shape[:-2], -1)
