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
import os
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from common.character.humanoid import DEEPMIMIC_JOINTS
from common.maths.rotations import quat_fix_hemisphere, quat_from_axis_angle, quat_mul

ROW_LENGTH = 44
# Physical bounds of a clip's values: beyond them a file is corrupt or in other units (e.g. millimetres), and
# carrying on would put the character where nothing can track it.
MAX_ROOT_DISTANCE = 1000.0  # m from the origin
MAX_FRAME_DURATION = 60.0  # s
MAX_HINGE_ANGLE = 2.0 * math.pi  # rad: a knee or elbow turned more than once round
LOOP_MODES = ("wrap", "none")
CLIP_PACK_FORMAT = "mimictrack.clip_pack"
CLIP_PACK_VERSION = 1

# r = +90 deg about X maps DeepMimic's Y-up frame to Z up: (x, y, z) -> (x, -z, y).
_Y_TO_Z = np.array([math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0])
_Y_TO_Z_INV = _Y_TO_Z * np.array([1.0, -1.0, -1.0, -1.0])
_DEEPMIMIC_HINGE_AXIS = np.array([0.0, 0.0, 1.0])


class MotionFormatError(ValueError):
    """A motion file that cannot be read; the message names the file, the frame and the problem."""


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
    """

    name: str
    source: str
    loop: bool
    times: np.ndarray
    root_pos: np.ndarray
    root_rot: np.ndarray
    joint_rot: np.ndarray

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

    Args:
        frames: DeepMimic rows. Shape: (M, 44).
        loop: ``"wrap"`` or ``"none"``.
        name: Clip name.
        source: File name used in error messages.

    Raises:
        MotionFormatError: naming ``source``, the frame and the problem.
    """
    if loop not in LOOP_MODES:
        raise MotionFormatError(f"{source}: 'Loop' must be one of {LOOP_MODES}, got {loop!r}")
    if frames.ndim != 2 or frames.shape[0] == 0:
        raise MotionFormatError(f"{source}: no frames")
    if frames.shape[0] < 2:
        raise MotionFormatError(f"{source}: a clip needs at least 2 frames, got {frames.shape[0]}")
    bad = np.argwhere(~np.isfinite(frames))
    if len(bad):
        f, c = bad[0]
        raise MotionFormatError(f"{source}: frame {f}: value {frames[f, c]} at column {c} is not finite")
    dur = frames[:-1, 0]
    nonpos = np.flatnonzero(dur <= 0)
    if len(nonpos):
        f = nonpos[0]
        raise MotionFormatError(f"{source}: frame {f}: frame duration must be positive, got {dur[f]}")
    _check_bound(dur, MAX_FRAME_DURATION, source, "frame duration {:.6g} s is above {:g} s")
    _check_bound(np.linalg.norm(frames[:, 1:4], axis=-1), MAX_ROOT_DISTANCE, source,
                 "root {:.6g} m from the origin, farther than {:g} m")  # fmt: skip
    times = np.concatenate([[0.0], np.cumsum(dur)])

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
    norm = np.linalg.norm(q, axis=-1)
    bad = np.flatnonzero(norm < 1e-6)
    if len(bad):
        raise MotionFormatError(f"{source}: frame {bad[0]}: zero-length quaternion for joint '{joint}'")
    return q / norm[:, None]


def read_deepmimic(path: str | Path) -> Clip:
    """Reads one DeepMimic ``.txt`` clip (JSON with ``Loop`` and ``Frames``)."""
    path = Path(path)
    try:
        doc = json.loads(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError as e:
        raise MotionFormatError(f"{path}: not a text file (byte 0x{e.object[e.start]:02x} at offset {e.start} is not "
                                "UTF-8); a DeepMimic clip is JSON text") from None  # fmt: skip
    except json.JSONDecodeError as e:
        raise MotionFormatError(f"{path}: not valid JSON ({e})") from None
    except OSError as e:
        raise MotionFormatError(f"{path}: cannot read ({e.strerror})") from None
    if not isinstance(doc, dict) or "Frames" not in doc:
        raise MotionFormatError(f"{path}: missing the 'Frames' key")
    rows = doc["Frames"]
    if not isinstance(rows, list) or not rows:
        raise MotionFormatError(f"{path}: no frames")
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != ROW_LENGTH:
            n = len(row) if isinstance(row, list) else type(row).__name__
            raise MotionFormatError(f"{path}: frame {i}: expected {ROW_LENGTH} values, got {n}")
    try:
        frames = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise MotionFormatError(f"{path}: frames must be numbers ({e})") from None
    return frames_to_clip(frames, doc.get("Loop", "none"), clip_name(path), str(path))


def write_clip_pack(path: str | Path, sources: list[str | Path]) -> None:
    """Stores DeepMimic clips compactly: their raw rows as float32 in one HDF5 file (atomic write)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = CLIP_PACK_FORMAT
            f.attrs["version"] = CLIP_PACK_VERSION
            for src in sources:
                read_deepmimic(src)  # validates before storing
                doc = json.loads(Path(src).read_text(encoding="utf-8"))
                d = f.create_dataset(
                    clip_name(src), data=np.asarray(doc["Frames"], dtype=np.float32), compression="gzip"
                )
                d.attrs["loop"] = doc.get("Loop", "none")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def read_clip_pack(path: str | Path) -> list[Clip]:
    """Reads every clip of a pack written by :func:`write_clip_pack`."""
    path = Path(path)
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != CLIP_PACK_FORMAT:
                raise MotionFormatError(f"{path}: not a clip pack (format {f.attrs.get('format')!r})")
            if f.attrs.get("version") != CLIP_PACK_VERSION:
                raise MotionFormatError(
                    f"{path}: clip pack version {f.attrs.get('version')}, this code reads {CLIP_PACK_VERSION}"
                )
            return [
                frames_to_clip(f[k][()].astype(np.float64), str(f[k].attrs["loop"]), k, f"{path}:{k}")
                for k in sorted(f.keys())
            ]
    except OSError as e:
        raise MotionFormatError(f"{path}: not a readable HDF5 file ({e})") from None
