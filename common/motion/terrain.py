"""A clip's terrain: a heightfield that travels with the clip, its height at any point, and its files.

A terrain is a grid of heights (metres, Z up) at the nodes ``(x0 + j * cell, y0 + i * cell)``: row i runs along y,
column j along x, as in a MuJoCo ``hfield``. Between the nodes the ground is what MuJoCo collides with: each cell is
two flat triangles split along the diagonal from node (i, j) to node (i + 1, j + 1) (``mj_ray`` and the contacts of a
body resting on the field agree to 1e-6 m, ``tests/common/test_terrain.py``). Bilinear interpolation is not that
surface: it differs from it by up to a quarter of ``|h00 - h10 - h01 + h11|`` inside a cell (a box's corner, a bump),
so the project uses the triangles. Outside its grid the ground is flat, :data:`OFF_GRID_DROP` below the terrain's
lowest point: the simulator's floor plane is moved there, under the heightfield's solid (a plane level with the lowest
heights would double every contact there). A terrain must reach beyond where its clip goes (the generator's strips
have 1 m of flat ground before and after the feature). A clip without a terrain is on the flat floor at height 0.

Where a terrain is stored (one layout, :func:`write_terrain` / :func:`read_terrain`): a group holding the dataset
``heights`` (rows, cols) and ``origin`` (2,) and the attribute ``cell_size``:
- motion datasets: ``clips/<clip>/terrain`` beside the clip's frames (dataset version 3);
- clip packs: ``terrains/<clip>`` beside the clip's rows (clip pack version 2);
- a DeepMimic ``.txt`` clip: the sidecar ``<clip>.terrain.h5`` next to it (format ``mimictrack.terrain``), found by
  :func:`read_sidecar` whenever the clip is read.
Every reader refuses a terrain outside :mod:`common.motion.limits`' bounds with one
:class:`~common.motion.errors.MotionFormatError` line.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from common.config import hdf5_output
from common.motion import hdf5
from common.motion.errors import MotionFormatError
from common.motion.limits import (
    MAX_ROOT_DISTANCE,
    MAX_TERRAIN_HEIGHT,
    MAX_TERRAIN_POINTS,
    TERRAIN_CELL_RANGE,
    check_regular_file,
)

SIDECAR_SUFFIX = ".terrain.h5"
SIDECAR_FORMAT = "mimictrack.terrain"
SIDECAR_VERSION = 1
OFF_GRID_DROP = 0.5  # m: the ground outside a terrain's grid lies this far below its lowest point
MAX_TERRAIN_SIDE = 20_000  # grid points along one side: 200 m at 1 cm; the total is bounded by MAX_TERRAIN_POINTS


@dataclass(frozen=True, eq=False)
class Terrain:
    """A heightfield on a square grid.

    Attributes:
        heights: Height of every grid node (m). Shape: (rows, cols); row i at y0 + i * cell, column j at x0 + j * cell.
        cell_size: Spacing of the nodes (m), the same along x and y.
        origin: (x0, y0), the world position of node (0, 0) (m). Shape: (2,).
    """

    heights: np.ndarray
    cell_size: float
    origin: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.heights.shape

    @property
    def size(self) -> np.ndarray:
        """Extent along x and y (m). Shape: (2,)."""
        return (np.array(self.heights.shape[::-1]) - 1) * self.cell_size

    @property
    def floor(self) -> float:
        """The height outside the grid: :data:`OFF_GRID_DROP` below the lowest node."""
        return float(self.heights.min()) - OFF_GRID_DROP

    def key(self) -> tuple:
        """Equal for equal terrains (to build one simulator model for the clips that share one)."""
        return self.heights.shape, self.heights.tobytes(), float(self.cell_size), tuple(self.origin.tolist())

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The ground's height at (x, y) as MuJoCo collides with it: the cell's triangle, :attr:`floor` outside.

        Args:
            x, y: World coordinates (m), any broadcastable shapes.

        Returns:
            Heights (m), the broadcast shape of x and y.
        """
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        rows, cols = self.heights.shape
        u = (x - self.origin[0]) / self.cell_size
        v = (y - self.origin[1]) / self.cell_size
        inside = (u >= 0.0) & (u <= cols - 1) & (v >= 0.0) & (v <= rows - 1)
        j = np.clip(u, 0.0, cols - 2.0).astype(np.intp)  # the cell's corner: truncation is floor here
        i = np.clip(v, 0.0, rows - 2.0).astype(np.intp)
        fu, fv = u - j, v - i  # in [0, 1] inside the grid; outside, the result is replaced by the floor
        corner = i * cols + j
        h = self.heights.ravel()
        h00, h11 = h.take(corner), h.take(corner + cols + 1)
        # Below the diagonal (fu >= fv) the triangle (0, 0), (1, 0), (1, 1): h00 + fu (h10 - h00) + fv (h11 - h10);
        # above it (0, 0), (0, 1), (1, 1): the same with fu and fv swapped and h01 for h10.
        below = fu >= fv
        mid = h.take(np.where(below, corner + 1, corner + cols))
        p, q = np.where(below, fu, fv), np.where(below, fv, fu)
        return np.where(inside, h00 + p * (mid - h00) + q * (h11 - mid), self.floor)


def check_terrain(heights: np.ndarray, cell_size: float, origin: np.ndarray, where: str) -> Terrain:
    """A :class:`Terrain` from checked parts.

    Raises:
        MotionFormatError: ``where`` and the first problem on one line: fewer than 2 x 2 or more than
            :data:`~common.motion.limits.MAX_TERRAIN_POINTS` points, a height that is not finite or beyond
            :data:`~common.motion.limits.MAX_TERRAIN_HEIGHT`, a cell size outside
            :data:`~common.motion.limits.TERRAIN_CELL_RANGE`, a grid reaching farther than twice
            :data:`~common.motion.limits.MAX_ROOT_DISTANCE` from the world's origin.
    """
    heights = np.asarray(heights, dtype=np.float64)
    origin = np.asarray(origin, dtype=np.float64)
    if heights.ndim != 2 or min(heights.shape) < 2:
        raise MotionFormatError(f"{where}: terrain heights have shape {heights.shape}, expected (rows, cols) of at "
                                "least 2 x 2")  # fmt: skip
    if heights.size > MAX_TERRAIN_POINTS or max(heights.shape) > MAX_TERRAIN_SIDE:
        raise MotionFormatError(f"{where}: terrain of {heights.shape[0]:,} x {heights.shape[1]:,} points, more than "
                                f"{MAX_TERRAIN_POINTS:,} in all or {MAX_TERRAIN_SIDE:,} along a side")  # fmt: skip
    bad = np.argwhere(~np.isfinite(heights))
    if len(bad):
        raise MotionFormatError(f"{where}: terrain height at row {bad[0][0]}, column {bad[0][1]} is not finite")
    high = np.argwhere(np.abs(heights) > MAX_TERRAIN_HEIGHT)
    if len(high):
        i, j = high[0]
        raise MotionFormatError(f"{where}: terrain height {heights[i, j]:.6g} m at row {i}, column {j} is beyond "
                                f"+-{MAX_TERRAIN_HEIGHT:g} m")  # fmt: skip
    lo, hi = TERRAIN_CELL_RANGE
    if not (isinstance(cell_size, float | int) and not isinstance(cell_size, bool) and lo <= cell_size <= hi):
        raise MotionFormatError(f"{where}: terrain cell_size {cell_size!r} m is outside {lo:g} to {hi:g} m")
    if origin.shape != (2,) or not np.isfinite(origin).all():
        raise MotionFormatError(f"{where}: terrain origin must be 2 finite numbers (x, y), got "
                                f"{np.array2string(origin, precision=4)}")  # fmt: skip
    far = np.abs(origin).max(initial=0.0), np.abs(origin + (np.array(heights.shape[::-1]) - 1) * cell_size).max()
    if max(far) > 2.0 * MAX_ROOT_DISTANCE:
        raise MotionFormatError(f"{where}: terrain reaches {max(far):.6g} m from the origin, farther than "
                                f"{2 * MAX_ROOT_DISTANCE:g} m")  # fmt: skip
    return Terrain(heights, float(cell_size), origin)


def write_terrain(group: h5py.Group, terrain: Terrain) -> None:
    """Writes ``terrain`` into an HDF5 group: datasets ``heights`` and ``origin``, attribute ``cell_size``."""
    group.create_dataset("heights", data=terrain.heights, compression="gzip", compression_opts=1)
    group.create_dataset("origin", data=terrain.origin)
    group.attrs["cell_size"] = terrain.cell_size


def read_terrain(group: object, where: str) -> Terrain:
    """Reads and checks what :func:`write_terrain` wrote (shapes checked before anything is read).

    Raises:
        MotionFormatError: ``where`` and the problem on one line (see :func:`check_terrain`).
    """
    if not isinstance(group, h5py.Group):
        raise MotionFormatError(f"{where}: 'terrain' is not a group of arrays")
    item = group.get("heights")
    if isinstance(item, h5py.Dataset) and item.ndim != 2:
        raise MotionFormatError(f"{where}: terrain heights have shape {item.shape}, expected (rows, cols)")
    if isinstance(item, h5py.Dataset) and item.size > MAX_TERRAIN_POINTS:
        raise MotionFormatError(f"{where}: terrain of {item.shape[0]:,} x {item.shape[1]:,} points, more than "
                                f"{MAX_TERRAIN_POINTS:,}")  # fmt: skip
    heights = hdf5.array(group, "heights", f"{where}: terrain", (None, None), MAX_TERRAIN_SIDE)
    origin = hdf5.array(group, "origin", f"{where}: terrain", (2,), 2)
    cell = hdf5.attr(group, "cell_size", "number", f"{where}: terrain")
    return check_terrain(heights, cell, origin, where)


def sidecar_path(clip_path: str | Path) -> Path:
    """``walk_up.txt`` -> ``walk_up.terrain.h5``, next to it."""
    path = Path(clip_path)
    return path.with_name(path.stem + SIDECAR_SUFFIX)


def write_sidecar(clip_path: str | Path, terrain: Terrain) -> Path:
    """Writes a ``.txt`` clip's terrain into its sidecar file (atomically); returns the sidecar's path."""
    path = sidecar_path(clip_path)
    check_terrain(terrain.heights, terrain.cell_size, terrain.origin, str(path))
    with hdf5_output(path) as f:
        f.attrs["format"] = SIDECAR_FORMAT
        f.attrs["version"] = SIDECAR_VERSION
        write_terrain(f.create_group("terrain"), terrain)
    return path


def read_sidecar(clip_path: str | Path) -> Terrain | None:
    """The terrain of a ``.txt`` clip from its sidecar file; None when it has none (the flat floor).

    Raises:
        MotionFormatError: naming the sidecar and the problem on one line.
    """
    path = sidecar_path(clip_path)
    if not path.exists() and not path.is_symlink():
        return None
    return read_terrain_file(path)


def read_terrain_file(path: str | Path) -> Terrain:
    """A terrain file (format ``mimictrack.terrain``, as :func:`write_sidecar` writes one).

    Raises:
        MotionFormatError: naming the file and the problem on one line.
    """
    path = Path(path)
    check_regular_file(path, MotionFormatError, max_bytes=None)
    where = str(path)
    try:
        with h5py.File(path, "r") as f:
            hdf5.check_header(f, where, SIDECAR_FORMAT, "terrain file", (SIDECAR_VERSION,))
            return read_terrain(f.get("terrain"), where)
    except OSError as e:
        raise MotionFormatError(f"{path}: not a readable HDF5 file ({e})") from None
