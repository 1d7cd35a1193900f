"""A tracking policy's observation (the PPO tracker's and the gymnasium wrapper's): named features, flattened in a
fixed order, with their layout.

``parc`` (the default; PARC's motion tracker observes simulated-minus-reference features and several future
reference frames): everything in the simulated root's *heading frame* H (rotated by the root's yaw about +Z, origin
under the root on the ground), so that a shift along the ground or a turn about the vertical changes nothing:
- ``sim_pos``: H^-1 (x_b - root_xy), heights kept (B, 3); ``sim_rot``: two-axis of H^-1 q_b (B, 6, carries the
  tilt, i.e. gravity); ``sim_vel``, ``sim_angvel``: H^-1 v_b, H^-1 w_b (B, 3); ``dof_pos``, ``dof_vel``: the hinges.
- for every offset k of ``future_frames`` (reference at t + k dt): ``ref{k}_pos``: H^-1 (x_b^sim - x_b^ref);
  ``ref{k}_rot``: two-axis of H^-1 q_b^sim (q_b^ref)^-1 H, the turn from the reference body to the simulated one;
  ``ref{k}_dof_pos``: hinge angles sim - ref. The first offset also has ``ref{k}_vel``, ``ref{k}_angvel`` and
  ``ref{k}_dof_vel`` (sim - ref); later frames' velocities follow from the spacing of their positions.

``local`` (the previous default): :func:`common.sim.features.tracking_observation` (Local() of both characters, the
reference root in the simulated root's frame, the clip phase).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np

from common.character.humanoid import Humanoid
from common.character.state import CharacterState
from common.maths.rotations import quat_conj, quat_from_yaw, quat_mul, quat_rotate, quat_to_two_axis, quat_yaw
from common.motion.library import MotionLibrary
from common.sim.features import OBSERVATION_KEYS, tracking_observation
from common.sim.gym import StepResult


@dataclass(frozen=True)
class ObservationConfig:
    """What a tracking policy sees (this module).

    Attributes:
        kind: ``parc`` (simulated-minus-reference features in the simulated root's heading frame, and future
            reference frames) or ``local`` (Local() of both characters, the reference root one frame ahead, phase).
        future_frames: ``parc``: offsets k (control steps) of the reference frames t + k dt observed, increasing;
            the first one also gives the velocity errors.
    """

    kind: Literal["parc", "local"] = "parc"
    future_frames: tuple[int, ...] = (1, 2, 4, 8, 16)

    def __post_init__(self) -> None:
        k = self.future_frames
        if not k or min(k) < 1 or list(k) != sorted(set(k)):
            raise ValueError(f"future_frames must be distinct positive offsets in increasing order, got {list(k)}")


def parc_features(sim: CharacterState, refs: Mapping[int, CharacterState], hinge_qpos: np.ndarray,
                  hinge_dof: np.ndarray) -> dict[str, np.ndarray]:  # fmt: skip
    """Named ``parc`` features (see the module docstring) of N characters, each flattened to (N, k).

    Args:
        sim: Simulated state at t, leading shape (N,).
        refs: Reference state at t + k dt for every offset k, in order; the first also gives velocity errors.
        hinge_qpos: qpos index of every actuated hinge. Shape: (nu,).
        hinge_dof: qvel index of every actuated hinge. Shape: (nu,).
    """
    n = sim.body_pos.shape[0]
    heading = quat_from_yaw(quat_yaw(sim.body_rot[:, 0]))[:, None]  # (N, 1, 4)
    inv = quat_conj(heading)
    origin = sim.body_pos[:, :1] * np.array([1.0, 1.0, 0.0])

    def vec(v: np.ndarray) -> np.ndarray:
        return quat_rotate(inv, v).reshape(n, -1)

    def rot(q: np.ndarray) -> np.ndarray:
        return quat_to_two_axis(q).reshape(n, -1)

    dof_pos, dof_vel = sim.qpos[:, hinge_qpos], sim.qvel[:, hinge_dof]
    out = {
        "sim_pos": vec(sim.body_pos - origin), "sim_rot": rot(quat_mul(inv, sim.body_rot)),
        "sim_vel": vec(sim.body_linvel), "sim_angvel": vec(sim.body_angvel), "dof_pos": dof_pos, "dof_vel": dof_vel,
    }  # fmt: skip
    for i, (k, ref) in enumerate(refs.items()):
        out[f"ref{k}_pos"] = vec(sim.body_pos - ref.body_pos)
        out[f"ref{k}_rot"] = rot(quat_mul(quat_mul(inv, quat_mul(sim.body_rot, quat_conj(ref.body_rot))), heading))
        out[f"ref{k}_dof_pos"] = dof_pos - ref.qpos[:, hinge_qpos]
        if i == 0:
            out[f"ref{k}_vel"] = vec(sim.body_linvel - ref.body_linvel)
            out[f"ref{k}_angvel"] = vec(sim.body_angvel - ref.body_angvel)
            out[f"ref{k}_dof_vel"] = dof_vel - ref.qvel[:, hinge_dof]
    return out


class Observer:
    """Builds the observation of N characters from the gym's state, querying the future reference frames.

    Args:
        config: Which observation and, for ``parc``, the future frame offsets.
        humanoid: The model (hinge indices).
        library: The clips the characters follow (the clip ids of the gym's results refer to it).
    """

    def __init__(self, config: ObservationConfig, humanoid: Humanoid, library: MotionLibrary) -> None:
        self.config, self.library = config, library
        self.hinge_qpos, self.hinge_dof = humanoid.hinge_qpos, humanoid.hinge_dof

    def features(self, sim: CharacterState, ref_next: CharacterState, phase: np.ndarray, clip: np.ndarray,
                 time: np.ndarray) -> dict[str, np.ndarray]:  # fmt: skip
        """Named features, {name: (N, k)}, in the flat order.

        Args:
            sim: Simulated state at time t, leading shape (N,).
            ref_next: Reference at t + dt (the gym's ``ref_next``).
            phase: Clip phase in [0, 1). Shape: (N,).
            clip: Clip index. Shape: (N,).
            time: Clip time t in seconds. Shape: (N,).
        """
        if self.config.kind == "local":
            named = tracking_observation(sim, ref_next, phase)
            return {k: named[k] for k in OBSERVATION_KEYS}
        dt = self.library.dt
        refs = {k: ref_next if k == 1 else self.library.query(clip, time + k * dt) for k in self.config.future_frames}
        return parc_features(sim, refs, self.hinge_qpos, self.hinge_dof)

    def __call__(self, result: StepResult) -> np.ndarray:
        """Flat observation of the current states of ``result``. Shape: (N, D_obs)."""
        return _flat(self.features(result.sim, result.ref_next, result.phase, result.clip, result.time))

    def final(self, result: StepResult, rows: np.ndarray) -> np.ndarray:
        """Flat observation of the states the step reached (before any reset) of characters ``rows``. (M, D_obs)."""
        return _flat(self.features(result.final_sim[rows], result.final_ref_next[rows], result.final_phase[rows],
                                   result.final_clip[rows], result.final_time[rows]))  # fmt: skip

    def layout(self, result: StepResult) -> dict[str, slice]:
        """Slice of every named feature in the flat observation, measured on ``result``."""
        out, start = {}, 0
        for key, value in self.features(result.sim, result.ref_next, result.phase, result.clip, result.time).items():
            out[key] = slice(start, start + value.shape[-1])
            start += value.shape[-1]
        return out


def _flat(features: dict[str, np.ndarray]) -> np.ndarray:
    return np.concatenate(list(features.values()), axis=-1)
