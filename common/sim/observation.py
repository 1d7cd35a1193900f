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

Terrain features of ``parc`` (PARC's, off by default; both left out of the normaliser, :func:`is_raw_feature`):
- ``heightmap``: the simulated root's height above the ground at a square grid of points around it, turned with its
  heading (spacing ``heightmap_spacing``, out to ``heightmap_extent``; x forward varying fastest, then y left);
  constant on flat ground. (P,), P = (2 extent / spacing + 1)^2.
- ``ref{k}_contacts`` for every offset k of ``contact_frames``: 1 where the reference's body at t + k dt is within
  ``contact_height`` of its clip's ground, else 0 (:func:`common.sim.terrain.contact_labels`). (B,).

``local`` (the previous default): :func:`common.sim.features.tracking_observation` (Local() of both characters, the
reference root in the simulated root's frame, the clip phase).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np

from common.character.humanoid import BodyGeometry, Humanoid
from common.character.state import CharacterState
from common.maths.rotations import quat_conj, quat_from_yaw, quat_mul, quat_rotate, quat_to_two_axis, quat_yaw
from common.motion.library import MotionLibrary
from common.sim.features import OBSERVATION_KEYS, tracking_observation
from common.sim.gym import StepResult
from common.sim.terrain import ClipTerrains, contact_labels, heightmap, heightmap_offsets


@dataclass(frozen=True)
class ObservationConfig:
    """What a tracking policy sees (this module).

    Attributes:
        kind: ``parc`` (simulated-minus-reference features in the simulated root's heading frame, and future
            reference frames) or ``local`` (Local() of both characters, the reference root one frame ahead, phase).
        future_frames: ``parc``: offsets k (control steps) of the reference frames t + k dt observed, increasing;
            the first one also gives the velocity errors.
        heightmap_extent: ``parc``: the heightmap reaches this far (m) from the root along the heading and across it
            (PARC: 1.0); None: no heightmap.
        heightmap_spacing: Distance between the heightmap's points (m; PARC's horizontal scale).
        contact_frames: ``parc``: offsets k of the reference frames whose contact labels are observed, increasing;
            empty: none.
        contact_height: A reference body within this height (m) of the ground is in contact.
    """

    kind: Literal["parc", "local"] = "parc"
    future_frames: tuple[int, ...] = (1, 2, 4, 8, 16)
    heightmap_extent: float | None = None
    heightmap_spacing: float = 0.1
    contact_frames: tuple[int, ...] = ()
    contact_height: float = 0.03

    def __post_init__(self) -> None:
        k = self.future_frames
        if not k or min(k) < 1 or list(k) != sorted(set(k)):
            raise ValueError(f"future_frames must be distinct positive offsets in increasing order, got {list(k)}")
        c = self.contact_frames
        if c and (min(c) < 1 or list(c) != sorted(set(c))):
            raise ValueError(f"contact_frames must be distinct positive offsets in increasing order, got {list(c)}")
        if not (self.heightmap_spacing > 0 and self.contact_height > 0):
            raise ValueError(f"heightmap_spacing and contact_height must be > 0 (m), got {self.heightmap_spacing}, "
                             f"{self.contact_height}")  # fmt: skip
        e = self.heightmap_extent
        if e is not None and not e >= self.heightmap_spacing:
            raise ValueError(f"heightmap_extent must be >= heightmap_spacing ({self.heightmap_spacing} m), got {e}")
        if self.kind != "parc" and (e is not None or c):
            raise ValueError("heightmap_extent and contact_frames are features of the 'parc' observation")


def terrain_feature_widths(config: ObservationConfig, num_bodies: int) -> dict[str, int]:
    """{name: width} of the terrain features ``config`` turns on, in the order they follow the ``parc`` features."""
    out = {}
    if config.heightmap_extent is not None:
        out["heightmap"] = len(heightmap_offsets(config.heightmap_extent, config.heightmap_spacing))
    return out | {f"ref{k}_contacts": num_bodies for k in config.contact_frames}


def is_raw_feature(name: str) -> bool:
    """Features a normaliser leaves as they are: the heightmap (metres) and contact labels (0 or 1), as PARC does."""
    return name == "heightmap" or name.endswith("_contacts")


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
        terrain_features = config.heightmap_extent is not None or bool(config.contact_frames)
        self.terrains = ClipTerrains.of(library) if terrain_features else None
        self.geometry = BodyGeometry(humanoid) if config.contact_frames else None
        self.offsets = (None if config.heightmap_extent is None
                        else heightmap_offsets(config.heightmap_extent, config.heightmap_spacing))  # fmt: skip

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
        out = parc_features(sim, refs, self.hinge_qpos, self.hinge_dof)
        if self.offsets is not None:
            out["heightmap"] = heightmap(self.terrains, clip, sim.body_pos[:, 0], sim.body_rot[:, 0], self.offsets)
        for k in self.config.contact_frames:
            ref = refs[k] if k in refs else ref_next if k == 1 else self.library.query(clip, time + k * dt)
            out[f"ref{k}_contacts"] = contact_labels(self.terrains, clip, self.geometry, ref.body_pos, ref.body_rot,
                                                     self.config.contact_height)  # fmt: skip
        return out

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
