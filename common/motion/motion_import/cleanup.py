"""Clean-up of clips (imported or DeepMimic): trim, left-right mirror, ground fix and loop mode.

All functions take and return :class:`~common.motion.motion.Clip` keyframes in the project's frame (Z up, the character
facing +X with its left at +Y). The ground fix measures heights above the flat floor, or above a terrain
(:mod:`common.motion.terrain`) when one is given: fitting a clip to a terrain (:mod:`.terrain_fit`) ends with it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from common.character.humanoid import DEEPMIMIC_JOINTS, BodyGeometry, Humanoid, mirror_name
from common.motion.library import MotionLibrary
from common.motion.motion import LOOP_MODES, Clip
from common.motion.terrain import Terrain

STANCE_SPEED = 0.2  # m/s: a foot slower than this is taken to be standing on the ground
GROUND_TOLERANCE = 0.01  # m: a stance foot deeper under the floor than this is lifted out by --fix-ground
LIFT_TO = 0.008  # m under the floor: where a lifted stance foot ends, inside the tolerance by 2 mm for interpolation
LIFT_SPEED = 0.2  # m/s: the most the lift changes the root's vertical speed (walking's own peaks ~0.3 m/s)
LIFT_SMOOTHING = 0.05  # s: half-width of the window that rounds the lift's corners (its acceleration ~4 m/s^2 at most)


def trim(clip: Clip, start: float, end: float) -> Clip:
    """The keyframes with start <= t <= end (seconds), times restarting at 0.

    Raises:
        ValueError: if fewer than two keyframes remain.
    """
    keep = np.flatnonzero((clip.times >= start - 1e-9) & (clip.times <= end + 1e-9))
    if len(keep) < 2:
        raise ValueError(f"{clip.source}: trim {start:g}..{end:g} s keeps {len(keep)} keyframes of a"
                         f" {clip.duration:.3f} s clip; a clip needs at least 2")  # fmt: skip
    return replace(clip, times=clip.times[keep] - clip.times[keep[0]], root_pos=clip.root_pos[keep],
                   root_rot=clip.root_rot[keep], joint_rot=clip.joint_rot[keep])  # fmt: skip


def unroll(clip: Clip, humanoid: Humanoid, cycles: int) -> Clip:
    """A wrap clip played for ``cycles`` cycles as the motion library continues it (each cycle turned and moved on by
    the cycle transform, the loop seam as the library closes it), as a one-shot clip with a keyframe per control
    frame: a walk long enough to climb a flight of stairs.

    Raises:
        ValueError: a one-shot clip, or ``cycles`` < 1.
    """
    from common.character.humanoid import hinges_to_joint_rotations

    if not clip.loop or cycles < 1:
        raise ValueError(f"{clip.source}: only a wrap clip can be unrolled, for 1 cycle or more (got "
                         f"{'a one-shot clip' if not clip.loop else f'{cycles} cycles'})")  # fmt: skip
    library = MotionLibrary.from_clips([clip], humanoid)
    frames = cycles * (int(library.num_frames[0]) - 1) + 1
    times = np.arange(frames) * library.dt
    qpos = library.query(np.zeros(frames, dtype=np.int64), times).qpos
    return replace(clip, loop=False, times=times, root_pos=qpos[:, :3].copy(), root_rot=qpos[:, 3:7].copy(),
                   joint_rot=hinges_to_joint_rotations(humanoid, qpos))  # fmt: skip


def _mirror_quat(q: np.ndarray) -> np.ndarray:
    """Reflection through the XZ plane: M R M with M = diag(1, -1, 1) is (w, x, y, z) -> (w, -x, y, -z)."""
    return q * np.array([1.0, -1.0, 1.0, -1.0])


def mirror(clip: Clip) -> Clip:
    """Left-right mirror (as DeepMimic's ``_mirror`` clips): reflected through the character's sagittal plane
    (y -> -y) with every left joint's rotation swapped for its right twin's. Mirroring twice is the identity.

    A terrain is reflected with the clip (its rows reversed). Its nodes are reflected exactly; inside a cell whose four
    corners are not in one plane the reflected field differs from the reflected surface, because every cell of a
    heightfield is split along the same diagonal (a terrain constant across y, as stairs and slopes, is exact)."""
    names = [n for n, _, _ in DEEPMIMIC_JOINTS]
    swap = [names.index(mirror_name(n)) for n in names]
    root_pos = clip.root_pos * np.array([1.0, -1.0, 1.0])
    terrain = clip.terrain
    if terrain is not None:
        far = terrain.origin[1] + (terrain.shape[0] - 1) * terrain.cell_size
        terrain = Terrain(terrain.heights[::-1].copy(), terrain.cell_size, np.array([terrain.origin[0], -far]))
    return replace(clip, name=clip.name, root_pos=root_pos, root_rot=_mirror_quat(clip.root_rot),
                   joint_rot=_mirror_quat(clip.joint_rot[:, swap]), terrain=terrain)  # fmt: skip


def set_loop(clip: Clip, mode: str) -> Clip:
    """``wrap`` (cyclic: the library closes and continues the loop) or ``none`` (one-shot)."""
    if mode not in LOOP_MODES:
        raise ValueError(f"loop must be one of {LOOP_MODES}, got {mode!r}")
    return replace(clip, loop=mode == "wrap")


@dataclass(frozen=True)
class FootContact:
    """Feet of a clip on the control-rate grid.

    Attributes:
        height: Lowest point of each foot above the ground (the floor, or the terrain under each of the foot's support
            points). Shape: (T, 2).
        speed: Speed of each foot's origin (the ankle). Shape: (T, 2).
    """

    height: np.ndarray
    speed: np.ndarray

    @property
    def stance(self) -> np.ndarray:
        """Frames at which each foot is slower than :data:`STANCE_SPEED`. Shape: (T, 2), bool."""
        return self.speed < STANCE_SPEED


def ground_of(terrain: Terrain | None) -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
    """The ground :meth:`~common.character.humanoid.BodyGeometry.clearance` measures from: the terrain's height, or
    None for the flat floor."""
    return None if terrain is None else terrain.height_at


def foot_contact(clip: Clip, humanoid: Humanoid) -> FootContact:
    """Foot heights above the clip's ground (the floor, or its terrain) and speeds, from the motion library's MuJoCo
    kinematics (played one-shot)."""
    library = MotionLibrary.from_clips([replace(clip, loop=False)], humanoid)
    frames = library.frames
    height = BodyGeometry(humanoid).clearance(frames.body_pos, frames.body_rot, ground_of(clip.terrain))
    height = height[:, humanoid.foot_indices]
    speed = np.linalg.norm(frames.body_linvel[:, humanoid.foot_indices], axis=-1)
    return FootContact(height, speed)


@dataclass(frozen=True)
class GroundFix:
    """What :func:`fix_ground` did.

    Attributes:
        shift: The whole clip's shift in metres (+ = up): minus the median stance-foot height.
        lift: The local lift added on top, per keyframe, metres (>= 0). Shape: (M,).
        deepest: The lowest stance foot before the local lift (after the shift), metres above the ground.
    """

    shift: float
    lift: np.ndarray
    deepest: float

    def report(self) -> str:
        lifted = int(np.count_nonzero(self.lift))
        text = f"ground fixed: moved {self.shift * 100:+.1f} cm"
        if lifted:
            text += (f"; lifted up to {self.lift.max() * 100:.1f} cm over {lifted} keyframes where a stance foot was "
                     f"below -{GROUND_TOLERANCE * 100:g} cm (down to {self.deepest * 100:.1f} cm)")  # fmt: skip
        return text


def fix_ground(clip: Clip, humanoid: Humanoid) -> tuple[Clip, GroundFix]:
    """Puts the feet on the floor in stance: the whole clip shifted (:func:`shift_to_ground`), then lifted where a
    stance foot is still more than :data:`GROUND_TOLERANCE` under the floor (:func:`lift_out_of_floor`).

    The floor is the clip's ground: the flat floor at height 0, or the clip's terrain (heights above it measured
    under each support point of a foot, :meth:`~common.character.humanoid.BodyGeometry.clearance`). On a terrain
    flat at height 0 the result equals the flat floor's bit for bit.

    Returns:
        (the fixed clip, what was done).
    """
    clip, shift = shift_to_ground(clip, humanoid)
    fixed, lift, deepest = lift_out_of_floor(clip, humanoid)
    return fixed, GroundFix(shift, lift, deepest)


def shift_to_ground(clip: Clip, humanoid: Humanoid) -> tuple[Clip, float]:
    """Lifts or lowers the whole clip so that its feet rest on the floor (the clip's ground) in stance.

    The shift is minus the median lowest-point height of the feet over their stance frames (foot speed below
    :data:`STANCE_SPEED`), or over all frames of the lower foot if no foot is ever at rest.

    Returns:
        (the shifted clip, the shift in metres, + = up).
    """
    feet = foot_contact(clip, humanoid)
    stance = feet.height[feet.stance]
    shift = -float(np.median(stance if stance.size else feet.height.min(axis=-1)))
    root_pos = clip.root_pos + np.array([0.0, 0.0, shift])
    return replace(clip, root_pos=root_pos), shift


def lift_out_of_floor(clip: Clip, humanoid: Humanoid, passes: int = 3) -> tuple[Clip, np.ndarray, float]:
    """Lifts the root where a stance foot is more than :data:`GROUND_TOLERANCE` under the floor, smoothly in time.

    One shift for the whole clip leaves a local dip in a recording where it was: a CMU take kept a foot 3 to 5.7 cm
    under the floor for 18 frames. Per control-rate frame, the need d is how far the lowest stance foot is below
    -:data:`LIFT_TO` where it is below -:data:`GROUND_TOLERANCE` (0 elsewhere, so that a clip whose stance feet are
    all within the tolerance is left exactly as it was). The lift is :func:`smooth_lift` of d: never below it, never
    lowering a frame, changing the root's vertical speed by at most :data:`LIFT_SPEED` and 0 beyond the ramps that
    speed needs. Keyframes take it by linear interpolation in time. Lifting changes the feet's speeds a little and so
    which frames are stance: the lift is recomputed on the lifted clip, ``passes`` times at most, until no stance foot
    is below -GROUND_TOLERANCE.

    Returns:
        (the lifted clip, the lift per keyframe in metres (M,), the lowest stance foot before, in metres).
    """
    lift = np.zeros(clip.num_keyframes)
    deepest = 0.0
    dt = humanoid.physics.control_dt
    for i in range(passes):
        feet = foot_contact(clip, humanoid)
        low = np.where(feet.stance, feet.height, np.inf).min(axis=-1)
        if i == 0:
            deepest = float(low.min()) if np.isfinite(low).any() else 0.0
        need = np.where(low < -GROUND_TOLERANCE, -LIFT_TO - low, 0.0)
        if not need.any():
            break
        step = smooth_lift(need, LIFT_SPEED * dt, max(1, int(round(LIFT_SMOOTHING / dt))))
        added = np.interp(clip.times, np.arange(len(step)) * dt, step)
        lift += added
        clip = replace(clip, root_pos=clip.root_pos + added[:, None] * np.array([0.0, 0.0, 1.0]))
    return clip, lift, deepest


def smooth_lift(need: np.ndarray, rise: float, half: int) -> np.ndarray:
    """The lift of :func:`lift_out_of_floor` (and the offset of a terrain fit): a curve never below ``need``,
    changing by at most ``rise`` per frame.

    First the cone envelope c_k = max_j (d_j - rise |k - j|), the lowest curve above d whose slope is at most
    ``rise`` (two running passes); then its running maximum over +-``half`` frames and a Hann window of that
    half-width, which round the cone's corners (at each frame k, every frame of the window around k is >= c_k after
    the maximum, so their weighted mean is too). A maximum and a mean of curves of slope <= ``rise`` keep it.

    Args:
        need: d per frame (any sign; the ground fix's are >= 0, and its lift then too). Shape: (T,).
        rise: The largest change per frame, metres.
        half: Half-width of the rounding, frames.

    Returns:
        The curve per frame, equal to d wherever d is constant over the reach of its ramps and the rounding.
        Shape: (T,).
    """
    cone = need.astype(np.float64).copy()
    for k in range(1, len(cone)):
        cone[k] = max(cone[k], cone[k - 1] - rise)
    for k in range(len(cone) - 2, -1, -1):
        cone[k] = max(cone[k], cone[k + 1] - rise)
    padded = np.pad(cone, half, mode="edge")
    peak = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1).max(axis=-1)
    weights = np.sin(np.pi * np.arange(1, 2 * half + 2) / (2 * half + 2)) ** 2
    weights /= weights.sum()
    return np.convolve(np.pad(peak, half, mode="edge"), weights, mode="valid")
