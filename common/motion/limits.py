"""Plausibility bounds of motion data, stated once: every reader of clips (``.txt``), clip packs and motion datasets
(``.h5``) and BVH files refuses what lies beyond them, and every writer checks what it writes against them, so that
what a writer writes its reader accepts.

Beyond these bounds a file is corrupt, in other units (centimetres read as metres), or would make a command allocate
more memory than a machine has; carrying on would put the character where nothing can track it. The bundled clips
lie well inside them: frames of 8.3 to 62.5 ms, roots within 3 m of the origin, quaternions of length 0.58 to 1.01
(DeepMimic's own files are not all normalised), clips of at most 33 s.
"""

from __future__ import annotations

import math
import stat
from pathlib import Path

import numpy as np

MIN_FRAME_DURATION = 1e-4  # s: 10 kHz, faster than any motion capture; 1e-9 s frames are a unit slip or a glitch
MAX_FRAME_DURATION = 1.0  # s: one keyframe a second; the library interpolates linearly between keyframes
MAX_CLIP_DURATION = 600.0  # s: resampled at 60 Hz a clip of 10 minutes takes ~100 MB of per-frame states
MAX_KEYFRAMES = 300_000  # per clip: 10 minutes at 500 fps, 42 minutes at CMU's 120 fps
MAX_CLIPS = 10_000  # per clip pack or motion dataset
MAX_TOTAL_FRAMES = 2_000_000  # control-rate frames of a motion dataset: 9 hours at 60 Hz, ~5 GB of per-frame states
MAX_ROOT_DISTANCE = 100.0  # m from the origin: capture volumes span tens of metres; 900 m is a file in cm or mm
MAX_HINGE_ANGLE = 2.0 * math.pi  # rad: a knee or elbow turned more than once round
MIN_QUAT_NORM = 1e-6  # below: a zero quaternion, no rotation at all
QUAT_NORM_RANGE = (0.1, 10.0)  # a rotation written with few digits is near 1; 1e200 is not a rotation
MAX_FILE_BYTES = 256 * 2**20  # a text clip, BVH file or joint map: MAX_KEYFRAMES rows of a clip are ~160 MB of JSON
MAX_NUMBER_DIGITS = 20  # digits of an integer in a text file: no bound above needs more (Python refuses 4,300)
MAX_BVH_DEPTH = 64  # joints from a BVH root to its deepest leaf: CMU's deepest chain is 9, with fingers ~15
MAX_BVH_JOINTS = 1_000
MAX_BVH_VALUE = 1e6  # |value| of a BVH number (file units or degrees): 1 km in mm, 2,777 turns
MAX_TERRAIN_HEIGHT = 100.0  # m, |height| of a terrain point: a 10 km mountain is a file in cm or mm
TERRAIN_CELL_RANGE = (0.005, 1.0)  # m: PARC samples at 0.1 m; finer than 5 mm is no ground a foot feels
MAX_TERRAIN_POINTS = 4_000_000  # grid points of one terrain: 200 m x 200 m at 0.1 m, 32 MB of float64


def check_regular_file(path: Path, error: type[Exception], max_bytes: int | None = MAX_FILE_BYTES) -> None:
    """Refuses, before opening it, a path that is not a regular file, or one larger than ``max_bytes``.

    Opening a FIFO for reading blocks until something writes to it (a command given one as a clip hung); a character
    device (``/dev/zero``) never ends. ``stat`` follows symbolic links and opens nothing.

    Raises:
        error: ``"<path>: <problem>"`` on one line.
    """
    try:
        st = path.stat()
    except FileNotFoundError:
        raise error(f"{path}: no such file") from None
    except OSError as e:
        raise error(f"{path}: cannot read ({e.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        kind = ("a directory" if stat.S_ISDIR(st.st_mode) else "a FIFO (named pipe)" if stat.S_ISFIFO(st.st_mode)
                else "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode)
                else "a socket" if stat.S_ISSOCK(st.st_mode) else "not a file")  # fmt: skip
        raise error(f"{path}: not a regular file ({kind})")
    if max_bytes is not None and st.st_size > max_bytes:
        raise error(f"{path}: {st.st_size:,} bytes, more than the {max_bytes:,} this reader takes")


def lengths(v: np.ndarray) -> np.ndarray:
    """Euclidean lengths over the last axis without overflow: the largest component is taken out first, so that a
    quaternion of 1e200 has length 1e200, not inf (its square overflows). Shape: (..., k) -> (...)."""
    scale = np.abs(v).max(axis=-1, initial=0.0)
    return scale * np.linalg.norm(v / np.where(scale > 0, scale, 1.0)[..., None], axis=-1)


def show_value(value: object) -> str:
    """A value read from a JSON or YAML file as the file wrote it, for messages: ``'0.03' (a string)``, ``true``."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        text = value if len(value) <= 20 else value[:17] + "..."
        return f"{text!r} (a string)"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "an object"
    return f"{value!r}"[:40]
