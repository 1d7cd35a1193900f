"""Writing a clip as a DeepMimic ``.txt`` file (the inverse of :func:`common.motion.motion.read_deepmimic`).

The project's frame is Z up; DeepMimic's is Y up: positions (x, y, z) -> (x, z, -y), rotations q -> r^-1 q r with
r = +90 deg about X, and knee/elbow angles negated (DeepMimic's hinge is its local +z, the model's +y).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from common.character.humanoid import DEEPMIMIC_JOINTS
from common.maths.rotations import quat_conj, quat_from_axis_angle, quat_mul
from common.motion.motion import ROW_LENGTH, Clip, frames_to_clip
from common.motion.terrain import sidecar_path, write_sidecar

_R = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), np.pi / 2)  # Y up -> Z up


def z_up_to_y_up_pos(p: np.ndarray) -> np.ndarray:
    """(x, y, z) in Z up -> (x, z, -y) in Y up. Shape: (..., 3)."""
    return np.stack([p[..., 0], p[..., 2], -p[..., 1]], axis=-1)


def z_up_to_y_up_quat(q: np.ndarray) -> np.ndarray:
    """r^-1 q r, r = +90 deg about X. Shape: (..., 4)."""
    return quat_mul(quat_mul(quat_conj(_R), q), _R)


def clip_to_rows(clip: Clip) -> np.ndarray:
    """DeepMimic rows of a clip. Shape: (M, 44)."""
    rows = np.zeros((clip.num_keyframes, ROW_LENGTH))
    rows[:-1, 0] = np.diff(clip.times)
    rows[:, 1:4] = z_up_to_y_up_pos(clip.root_pos)
    rows[:, 4:8] = z_up_to_y_up_quat(clip.root_rot)
    col = 8
    for j, (_, _, kind) in enumerate(DEEPMIMIC_JOINTS):
        q = clip.joint_rot[:, j]
        if kind == "spherical":
            rows[:, col : col + 4] = z_up_to_y_up_quat(q)
            col += 4
        else:
            # The model's hinge angle about +y; DeepMimic's angle about its +z is its negative.
            rows[:, col] = -2.0 * np.arctan2(q[:, 2], q[:, 0])
            col += 1
    return rows


def check_writable(clip: Clip) -> None:
    """Raises what :func:`~common.motion.motion.read_deepmimic` would raise on the clip written as DeepMimic rows
    (one frame, a frame time or a root beyond the bounds of :mod:`common.motion.limits`, ...), naming ``clip.source``.
    """
    _rows_read_back(clip)


def _rows_read_back(clip: Clip) -> list[list[float]]:
    """The rows as written (9 significant digits), checked by the reader's own :func:`frames_to_clip`."""
    rows = [[float(f"{v:.9g}") for v in row] for row in clip_to_rows(clip)]
    frames_to_clip(np.asarray(rows, dtype=np.float64).reshape(-1, ROW_LENGTH), "wrap" if clip.loop else "none",
                   clip.name, clip.source)  # fmt: skip
    return rows


def write_deepmimic(path: str | Path, clip: Clip) -> None:
    """Writes ``clip`` as DeepMimic JSON (``Loop``, ``Frames``), atomically: nothing is replaced until complete.

    A clip's terrain goes into its sidecar file (:func:`common.motion.terrain.write_sidecar`); a flat clip's stale
    sidecar is removed, so that the reader reads back the clip as written.

    Raises:
        MotionFormatError: a clip the reader would refuse as written (see :func:`check_writable`); nothing is written.
    """
    path = Path(path)
    doc = {"Loop": "wrap" if clip.loop else "none", "Frames": _rows_read_back(clip)}
    if clip.terrain is not None:
        write_sidecar(path, clip.terrain)
    else:
        sidecar_path(path).unlink(missing_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(json.dumps(doc, separators=(",", ":")).replace("],[", "],\n["))
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
