"""DeepMimic tracking rewards and the termination rules, as pure functions of simulated vs reference states.

Reward (Peng et al. 2018, DeepMimic, eq. 5-10 and its code): each term is exp(-scale * error) and the terms are
combined as a weighted sum (``form: sum``, DeepMimic) or a product (``form: product``). Errors:
- pose: sum_j w_j angle(q_j^sim, q_j^ref)^2 over the joints' local rotations and the root's world rotation,
  with DeepMimic's per-joint weights normalised to sum to 1;
- velocity: sum_j w_j |w_j^sim - w_j^ref|^2 over joint angular velocities (relative to the parent, in the parent
  frame) and the root's world angular velocity;
- end_effector: mean over hands and feet of |p_e - p_root|^2 difference, each in its own heading frame;
- root: |p|^2 + 0.1 angle^2 + 0.01 |v|^2 + 0.001 |w|^2 of the root differences;
- com: |v_com^sim - v_com^ref|^2 of the centre-of-mass velocity.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from common.humanoid import Humanoid
from common.motion_library import CharacterState
from common.rotations import cross, quat_conj, quat_geodesic_angle, quat_mul, quat_rotate, quat_yaw

REWARD_TERMS = ("pose", "velocity", "end_effector", "root", "com")
# DeepMimic humanoid3d DiffWeight per joint (the joint's child body); hands have no joint (weight 0).
DEEPMIMIC_BODY_WEIGHTS = {
    "pelvis": 1.0, "torso": 0.5, "head": 0.3, "right_thigh": 0.5, "right_shin": 0.3, "right_foot": 0.2,
    "right_upper_arm": 0.3, "right_lower_arm": 0.2, "right_hand": 0.0, "left_thigh": 0.5, "left_shin": 0.3,
    "left_foot": 0.2, "left_upper_arm": 0.3, "left_lower_arm": 0.2, "left_hand": 0.0,
}  # fmt: skip


@dataclass(frozen=True)
class RewardTerms:
    """One number per reward term."""

    pose: float
    velocity: float
    end_effector: float
    root: float
    com: float


@dataclass(frozen=True)
class RewardConfig:
    """DeepMimic's reward.

    Attributes:
        form: ``sum`` (weighted sum of exponentials, DeepMimic) or ``product`` (product of exponentials, weights
            unused).
        weights: Weight of each term in the sum (DeepMimic: 0.5, 0.05, 0.15, 0.2, 0.1).
        scales: k in exp(-k * error) (DeepMimic: 2, 0.1, 40, 5, 10).
    """

    form: Literal["sum", "product"] = "sum"
    weights: RewardTerms = field(default_factory=lambda: RewardTerms(0.5, 0.05, 0.15, 0.2, 0.1))
    scales: RewardTerms = field(default_factory=lambda: RewardTerms(2.0, 0.1, 40.0, 5.0, 10.0))


@dataclass(frozen=True)
class TerminationConfig:
    """When an episode ends. A ``None`` threshold disables its rule.

    Attributes:
        max_episode_frames: Truncate after this many control steps (SuperTrack: 512).
        grace_frames: Failure rules are checked only once an episode has lasted this many steps (SuperTrack: 48).
        head_height_error: Terminate when the head height differs from the reference by more than this (m).
        root_pos_error: Terminate when the root is farther than this from the reference root (m).
        root_rot_error: Terminate when the root rotation differs by more than this (rad).
        body_pos_error: Terminate when any body is farther than this from its reference (m).
        min_root_height: Terminate when the root is lower than this (m).
        fall_contact: Terminate on ground contact of ``deepmimic`` (pelvis, torso, head) or ``non_foot`` bodies.
        contact_height: A body whose lowest point is below this height (m) touches the ground.
        clip_end: Truncate when a one-shot clip has no frame left.
    """

    max_episode_frames: int | None = 512
    grace_frames: int = 48
    head_height_error: float | None = 0.25
    root_pos_error: float | None = None
    root_rot_error: float | None = None
    body_pos_error: float | None = None
    min_root_height: float | None = None
    fall_contact: Literal["off", "deepmimic", "non_foot"] = "off"
    contact_height: float = 0.005
    clip_end: bool = True


class TrackingReward:
    """Computes the reward terms for N characters. Holds only model constants (weights, masses, indices)."""

    def __init__(self, humanoid: Humanoid, config: RewardConfig) -> None:
        self.config = config
        w = np.array([DEEPMIMIC_BODY_WEIGHTS[b] for b in humanoid.body_names])
        self.body_weights = w / w.sum()
        self.parent = humanoid.parent_index
        self.child = np.flatnonzero(self.parent >= 0)
        self.root = humanoid.root_index
        self.effectors = humanoid.end_effector_indices
        m = humanoid.model
        self.mass = np.asarray(m.body_mass[1:])
        self.com_offset = np.asarray(m.body_ipos[1:])  # body-frame centre of mass; inertial frames are not rotated

    def _relative(self, s: CharacterState) -> tuple[np.ndarray, np.ndarray]:
        """Joint-local rotations (children; the root keeps its world rotation), shape (N, B, 4), and joint angular
        velocities relative to the parent in the parent frame (the root's in world), shape (N, B, 3)."""
        inv_parent = quat_conj(s.body_rot[:, self.parent[self.child]])
        rot = s.body_rot.copy()
        rot[:, self.child] = quat_mul(inv_parent, s.body_rot[:, self.child])
        angvel = s.body_angvel.copy()
        angvel[:, self.child] = quat_rotate(
            inv_parent, s.body_angvel[:, self.child] - s.body_angvel[:, self.parent[self.child]]
        )
        return rot, angvel

    def com_velocity(self, s: CharacterState) -> np.ndarray:
        """Centre-of-mass velocity: sum_b m_b (v_b + w_b x R_b c_b) / M. Shape: (N, 3)."""
        v = s.body_linvel + cross(s.body_angvel, quat_rotate(s.body_rot, self.com_offset))
        return np.einsum("b,nbk->nk", self.mass, v) / self.mass.sum()

    def _heading_local_effectors(self, s: CharacterState) -> np.ndarray:
        """End effectors relative to the root, in the root's heading frame (rotated by -yaw about z). (N, E, 3)."""
        rel = s.body_pos[:, self.effectors] - s.body_pos[:, self.root, None]
        yaw = quat_yaw(s.body_rot[:, self.root])[:, None]
        c, sn = np.cos(yaw), np.sin(yaw)
        out = rel.copy()
        out[..., 0] = c * rel[..., 0] + sn * rel[..., 1]
        out[..., 1] = -sn * rel[..., 0] + c * rel[..., 1]
        return out

    def errors(self, sim: CharacterState, ref: CharacterState) -> dict[str, np.ndarray]:
        """Squared tracking errors per term. Each: (N,)."""
        rot_s, angvel_s = self._relative(sim)
        rot_r, angvel_r = self._relative(ref)
        pose = _angle(rot_s, rot_r) ** 2
        vel = np.sum((angvel_s - angvel_r) ** 2, axis=-1)
        ee = self._heading_local_effectors(sim) - self._heading_local_effectors(ref)
        r = self.root
        root = (
            np.sum((sim.body_pos[:, r] - ref.body_pos[:, r]) ** 2, axis=-1)
            + 0.1 * pose[:, r]
            + 0.01 * np.sum((sim.body_linvel[:, r] - ref.body_linvel[:, r]) ** 2, axis=-1)
            + 0.001 * np.sum((sim.body_angvel[:, r] - ref.body_angvel[:, r]) ** 2, axis=-1)
        )
        return {
            "pose": pose @ self.body_weights,
            "velocity": vel @ self.body_weights,
            "end_effector": np.mean(np.sum(ee**2, axis=-1), axis=-1),
            "root": root,
            "com": np.sum((self.com_velocity(sim) - self.com_velocity(ref)) ** 2, axis=-1),
        }

    def __call__(self, sim: CharacterState, ref: CharacterState) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Reward and its named terms exp(-scale * error).

        Returns:
            reward (N,), and {term: (N,)} of the unweighted exponentials.
        """
        err = self.errors(sim, ref)
        terms = {k: np.exp(-getattr(self.config.scales, k) * err[k]) for k in REWARD_TERMS}
        if self.config.form == "sum":
            reward = sum(getattr(self.config.weights, k) * terms[k] for k in REWARD_TERMS)
        else:
            reward = np.prod(np.stack([terms[k] for k in REWARD_TERMS]), axis=0)
        return reward, terms


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Geodesic angle between unit quaternions from their dot product: 2 arccos |<a, b>| (sign-invariant).

    Cheaper than a quaternion product; arccos loses precision only for angles below ~1e-8 rad, which no reward
    term can resolve.
    """
    return 2.0 * np.arccos(np.minimum(np.abs(np.sum(a * b, axis=-1)), 1.0))


def termination(
    config: TerminationConfig,
    humanoid: Humanoid,
    sim: CharacterState,
    ref: CharacterState,
    episode_frames: np.ndarray,
    lowest_points: np.ndarray,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Failure rules after a step. Returns terminated (N,) and which rule fired, {rule: (N,) bool}.

    Args:
        config: The rules.
        humanoid: The model.
        sim: Simulated state after the step.
        ref: Reference state at the same time.
        episode_frames: Steps taken in the episode including this one. Shape: (N,).
        lowest_points: Lowest point of every body of the simulated character. Shape: (N, B).
    """
    rules: dict[str, np.ndarray] = {}
    r, h = humanoid.root_index, humanoid.head_index
    if config.head_height_error is not None:
        rules["head_height"] = np.abs(sim.body_pos[:, h, 2] - ref.body_pos[:, h, 2]) > config.head_height_error
    if config.root_pos_error is not None:
        rules["root_pos"] = np.linalg.norm(sim.body_pos[:, r] - ref.body_pos[:, r], axis=-1) > config.root_pos_error
    if config.root_rot_error is not None:
        rules["root_rot"] = quat_geodesic_angle(sim.body_rot[:, r], ref.body_rot[:, r]) > config.root_rot_error
    if config.body_pos_error is not None:
        dist = np.linalg.norm(sim.body_pos - ref.body_pos, axis=-1)
        rules["body_pos"] = dist.max(axis=-1) > config.body_pos_error
    if config.min_root_height is not None:
        rules["root_height"] = sim.body_pos[:, r, 2] < config.min_root_height
    if config.fall_contact != "off":
        if config.fall_contact == "deepmimic":
            bodies = humanoid.fall_contact_indices
        else:
            bodies = np.setdiff1d(np.arange(humanoid.num_bodies), humanoid.foot_indices)
        rules["fall_contact"] = np.any(lowest_points[:, bodies] < config.contact_height, axis=-1)
    armed = episode_frames >= config.grace_frames
    terminated = np.zeros(len(episode_frames), dtype=bool)
    for k in rules:
        rules[k] &= armed
        terminated |= rules[k]
    return terminated, rules
