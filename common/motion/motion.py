"""Reading motion clips: DeepMimic ``.txt`` files and the project's compact clip packs.

A clip is kept as its source keyframes (at the source's own, possibly irregular, frame times), already in the
project's frame: Z up, metres, quaternions (w, x, y, z). :mod:`common.motion.library` resamples clips by time
to the control rate and computes everything else.

DeepMimic row layout (44 values): frame duration; root position (3, Y up); root rotation (4); then per joint in
DeepMimic's order a local quaternion (4) for spherical joints or an angle (1, radians about local +z) for knees
and elbows. See ``common/motion/data/README.md``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import h5py
import numpy as np

from common.character.humanoid import DEEPMIMIC_JOINTS
from common.config import hdf5_output
from common.maths.rotations import quat_fix_hemisphere, quat_from_axis_angle, quat_mul
from common.motion import hdf5
from common.motion.errors import MotionFormatError
from common.motion.limits import (
    MAX_CLIP_DURATION,
    MAX_CLIPS,
    MAX_FRAME_DURATION,
    MAX_HINGE_ANGLE,
    MAX_KEYFRAMES,
    MAX_NUMBER_DIGITS,
    MAX_ROOT_DISTANCE,
    MIN_FRAME_DURATION,
    MIN_QUAT_NORM,
    QUAT_NORM_RANGE,
    check_regular_file,
    lengths,
    show_value,
)
from common.motion.terrain import Terrain, read_sidecar, read_terrain, write_terrain
from common.strict_json import parse_json

ROW_LENGTH = 44
LOOP_MODES = ("wrap", "none")
CLIP_PACK_FORMAT = "mimictrack.clip_pack"
CLIP_PACK_VERSION = 1
CLIP_PACK_TERRAIN_VERSION = 2  # written when a clip has a terrain (group 'terrains'), so older code refuses the file
TERRAIN_GROUP = "terrains"

# r = +90 deg about X maps DeepMimic's Y-up frame to Z up: (x, y, z) -> (x, -z, y).
_Y_TO_Z = np.array([math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0])
_Y_TO_Z_INV = _Y_TO_Z * np.array([1.0, -1.0, -1.0, -1.0])
_DEEPMIMIC_HINGE_AXIS = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Clip:
    """Source keyframes of one clip in the project's frame (Z up).

    Attributes:
        name: Clip name (file stem without the ``humanoid3d_`` prefix).
        source: File the clip came from (and the clip's key inside a pack).
        loop: True for DeepMimic's ``wrap`` clips (cyclic), False for ``none`` (one-shot).
        times: Keyframe times in seconds, starting at 0. Shape: (M,).
        root_pos: Root (pelvis) position, world. Shape: (M, 3).
        root_rot: Root rotation, world, unit quaternions in one hemisphere along time. Shape: (M, 4).
        joint_rot: Local rotation of every joint in ``DEEPMIMIC_JOINTS`` order, as unit quaternions (knees and
            elbows as a rotation about the model's +y hinge axis). Shape: (M, J=12, 4).
        terrain: The ground the clip is on (:mod:`common.motion.terrain`); None: the flat floor.
    """

    name: str
    source: str
    loop: bool
    times: np.ndarray
    root_pos: np.ndarray
    root_rot: np.ndarray
    joint_rot: np.ndarray
    terrain: Terrain | None = None

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    @property
    def num_keyframes(self) -> int:
        return len(self.times)

    @property
    def source_fps(self) -> float:
        """Median keyframe rate of the source."""
        return float(1.0 / np.median(np.diff(self.times)))


def clip_name(path: str | Path) -> str:
    stem = Path(path).stem
    return stem[len("humanoid3d_") :] if stem.startswith("humanoid3d_") else stem


def y_up_to_z_up_pos(p: np.ndarray) -> np.ndarray:
    """(x, y, z) in Y up -> (x, -z, y) in Z up. Shape: (..., 3)."""
    return np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)


def y_up_to_z_up_quat(q: np.ndarray) -> np.ndarray:
    """Conjugates a rotation into the Z-up frame: r * q * inv(r), r = +90 deg about X. Shape: (..., 4)."""
    return quat_mul(quat_mul(_Y_TO_Z, q), _Y_TO_Z_INV)


def frames_to_clip(frames: np.ndarray, loop: str, name: str, source: str) -> Clip:
    """Validates DeepMimic rows and converts them to a :class:`Clip`.

    The bounds are those of :mod:`common.motion.limits`: frame durations in [MIN_FRAME_DURATION,
    MAX_FRAME_DURATION] (the last row's duration is not used), at most MAX_CLIP_DURATION and MAX_KEYFRAMES, the root
    within MAX_ROOT_DISTANCE of the origin, quaternion lengths in QUAT_NORM_RANGE, hinge angles within
    MAX_HINGE_ANGLE.

    Args:
        frames: DeepMimic rows. Shape: (M, 44).
        loop: ``"wrap"`` or ``"none"``.
        name: Clip name.
        source: File name used in error messages.

    Raises:
        MotionFormatError: naming ``source``, the frame and the problem.
    """
    if not isinstance(loop, str) or loop not in LOOP_MODES:
        raise MotionFormatError(f"{source}: 'Loop' must be one of {LOOP_MODES}, got {show_value(loop)}")
    if frames.ndim != 2 or frames.shape[0] == 0:
        raise MotionFormatError(f"{source}: no frames")
    if frames.shape[1] != ROW_LENGTH:
        raise MotionFormatError(f"{source}: frames of {frames.shape[1]} values, a DeepMimic frame has {ROW_LENGTH}")
    if frames.shape[0] < 2:
        raise MotionFormatError(f"{source}: a clip needs at least 2 frames, got {frames.shape[0]}")
    if frames.shape[0] > MAX_KEYFRAMES:
        raise MotionFormatError(f"{source}: {frames.shape[0]:,} frames, more than {MAX_KEYFRAMES:,}")
    bad = np.argwhere(~np.isfinite(frames))
    if len(bad):
        f, c = bad[0]
        raise MotionFormatError(f"{source}: frame {f}: value {frames[f, c]} at column {c} is not finite")
    dur = frames[:-1, 0]
    nonpos = np.flatnonzero(dur <= 0)
    if len(nonpos):
        f = nonpos[0]
        raise MotionFormatError(f"{source}: frame {f}: frame duration must be positive, got {dur[f]}")
    short = np.flatnonzero(dur < MIN_FRAME_DURATION)
    if len(short):
        raise MotionFormatError(f"{source}: frame {short[0]}: frame duration {dur[short[0]]:.6g} s is below "
                                f"{MIN_FRAME_DURATION:g} s")  # fmt: skip
    _check_bound(dur, MAX_FRAME_DURATION, source, "frame duration {:.6g} s is above {:g} s")
    times = np.concatenate([[0.0], np.cumsum(dur)])
    if times[-1] > MAX_CLIP_DURATION:
        raise MotionFormatError(f"{source}: the clip lasts {times[-1]:.6g} s, longer than {MAX_CLIP_DURATION:g} s")
    _check_bound(lengths(frames[:, 1:4]), MAX_ROOT_DISTANCE, source,
                 "root {:.6g} m from the origin, farther than {:g} m")  # fmt: skip

    root_pos = y_up_to_z_up_pos(frames[:, 1:4])
    root_rot = _unit_quats(frames[:, 4:8], source, "root")
    joint_rot = []
    col = 8
    for joint, _, kind in DEEPMIMIC_JOINTS:
        if kind == "spherical":
            joint_rot.append(_unit_quats(frames[:, col : col + 4], source, joint))
            col += 4
        else:
            # A rotation about DeepMimic's local +z (Y up); the conversion below makes it one about -y (Z up),
            # i.e. the model's +y hinge with the angle negated.
            _check_bound(np.abs(frames[:, col]), MAX_HINGE_ANGLE, source, f"'{joint}' angle {{:.6g}} rad is beyond "
                         "{:.6g} rad")  # fmt: skip
            joint_rot.append(quat_from_axis_angle(_DEEPMIMIC_HINGE_AXIS, frames[:, col]))
            col += 1
    joint_rot = np.stack(joint_rot, axis=1)
    root_rot = quat_fix_hemisphere(y_up_to_z_up_quat(root_rot), axis=0)
    joint_rot = quat_fix_hemisphere(y_up_to_z_up_quat(joint_rot), axis=0)
    return Clip(name, source, loop == "wrap", times, root_pos, root_rot, joint_rot)


def _check_bound(values: np.ndarray, bound: float, source: str, problem: str) -> None:
    """MotionFormatError naming the first frame whose value exceeds ``bound``; ``problem`` formats (value, bound)."""
    over = np.flatnonzero(values > bound)
    if len(over):
        raise MotionFormatError(f"{source}: frame {over[0]}: {problem.format(values[over[0]], bound)}")


def _unit_quats(q: np.ndarray, source: str, joint: str) -> np.ndarray:
    norm = lengths(q)
    bad = np.flatnonzero(norm < MIN_QUAT_NORM)
    if len(bad):
        raise MotionFormatError(f"{source}: frame {bad[0]}: zero-length quaternion for joint '{joint}'")
    lo, hi = QUAT_NORM_RANGE
    bad = np.flatnonzero((norm < lo) | (norm > hi))
    if len(bad):
        raise MotionFormatError(f"{source}: frame {bad[0]}: quaternion of length {norm[bad[0]]:.6g} for joint "
                                f"'{joint}' is not a rotation (lengths {lo:g} to {hi:g} are read as one)")  # fmt: skip
    return q / norm[:, None]


class _TooManyDigits(ValueError):
    """An integer in a JSON file longer than :data:`~common.motion.limits.MAX_NUMBER_DIGITS` digits."""


def _json_int(text: str) -> int:
    if len(text) > MAX_NUMBER_DIGITS + 1:  # + 1: a minus sign
        raise _TooManyDigits(len(text.lstrip("-")))
    return int(text)


def read_deepmimic(path: str | Path) -> Clip:
    """Reads one DeepMimic ``.txt`` clip (JSON with ``Loop`` and ``Frames``).

    Raises:
        MotionFormatError: naming the file (and the frame) and the problem on one line: not a regular file or too
            large (refused before opening), not UTF-8 JSON, nested too deep, an integer of too many digits, a value
            that is not a number (a string, ``true``, ``null``), or a clip :func:`frames_to_clip` refuses.
    """
    path = Path(path)
    check_regular_file(path, MotionFormatError)
    try:
        doc = parse_json(path.read_bytes().decode("utf-8"), parse_int=_json_int)
    except UnicodeDecodeError as e:
        raise MotionFormatError(f"{path}: not a text file (byte 0x{e.object[e.start]:02x} at offset {e.start} is not "
                                "UTF-8); a DeepMimic clip is JSON text") from None  # fmt: skip
    except json.JSONDecodeError as e:
        raise MotionFormatError(f"{path}: not valid JSON ({e})") from None
    except _TooManyDigits as e:
        raise MotionFormatError(f"{path}: an integer of {e.args[0]:,} digits; no value of a clip needs more than "
                                f"{MAX_NUMBER_DIGITS}") from None  # fmt: skip
    except RecursionError:
        raise MotionFormatError(f"{path}: JSON nested too deep to read; a DeepMimic clip is "
                                '{"Loop": ..., "Frames": [[...], ...]}') from None  # fmt: skip
    except OSError as e:
        raise MotionFormatError(f"{path}: cannot read ({e.strerror})") from None
    if not isinstance(doc, dict) or "Frames" not in doc:
        raise MotionFormatError(f"{path}: missing the 'Frames' key")
    rows = doc["Frames"]
    if not isinstance(rows, list) or not rows:
        raise MotionFormatError(f"{path}: no frames")
    if len(rows) > MAX_KEYFRAMES:
        raise MotionFormatError(f"{path}: {len(rows):,} frames, more than {MAX_KEYFRAMES:,}")
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != ROW_LENGTH:
            n = len(row) if isinstance(row, list) else show_value(row)
            raise MotionFormatError(f"{path}: frame {i}: expected {ROW_LENGTH} values, got {n}")
    # Numbers must be numbers: numpy would read "0.03" and true as 0.03 and 1.0 without a word.
    if not {type(v) for row in rows for v in row} <= {int, float}:
        i, c, v = next((i, c, v) for i, row in enumerate(rows) for c, v in enumerate(row)
                       if type(v) not in (int, float))  # fmt: skip
        raise MotionFormatError(f"{path}: frame {i}: column {c} holds {show_value(v)}, not a number")
    frames = np.asarray(rows, dtype=np.float64)
    clip = frames_to_clip(frames, doc.get("Loop", "none"), clip_name(path), str(path))
    terrain = read_sidecar(path)
    return clip if terrain is None else replace(clip, terrain=terrain)


def write_clip_pack(path: str | Path, sources: list[str | Path]) -> None:
    """Stores DeepMimic clips compactly: their raw rows as float32 in one HDF5 file (atomic write).

    Each clip is read (validated) and its rows checked again as float32, as :func:`read_clip_pack` will read them:
    rounding can carry a value over a bound (a frame duration of 1e-4 s is 9.99999975e-05 s in float32). A clip's
    terrain (its sidecar file) is stored in float64 in the group ``terrains``; the pack is then version 2.

    Raises:
        MotionFormatError: a source the reader refuses, as read or as stored; nothing is written.
    """
    path = Path(path)
    if not sources:
        raise MotionFormatError(f"{path}: a clip pack needs at least one clip")
    with hdf5_output(path) as f:
        f.attrs["format"] = CLIP_PACK_FORMAT
        f.attrs["version"] = CLIP_PACK_VERSION
        terrains: dict[str, Terrain] = {}
        for src in sources:
            clip = read_deepmimic(src)
            if clip.terrain is not None:
                terrains[clip.name] = clip.terrain
            doc = parse_json(Path(src).read_text(encoding="utf-8"))
            rows = np.asarray(doc["Frames"], dtype=np.float32)
            frames_to_clip(rows.astype(np.float64), doc.get("Loop", "none"), clip.name, f"{src} (as float32)")
            d = f.create_dataset(clip.name, data=rows, compression="gzip")
            d.attrs["loop"] = doc.get("Loop", "none")
        if terrains:
            if TERRAIN_GROUP in f:
                raise MotionFormatError(f"{path}: a clip named '{TERRAIN_GROUP}' cannot be in a pack with terrains")
            f.attrs["version"] = CLIP_PACK_TERRAIN_VERSION
            for name, terrain in terrains.items():
                write_terrain(f.require_group(TERRAIN_GROUP).create_group(name), terrain)


def read_clip_pack(path: str | Path) -> list[Clip]:
    """Reads every clip of a pack written by :func:`write_clip_pack`.

    Raises:
        MotionFormatError: naming the file (and the clip) and the problem: not a regular file, not HDF5, another
            format or version, no clips, a clip that is not a (frames, 44) array of numbers or has no 'loop' string,
            or rows :func:`frames_to_clip` refuses.
    """
    path = Path(path)
    check_regular_file(path, MotionFormatError, max_bytes=None)
    try:
        with h5py.File(path, "r") as f:
            version = hdf5.check_header(f, str(path), CLIP_PACK_FORMAT, "clip pack",
                                        (CLIP_PACK_VERSION, CLIP_PACK_TERRAIN_VERSION))  # fmt: skip
            terrains = f.get(TERRAIN_GROUP) if version == CLIP_PACK_TERRAIN_VERSION else None
            terrains = terrains if isinstance(terrains, h5py.Group) else None
            keys = sorted(k for k in f.keys() if terrains is None or k != TERRAIN_GROUP)
            if not keys:
                raise MotionFormatError(f"{path}: a clip pack with no clips")
            if len(keys) > MAX_CLIPS:
                raise MotionFormatError(f"{path}: {len(keys):,} clips, more than {MAX_CLIPS:,}")
            clips = []
            for k in keys:
                where = f"{path}:{k}"
                frames = hdf5.array(f, k, where, (None, ROW_LENGTH), MAX_KEYFRAMES)
                clip = frames_to_clip(frames, hdf5.attr(f[k], "loop", "str", where), k, where)
                if terrains is not None and k in terrains:
                    clip = replace(clip, terrain=read_terrain(terrains[k], where))
                clips.append(clip)
            unknown = sorted(set(terrains or ()) - set(keys))
            if unknown:
                raise MotionFormatError(f"{path}: a terrain for '{unknown[0]}', which is not a clip of the pack")
            return clips
    except OSError as e:
        raise MotionFormatError(f"{path}: not a readable HDF5 file ({e})") from None
