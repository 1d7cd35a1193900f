"""``mimic-motions import`` and ``render``: a BVH take (or any clip the library reads) to a clean clip file.

Import: read (BVH -> retarget onto the humanoid; a DeepMimic clip, a bundled name or a clip pack as they are), then
trim, mirror, fix the ground and set the loop mode, in that order; write a DeepMimic ``.txt`` or a motion dataset
``.h5`` (what ``mimic-motions convert`` writes), either of which every command loads like a bundled clip.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from common.character.humanoid import Humanoid
from common.motion.dataset import resolve_clips, save_dataset
from common.motion.library import MotionLibrary
from common.motion.motion import Clip, MotionFormatError
from common.motion.motion_import import cleanup
from common.motion.motion_import.bvh import read_bvh
from common.motion.motion_import.deepmimic import check_writable, write_deepmimic
from common.motion.motion_import.joint_map import load_joint_map
from common.motion.motion_import.retarget import RetargetOptions, retarget


@dataclass(frozen=True)
class ImportOptions:
    """What ``mimic-motions import`` does besides reading.

    Attributes:
        joint_map: Joint map preset or YAML file (BVH only).
        retarget: Units, up axis and root scaling (BVH only).
        trim: (start, end) in seconds of the source, or None.
        mirror: Left-right mirror.
        fix_ground: Shift the clip so that the feet rest on the floor in stance, and lift it out where a stance foot is
            still under the floor (:func:`~common.motion.motion_import.cleanup.fix_ground`).
        loop: ``"wrap"`` or ``"none"``; None keeps the source's (BVH: none).
        name: Clip name; None: the file stem.
    """

    joint_map: str = "cmu"
    retarget: RetargetOptions = RetargetOptions()
    trim: tuple[float, float] | None = None
    mirror: bool = False
    fix_ground: bool = False
    loop: str | None = None
    name: str | None = None


def import_clip(spec: str, humanoid: Humanoid, options: ImportOptions) -> tuple[Clip, list[str]]:
    """Reads, retargets and cleans one clip; returns it with lines describing what was done.

    Raises:
        MotionFormatError: an unreadable or malformed input, a joint map that does not fit it, or a clip that the
            loaders would refuse (one frame, a frame time or root position beyond :mod:`common.motion.limits`, shorter
            than one control step): what is returned, :func:`write_clip` writes and every loader reads.
        ValueError: an option that does not fit the clip (e.g. a trim that leaves no frames).
    """
    notes = []
    if spec.lower().endswith(".bvh"):
        bvh = read_bvh(spec)
        joint_map = load_joint_map(options.joint_map, humanoid.body_names)
        try:
            result = retarget(bvh, humanoid, joint_map, options.retarget, name=options.name)
        except MotionFormatError as e:  # some name the joint map or a bone only: name the take too
            raise (e if bvh.source in str(e) else MotionFormatError(f"{bvh.source}: {e}")) from None
        clip = result.clip
        check_playable(clip, humanoid)  # a take of one frame, or 900 m away, is refused here rather than written
        notes += [f"read {spec}: {len(bvh.joints)} joints, {bvh.num_frames} frames at {1 / bvh.frame_time:.1f} fps",
                  result.report()]  # fmt: skip
    else:
        clips = resolve_clips([spec])
        if len(clips) != 1:
            raise MotionFormatError(f"{spec}: holds {len(clips)} clips; import takes one")
        clip = replace(clips[0], name=options.name or clips[0].name)
        notes.append(f"read {clip.source}: {clip.num_keyframes} keyframes, {clip.duration:.3f} s")
    if options.trim is not None:
        clip = cleanup.trim(clip, *options.trim)
        notes.append(f"trimmed to {options.trim[0]:g}..{options.trim[1]:g} s: {clip.num_keyframes} keyframes")
    if options.mirror:
        clip = cleanup.mirror(clip)
        notes.append("mirrored left-right")
    if options.fix_ground:
        clip, ground = cleanup.fix_ground(clip, humanoid)
        notes.append(ground.report())
    if options.loop is not None:
        clip = cleanup.set_loop(clip, options.loop)
    check_playable(clip, humanoid)
    return clip, notes


def check_playable(clip: Clip, humanoid: Humanoid) -> None:
    """Raises, naming ``clip.source``, what a loader would refuse in the clip as written: what the DeepMimic reader
    refuses (:func:`~common.motion.motion_import.deepmimic.check_writable`), and a one-shot clip shorter than one
    control step, which the motion library cannot put on its grid."""
    check_writable(clip)
    if not clip.loop and clip.duration < humanoid.physics.control_dt:
        raise MotionFormatError(f"{clip.source}: the clip lasts {clip.duration:.4g} s, shorter than one control step "
                                f"({humanoid.physics.control_dt:.4g} s): no command could play it")  # fmt: skip


def write_clip(path: str | Path, clip: Clip, humanoid: Humanoid) -> None:
    """``.txt``: a DeepMimic clip; ``.h5``: a one-clip motion dataset at the humanoid's control rate."""
    path = Path(path)
    if path.suffix in (".txt", ".h5"):
        path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".txt":
        write_deepmimic(path, clip)
    elif path.suffix == ".h5":
        save_dataset(path, MotionLibrary.from_clips([clip], humanoid), humanoid)
    else:
        raise MotionFormatError(f"{path}: output must be a DeepMimic .txt or a motion dataset .h5")


def playback_qpos(library: MotionLibrary, clip: int, seconds: float | None = None) -> np.ndarray:
    """The clip's qpos on the control grid for kinematic playback: one-shot clips to their end, wrap clips for
    ``seconds`` (default one cycle), continued by the library. Shape: (T, nq)."""
    if library.loop[clip]:
        frames = int(round((seconds or library.duration[clip]) / library.dt)) + 1
    else:
        frames = int(library.num_frames[clip])
        if seconds is not None:
            frames = min(frames, int(round(seconds / library.dt)) + 1)
    times = np.arange(frames) * library.dt
    return library.query(np.full(frames, clip), times).qpos
