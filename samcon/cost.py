"""SAMCON's tracking cost and the low-dimensional state its linear feedback policies read.

Both are pure functions of simulated and reference :class:`~common.character.state.CharacterState` batches (leading
shape (N,)). Shape letters: N characters, B bodies, D feedback features.
"""

from __future__ import annotations

import numpy as np

from common.character.humanoid import Humanoid
from common.character.state import CharacterState
from common.maths.rotations import quat_geodesic_angle, quat_rotate_inv, quat_split_heading, quat_to_rotvec
from samcon.config import CostConfig

COST_TERMS = ("pose", "root_pos", "root_rot", "end_effector", "balance", "root_vel", "body_pos")
FEATURE_NAMES = (
    ("root_height",)
    + tuple(f"root_tilt_{a}" for a in "xyz")
    + tuple(f"root_vel_{a}" for a in "xyz")
    + tuple(f"root_ang_vel_{a}" for a in "xyz")
    + tuple(f"{foot}_{a}" for foot in ("right_foot", "left_foot") for a in "xyz")
)
"""The feedback state: deviations (simulated - reference) of the root and feet, each in its own heading frame."""


def centre_of_mass(humanoid: Humanoid, body_pos: np.ndarray) -> np.ndarray:
    """Mass-weighted mean of the body frame origins (near the centre of mass; the same rule for sim and reference).

    Args:
        body_pos: Shape: (N, B, 3).

    Returns:
        Shape: (N, 3).
    """
    mass = humanoid.body_mass
    return np.einsum("b,nbc->nc", mass / mass.sum(), body_pos)


def tracking_cost(
    humanoid: Humanoid, config: CostConfig, sim: CharacterState, ref: CharacterState
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The weighted tracking cost of one frame (Liu et al. 2010: pose, root, end effectors, balance).

    Returns:
        cost: Sum of the weighted terms plus the fall penalty. Shape: (N,).
        terms: Unweighted terms, {name: (N,)} for every name in :data:`COST_TERMS`, and ``fallen`` (N,) bool.
    """
    r, ee, feet = humanoid.root_index, humanoid.end_effector_indices, humanoid.foot_indices
    hinge = humanoid.hinge_qpos
    sim_rel = sim.body_pos - sim.body_pos[:, r : r + 1]
    ref_rel = ref.body_pos - ref.body_pos[:, r : r + 1]
    # Balance: the horizontal centre of mass relative to the middle of the feet, compared with the reference's.
    sim_com = centre_of_mass(humanoid, sim.body_pos) - sim.body_pos[:, feet].mean(axis=1)
    ref_com = centre_of_mass(humanoid, ref.body_pos) - ref.body_pos[:, feet].mean(axis=1)
    terms = {
        "pose": np.mean((sim.qpos[:, hinge] - ref.qpos[:, hinge]) ** 2, axis=-1),
        "root_pos": np.sum((sim.body_pos[:, r] - ref.body_pos[:, r]) ** 2, axis=-1),
        "root_rot": quat_geodesic_angle(sim.body_rot[:, r], ref.body_rot[:, r]) ** 2,
        "end_effector": np.mean(np.sum((sim_rel[:, ee] - ref_rel[:, ee]) ** 2, axis=-1), axis=-1),
        "balance": np.sum((sim_com[:, :2] - ref_com[:, :2]) ** 2, axis=-1),
        "root_vel": np.sum((sim.body_linvel[:, r] - ref.body_linvel[:, r]) ** 2, axis=-1),
        "body_pos": np.mean(np.sum((sim.body_pos - ref.body_pos) ** 2, axis=-1), axis=-1),
    }
    cost = sum(getattr(config, name) * terms[name] for name in COST_TERMS)
    h = humanoid.head_index
    fallen = np.abs(sim.body_pos[:, h, 2] - ref.body_pos[:, h, 2]) > config.fall_head_error
    return cost + config.fall_penalty * fallen, {**terms, "fallen": fallen}


def _heading_local(state: CharacterState, humanoid: Humanoid) -> np.ndarray:
    """Root height, tilt, velocities and feet of one batch in the root's heading frame. Shape: (N, D)."""
    r, feet = humanoid.root_index, humanoid.foot_indices
    rot = state.body_rot[:, r]
    heading, tilt = quat_split_heading(rot)
    feet_rel = state.body_pos[:, feet] - state.body_pos[:, r : r + 1]
    return np.concatenate([
        state.body_pos[:, r, 2:3],
        quat_to_rotvec(tilt),
        quat_rotate_inv(heading, state.body_linvel[:, r]),
        quat_rotate_inv(heading, state.body_angvel[:, r]),
        quat_rotate_inv(heading[:, None], feet_rel).reshape(len(rot), -1),
    ], axis=-1)  # fmt: skip


def feedback_features(humanoid: Humanoid, sim: CharacterState, ref: CharacterState) -> np.ndarray:
    """The feedback state of :data:`FEATURE_NAMES`: simulated minus reference, each in its own heading frame, so
    that it does not depend on where the clip's cycle has carried the character. Shape: (N, D)."""
    return _heading_local(sim, humanoid) - _heading_local(ref, humanoid)
