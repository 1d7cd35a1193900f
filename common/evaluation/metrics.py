"""Tracking metrics shared by the SuperTrack and PPO evaluations.

Every function takes simulated and reference arrays with arbitrary leading dims (``(T,)``, ``(N,)``,
``(T, N)``, ...) and returns one value per entry of those leading dims: reductions run over bodies or
dofs only, never over time or episodes, so the evaluator decides how to aggregate (see :func:`summarise`).

Shape letters: T frames, B bodies, D dofs; ``...`` stands for any leading dims. Simulated and reference
arrays must broadcast against each other. Quaternions are (w, x, y, z); positions are in metres.

The success criterion follows the UHC/PHC protocol: an episode succeeds when the per-frame mean body
position error never exceeds 0.5 m over the whole clip. The evaluator must also count an episode that the
environment terminated early as failed; it passes that in through ``success(..., terminated=...)``.

**Motion quality.** :func:`velocity_error_mm`, :func:`acceleration_error_mm`, :func:`foot_slide_mm` and
:func:`target_jitter` take a time axis (consecutive frames of one episode, at the control rate) and return one value
per first or second finite difference along it (T - 1 or T - 2 values), again never averaging over time. Differences
are per frame, not per second: a velocity in mm/frame, an acceleration in mm/frame^2, as UHC and PHC report them (at
the control rate here, 60 Hz; at 30 fps the same smooth motion gives twice the velocity and four times the
acceleration figure). World frame, Z up.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from common.maths.rotations import quat_geodesic_angle

__all__ = [
    "DEFAULT_MAX_FRAMES",
    "FOOT_CONTACT_HEIGHT_M",
    "METRICS",
    "METRIC_NAMES",
    "SUCCESS_THRESHOLD_M",
    "MetricInfo",
    "acceleration_error_mm",
    "best_index",
    "body_rot_error_rad",
    "contact_mean",
    "episode_length_ratio",
    "foot_slide_mm",
    "joint_vel_error",
    "mean_body_pos_error_m",
    "mpjpe_global_mm",
    "mpjpe_local_mm",
    "root_ang_vel_error",
    "root_lin_vel_error",
    "root_pos_error_m",
    "root_rot_error_rad",
    "success",
    "summarise",
    "target_jitter",
    "velocity_error_mm",
]

SUCCESS_THRESHOLD_M = 0.5
"""UHC/PHC failure threshold on the per-frame mean body position error, in metres."""

DEFAULT_MAX_FRAMES = 512
"""Episode length (frames) that :func:`episode_length_ratio` divides by unless told otherwise."""

FOOT_CONTACT_HEIGHT_M = 0.02
"""A foot touches the ground while the lowest point of its collision geom is less than this (metres) above it (on a
clip's terrain: the least gap between the geom and the terrain under it, measured by the evaluator with
:func:`common.sim.terrain.ground_clearance`), for the simulated character and the reference alike. The reference's
planted feet float up to about 2.5 cm (walk's push-off) and sink up to 6 cm into the floor; a simulated planted foot
sits within a few millimetres of it."""


@dataclass(frozen=True)
class MetricInfo:
    """How one logged metric is named, measured and ranked.

    Attributes:
        key: Name used in logs and in the comparison report.
        unit: Unit of the value (empty for dimensionless ratios).
        higher_is_better: True when a larger value is a better tracker.
        description: One-line meaning of the metric.
        ranked: False for a figure of the reference itself (the same for every tracker), which ranks no tracker.
    """

    key: str
    unit: str
    higher_is_better: bool
    description: str
    ranked: bool = True

    @property
    def direction(self) -> str:
        """Human-readable ranking rule: ``"higher is better"``, ``"lower is better"`` or ``"not ranked"``."""
        if not self.ranked:
            return "not ranked"
        return "higher is better" if self.higher_is_better else "lower is better"


_METRIC_LIST: tuple[MetricInfo, ...] = (
    MetricInfo("mpjpe_g", "mm", False, "mean per-body position error, world frame"),
    MetricInfo("mpjpe_l", "mm", False, "mean per-body position error relative to each root position"),
    MetricInfo("root_pos_err", "m", False, "root position distance"),
    MetricInfo("root_rot_err", "rad", False, "root orientation geodesic angle"),
    MetricInfo("body_rot_err", "rad", False, "mean body orientation geodesic angle"),
    MetricInfo("joint_vel_err", "rad/s", False, "mean absolute joint (dof) velocity difference"),
    MetricInfo("root_vel_err", "m/s", False, "root linear velocity difference norm"),
    MetricInfo("root_ang_vel_err", "rad/s", False, "root angular velocity difference norm"),
    MetricInfo("accel_err", "mm/frame^2", False, "mean body acceleration error (UHC/PHC), second differences"),
    MetricInfo("vel_err", "mm/frame", False, "mean body velocity error (UHC/PHC), first differences"),
    MetricInfo("foot_slide", "mm/frame", False, "mean horizontal foot speed while the foot touches the ground"),
    MetricInfo("foot_slide_ref", "mm/frame", False, "the same for the reference: the clip's own sliding", False),
    MetricInfo("target_jitter", "rad/frame^2", False, "mean absolute second difference of the policy's PD targets"),
    MetricInfo("mpjpe_g_succ", "mm", False, "MPJPE-g over the episodes that succeed (PHC/UHC; read with success)"),
    MetricInfo("mpjpe_l_succ", "mm", False, "MPJPE-l over the episodes that succeed (PHC/UHC; read with success)"),
    MetricInfo("success", "fraction", True, "episodes whose mean body error never exceeds 0.5 m"),
    MetricInfo("episode_len_ratio", "", True, "episode length divided by the maximum length"),
    MetricInfo("survival", "fraction", True, "episodes whose failure rule never fired over the horizon (SuperTrack)"),
)

METRICS: dict[str, MetricInfo] = {m.key: m for m in _METRIC_LIST}
"""Registry of every logged metric, keyed by its log name, in report order."""

METRIC_NAMES: tuple[str, ...] = tuple(METRICS)
"""Log keys of every metric, in report order."""


def best_index(key: str, values: ArrayLike) -> int:
    """Index of the best value of one metric across trackers (one report row).

    NaN values never win; ties go to the first occurrence.

    Args:
        key: Metric key from :data:`METRIC_NAMES`.
        values: One value per tracker, shape (K,).

    Returns:
        Index in ``values`` of the best value.

    Raises:
        KeyError: If ``key`` is not a registered metric.
        ValueError: If ``values`` is empty or all NaN, or the metric is not ranked (a figure of the reference).
    """
    info = METRICS[key]
    if not info.ranked:
        raise ValueError(f"metric {key!r} describes the reference and ranks no tracker")
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if v.size == 0 or np.all(np.isnan(v)):
        raise ValueError(f"no finite value to rank for metric {key!r}")
    return int(np.nanargmax(v) if info.higher_is_better else np.nanargmin(v))


def _as_vectors(sim: ArrayLike, ref: ArrayLike, width: int, name: str) -> tuple[NDArray, NDArray]:
    """Convert to float64 and check the trailing dim and broadcast compatibility."""
    s = np.asarray(sim, dtype=np.float64)
    r = np.asarray(ref, dtype=np.float64)
    for arr, who in ((s, "sim"), (r, "ref")):
        if arr.ndim < 1 or arr.shape[-1] != width:
            raise ValueError(f"{name}: {who} must have a trailing dim of {width}, got shape {arr.shape}")
    try:
        np.broadcast_shapes(s.shape, r.shape)
    except ValueError as err:
        raise ValueError(f"{name}: shapes {s.shape} and {r.shape} do not broadcast") from err
    return s, r


def _as_body_arrays(sim: ArrayLike, ref: ArrayLike, width: int, name: str) -> tuple[NDArray, NDArray]:
    """Like :func:`_as_vectors` but also require a body dim before the trailing one."""
    s, r = _as_vectors(sim, ref, width, name)
    if s.ndim < 2 or r.ndim < 2:
        raise ValueError(f"{name}: expected (..., B, {width}) arrays, got {s.shape} and {r.shape}")
    return s, r


def mean_body_pos_error_m(sim_body_pos: ArrayLike, ref_body_pos: ArrayLike) -> NDArray[np.float64]:
    """Mean over bodies of the world-frame Euclidean body position error.

    This is the quantity the success criterion thresholds (see :func:`success`).

    Args:
        sim_body_pos: Simulated body positions in metres, shape (..., B, 3).
        ref_body_pos: Reference body positions in metres, shape (..., B, 3).

    Returns:
        Mean body distance in metres, shape (...).
    """
    s, r = _as_body_arrays(sim_body_pos, ref_body_pos, 3, "mean_body_pos_error_m")
    return np.linalg.norm(s - r, axis=-1).mean(axis=-1)


def mpjpe_global_mm(sim_body_pos: ArrayLike, ref_body_pos: ArrayLike) -> NDArray[np.float64]:
    """Global mean per-joint position error (MPJPE-g): world-frame body distance averaged over bodies.

    Args:
        sim_body_pos: Simulated body positions in metres, shape (..., B, 3).
        ref_body_pos: Reference body positions in metres, shape (..., B, 3).

    Returns:
        MPJPE-g in millimetres, shape (...).
    """
    return 1000.0 * mean_body_pos_error_m(sim_body_pos, ref_body_pos)


def mpjpe_local_mm(sim_body_pos: ArrayLike, ref_body_pos: ArrayLike, root_index: int = 0) -> NDArray[np.float64]:
    """Root-relative mean per-joint position error (MPJPE-l).

    Each character is translated so that its own root body sits at the origin (translation only, no
    rotation alignment, as in the UHC/PHC MPJPE-l); the root itself counts in the mean with error 0.

    Args:
        sim_body_pos: Simulated body positions in metres, shape (..., B, 3).
        ref_body_pos: Reference body positions in metres, shape (..., B, 3).
        root_index: Index of the root body along the B dim.

    Returns:
        MPJPE-l in millimetres, shape (...).

    Raises:
        IndexError: If ``root_index`` is out of range for B.
    """
    s, r = _as_body_arrays(sim_body_pos, ref_body_pos, 3, "mpjpe_local_mm")
    n_bodies = np.broadcast_shapes(s.shape, r.shape)[-2]
    if not -n_bodies <= root_index < n_bodies:
        raise IndexError(f"root_index {root_index} out of range for {n_bodies} bodies")
    # Keep the body dim (None) so the root broadcasts over all B bodies.
    s_local = s - s[..., root_index, None, :]
    r_local = r - r[..., root_index, None, :]
    return 1000.0 * np.linalg.norm(s_local - r_local, axis=-1).mean(axis=-1)


def root_pos_error_m(sim_root_pos: ArrayLike, ref_root_pos: ArrayLike) -> NDArray[np.float64]:
    """Euclidean distance between simulated and reference root positions.

    Args:
        sim_root_pos: Simulated root position in metres, shape (..., 3).
        ref_root_pos: Reference root position in metres, shape (..., 3).

    Returns:
        Root distance in metres, shape (...).
    """
    s, r = _as_vectors(sim_root_pos, ref_root_pos, 3, "root_pos_error_m")
    return np.linalg.norm(s - r, axis=-1)


def root_rot_error_rad(sim_root_rot: ArrayLike, ref_root_rot: ArrayLike) -> NDArray[np.float64]:
    """Geodesic angle between simulated and reference root orientations (sign-invariant).

    Args:
        sim_root_rot: Simulated root quaternion (w, x, y, z), shape (..., 4).
        ref_root_rot: Reference root quaternion (w, x, y, z), shape (..., 4).

    Returns:
        Angle of ``sim * inv(ref)`` in radians, in [0, pi], shape (...).
    """
    s, r = _as_vectors(sim_root_rot, ref_root_rot, 4, "root_rot_error_rad")
    return np.asarray(quat_geodesic_angle(s, r), dtype=np.float64)


def body_rot_error_rad(sim_body_rot: ArrayLike, ref_body_rot: ArrayLike) -> NDArray[np.float64]:
    """Mean over bodies of the geodesic angle between simulated and reference body orientations.

    Args:
        sim_body_rot: Simulated body quaternions (w, x, y, z), shape (..., B, 4).
        ref_body_rot: Reference body quaternions (w, x, y, z), shape (..., B, 4).

    Returns:
        Mean body angle error in radians, shape (...).
    """
    s, r = _as_body_arrays(sim_body_rot, ref_body_rot, 4, "body_rot_error_rad")
    return np.asarray(quat_geodesic_angle(s, r), dtype=np.float64).mean(axis=-1)


def joint_vel_error(sim_dof_vel: ArrayLike, ref_dof_vel: ArrayLike) -> NDArray[np.float64]:
    """Mean over dofs of the absolute joint velocity difference.

    Args:
        sim_dof_vel: Simulated joint (dof) velocities in rad/s, shape (..., D).
        ref_dof_vel: Reference joint (dof) velocities in rad/s, shape (..., D).

    Returns:
        Mean absolute difference in rad/s, shape (...).
    """
    s = np.asarray(sim_dof_vel, dtype=np.float64)
    r = np.asarray(ref_dof_vel, dtype=np.float64)
    if s.ndim < 1 or r.ndim < 1:
        raise ValueError(f"joint_vel_error: expected (..., D) arrays, got {s.shape} and {r.shape}")
    return np.abs(s - r).mean(axis=-1)


def root_lin_vel_error(sim: ArrayLike, ref: ArrayLike) -> NDArray[np.float64]:
    """Norm of the difference between simulated and reference root linear velocities.

    Args:
        sim: Simulated root linear velocity in m/s, shape (..., 3).
        ref: Reference root linear velocity in m/s, shape (..., 3).

    Returns:
        Velocity error in m/s, shape (...).
    """
    s, r = _as_vectors(sim, ref, 3, "root_lin_vel_error")
    return np.linalg.norm(s - r, axis=-1)


def root_ang_vel_error(sim: ArrayLike, ref: ArrayLike) -> NDArray[np.float64]:
    """Norm of the difference between simulated and reference root angular velocities.

    Both must be expressed in the same frame (world or root-local) by the caller.

    Args:
        sim: Simulated root angular velocity in rad/s, shape (..., 3).
        ref: Reference root angular velocity in rad/s, shape (..., 3).

    Returns:
        Angular velocity error in rad/s, shape (...).
    """
    s, r = _as_vectors(sim, ref, 3, "root_ang_vel_error")
    return np.linalg.norm(s - r, axis=-1)


def _time_diff(x: NDArray, order: int, time_axis: int, name: str) -> NDArray:
    """The ``order``-th finite difference along ``time_axis`` (negative), checking there are enough frames."""
    if x.ndim < -time_axis or x.shape[time_axis] <= order:
        raise ValueError(f"{name}: need more than {order} frames along axis {time_axis}, got shape {x.shape}")
    return np.diff(x, n=order, axis=time_axis)


def velocity_error_mm(sim_body_pos: ArrayLike, ref_body_pos: ArrayLike) -> NDArray[np.float64]:
    """Velocity error (UHC/PHC): mean over bodies of ``|v_sim - v_ref|``, with ``v[t] = p[t] - p[t - 1]``.

    Args:
        sim_body_pos: Simulated body positions in metres over consecutive frames of one episode, shape (..., T, B, 3).
        ref_body_pos: Reference body positions in metres, shape (..., T, B, 3).

    Returns:
        Velocity error in mm/frame, one value per frame pair (t - 1, t), shape (..., T - 1).
    """
    s, r = _as_body_arrays(sim_body_pos, ref_body_pos, 3, "velocity_error_mm")
    dv = _time_diff(s, 1, -3, "velocity_error_mm") - _time_diff(r, 1, -3, "velocity_error_mm")
    return 1000.0 * np.linalg.norm(dv, axis=-1).mean(axis=-1)


def acceleration_error_mm(sim_body_pos: ArrayLike, ref_body_pos: ArrayLike) -> NDArray[np.float64]:
    """Acceleration error (UHC/PHC): mean over bodies of ``|a_sim - a_ref|``, with
    ``a[t] = p[t] - 2 p[t - 1] + p[t - 2]``.

    Args:
        sim_body_pos: Simulated body positions in metres over consecutive frames of one episode, shape (..., T, B, 3).
        ref_body_pos: Reference body positions in metres, shape (..., T, B, 3).

    Returns:
        Acceleration error in mm/frame^2, one value per frame triple (t - 2, t - 1, t), shape (..., T - 2).
    """
    s, r = _as_body_arrays(sim_body_pos, ref_body_pos, 3, "acceleration_error_mm")
    da = _time_diff(s, 2, -3, "acceleration_error_mm") - _time_diff(r, 2, -3, "acceleration_error_mm")
    return 1000.0 * np.linalg.norm(da, axis=-1).mean(axis=-1)


def foot_slide_mm(
    foot_pos: ArrayLike, foot_height: ArrayLike, threshold_m: float = FOOT_CONTACT_HEIGHT_M
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Horizontal displacement of each foot from one frame to the next, and whether it touched the floor at both.

    A foot touches the floor at a frame while its lowest point is less than ``threshold_m`` above the ground (the
    caller measures ``foot_height`` from the ground: z on the flat floor, the clearance above a clip's terrain); a
    step counts as sliding only when the foot touches at both of its frames. Average the displacements over the steps
    in contact with :func:`contact_mean` (a foot in the air slides by definition never).

    Args:
        foot_pos: Foot body positions in metres over consecutive frames of one episode (Z up), shape (..., T, F, 3).
        foot_height: Height of each foot's lowest point above the ground in metres, shape (..., T, F).
        threshold_m: Contact height.

    Returns:
        (slide, contact): the horizontal (x, y) displacement in mm/frame of every foot and step, shape
        (..., T - 1, F), and whether that foot touched the floor at both ends of the step, bool, shape (..., T - 1, F).
    """
    p = np.asarray(foot_pos, dtype=np.float64)
    h = np.asarray(foot_height, dtype=np.float64)
    if p.ndim < 3 or p.shape[-1] != 3 or h.shape != p.shape[:-1]:
        raise ValueError(f"foot_slide_mm: expected (..., T, F, 3) positions and (..., T, F) heights, got {p.shape}"
                         f" and {h.shape}")  # fmt: skip
    slide = 1000.0 * np.linalg.norm(_time_diff(p[..., :2], 1, -3, "foot_slide_mm"), axis=-1)
    touch = h < threshold_m
    return slide, touch[..., 1:, :] & touch[..., :-1, :]


def contact_mean(slide_sum: ArrayLike, contact_count: ArrayLike, valid: ArrayLike) -> float:
    """Mean over the (foot, step) pairs in contact of the frames marked valid: ``sum(slide) / count``.

    Args:
        slide_sum: Per step, the summed slide of the feet in contact (see :func:`foot_slide_mm`), e.g. shape (T, N).
        contact_count: Per step, how many feet were in contact, same shape.
        valid: Which steps count, bool, same shape.

    Returns:
        The mean slide (in the unit of ``slide_sum``); NaN when no foot touched the floor in a valid step.
    """
    s = np.asarray(slide_sum, dtype=np.float64)
    c = np.asarray(contact_count, dtype=np.float64)
    mask = np.asarray(valid, dtype=bool)
    if s.shape != mask.shape or c.shape != mask.shape:
        raise ValueError(f"contact_mean: shapes {s.shape}, {c.shape} and valid {mask.shape} differ")
    count = float(np.sum(c, where=mask))
    return float(np.sum(s, where=mask) / count) if count > 0 else float("nan")


def target_jitter(pd_targets: ArrayLike) -> NDArray[np.float64]:
    """PD-target jitter: mean over actuators of ``|q*[t] - 2 q*[t - 1] + q*[t - 2]|``, the targets' second difference.

    Args:
        pd_targets: The policy's PD targets (hinge angles in rad) over consecutive frames of one episode,
            shape (..., T, nu).

    Returns:
        Jitter in rad/frame^2, one value per frame triple (t - 2, t - 1, t), shape (..., T - 2).
    """
    q = np.asarray(pd_targets, dtype=np.float64)
    if q.ndim < 2:
        raise ValueError(f"target_jitter: expected (..., T, nu) targets, got shape {q.shape}")
    return np.abs(_time_diff(q, 2, -2, "target_jitter")).mean(axis=-1)


def success(
    mean_body_err_m_per_frame: ArrayLike,
    valid: ArrayLike | None = None,
    threshold_m: float = SUCCESS_THRESHOLD_M,
    terminated: ArrayLike | None = None,
) -> NDArray[np.bool_]:
    """UHC/PHC success: the per-frame mean body position error never exceeds the threshold.

    An error exactly equal to the threshold still passes; a NaN error in a valid frame fails. Frames
    marked invalid (padding of episodes shorter than T) are ignored. The evaluator must also count an
    episode that the environment terminated early (fall, divergence) as failed, because the frames it
    did not play were never tracked: pass those episodes as ``terminated=True``.

    Args:
        mean_body_err_m_per_frame: Mean body position error in metres per frame (see
            :func:`mean_body_pos_error_m`), shape (..., T).
        valid: Which frames exist, bool, shape (..., T); None means every frame is valid.
        threshold_m: Largest allowed per-frame error in metres.
        terminated: Whether each episode ended early, bool, shape (...); True forces failure.
            None means no episode terminated early.

    Returns:
        Per-episode success, bool, shape (...).
    """
    err = np.asarray(mean_body_err_m_per_frame, dtype=np.float64)
    if err.ndim < 1:
        raise ValueError("success: expected a (..., T) array of per-frame errors")
    # NaN <= threshold is False, so a diverged valid frame fails.
    frame_ok = err <= threshold_m
    if valid is not None:
        mask = np.asarray(valid, dtype=bool)
        if mask.shape != err.shape:
            raise ValueError(f"success: valid shape {mask.shape} != error shape {err.shape}")
        frame_ok = frame_ok | ~mask
    ok = np.all(frame_ok, axis=-1)
    if terminated is not None:
        term = np.asarray(terminated, dtype=bool)
        ok = ok & ~np.broadcast_to(term, ok.shape)
    return np.asarray(ok, dtype=bool)


def episode_length_ratio(length_frames: ArrayLike, max_frames: int = DEFAULT_MAX_FRAMES) -> NDArray[np.float64]:
    """Fraction of the maximum episode length that was played: ``clip(length / max_frames, 0, 1)``.

    Args:
        length_frames: Episode lengths in frames, any shape (...).
        max_frames: Maximum episode length in frames (> 0).

    Returns:
        Length ratio in [0, 1], shape (...).

    Raises:
        ValueError: If ``max_frames`` is not positive.
    """
    if max_frames <= 0:
        raise ValueError(f"max_frames must be positive, got {max_frames}")
    return np.clip(np.asarray(length_frames, dtype=np.float64) / float(max_frames), 0.0, 1.0)


def summarise(per_frame: Mapping[str, ArrayLike], valid: ArrayLike) -> dict[str, float]:
    """Masked mean of every per-frame metric over the valid frames.

    Every frame counts once, so longer episodes weigh more than shorter ones (frame-weighted mean, as
    MPJPE is usually reported). A metric with no valid frame summarises to NaN.

    Args:
        per_frame: Metric key -> per-frame values, each of the same shape as ``valid``, e.g. (N, T).
        valid: Which frames exist, bool, same shape as every metric array.

    Returns:
        Metric key -> mean over valid frames, as a Python float.

    Raises:
        ValueError: If a metric's shape differs from ``valid``'s.
    """
    mask = np.asarray(valid, dtype=bool)
    n_valid = int(mask.sum())
    out: dict[str, float] = {}
    for key, values in per_frame.items():
        v = np.asarray(values, dtype=np.float64)
        if v.shape != mask.shape:
            raise ValueError(f"summarise: metric {key!r} has shape {v.shape}, valid has {mask.shape}")
        # where= keeps NaN/inf in invalid (padding) frames out of the sum.
        out[key] = float(np.sum(v, where=mask) / n_valid) if n_valid > 0 else float("nan")
    return out
