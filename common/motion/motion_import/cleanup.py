"""Clean-up of clips (imported or DeepMimic): trim, left-right mirror, ground fix and loop mode.

All functions take and return :class:`~common.motion.motion.Clip` keyframes in the project's frame (Z up, the character
facing +X with its left at +Y).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from common.character.humanoid import DEEPMIMIC_JOINTS, BodyGeometry, Humanoid, mirror_name
from common.motion.library import MotionLibrary
from common.motion.motion import LOOP_MODES, Clip

STANCE_SPEED = 0.2  # m/s: a foot slower than this is taken to be standing on the ground


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


def _mirror_quat(q: np.ndarray) -> np.ndarray:
    """Reflection through the XZ plane: M R M with M = diag(1, -1, 1) is (w, x, y, z) -> (w, -x, y, -z)."""
    return q * np.array([1.0, -1.0, 1.0, -1.0])


def mirror(clip: Clip) -> Clip:
    """Left-right mirror (as DeepMimic's ``_mirror`` clips): reflected through the character's sagittal plane
    (y -> -y) with every left joint's rotation swapped for its right twin's. Mirroring twice is the identity."""
    names = [n for n, _, _ in DEEPMIMIC_JOINTS]
    swap = [names.index(mirror_name(n)) for n in names]
    root_pos = clip.root_pos * np.array([1.0, -1.0, 1.0])
    return replace(clip, name=clip.name, root_pos=root_pos, root_rot=_mirror_quat(clip.root_rot),
                   joint_rot=_mirror_quat(clip.joint_rot[:, swap]))  # fmt: skip


def set_loop(clip: Clip, mode: str) -> Clip:
    """``wrap`` (cyclic: the library closes and continues the loop) or ``none`` (one-shot)."""
    if mode not in LOOP_MODES:
        raise ValueError(f"loop must be one of {LOOP_MODES}, got {mode!r}")
    return replace(clip, loop=mode == "wrap")


@dataclass(frozen=True)
class FootContact:
    """Feet of a clip on the control-rate grid.

    Attributes:
        height: Lowest point of each foot above the ground. Shape: (T, 2).
        speed: Speed of each foot's origin (the ankle). Shape: (T, 2).
    """

    height: np.ndarray
    speed: np.ndarray

    @property
    def stance(self) -> np.ndarray:
        """Frames at which each foot is slower than :data:`STANCE_SPEED`. Shape: (T, 2), bool."""
        return self.speed < STANCE_SPEED


def foot_contact(clip: Clip, humanoid: Humanoid) -> FootContact:
    """Foot heights and speeds of a clip, from the motion library's MuJoCo kinematics (played one-shot)."""
    library = MotionLibrary.from_clips([replace(clip, loop=False)], humanoid)
    frames = library.frames
    height = BodyGeometry(humanoid).lowest_points(frames.body_pos, frames.body_rot)[:, humanoid.foot_indices]
    speed = np.linalg.norm(frames.body_linvel[:, humanoid.foot_indices], axis=-1)
    return FootContact(height, speed)


def fix_ground(clip: Clip, humanoid: Humanoid) -> tuple[Clip, float]:
    """Lifts or lowers the whole clip so that its feet rest on the floor in stance.

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
