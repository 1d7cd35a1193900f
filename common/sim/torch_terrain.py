"""The clips' terrains in torch: the ground's height under any point (:meth:`TerrainField.height`, a gather over the
terrains' padded height tensors) and the heightmap around a root (:func:`heightmap`), differentiable in x and y.

The torch flavour of :meth:`common.sim.terrain.ClipTerrains.height` and :func:`common.sim.terrain.heightmap`, for a
learner that samples the ground where its predictions put a character (SuperTrack's world-model rollout). The surface
is the same: each cell two flat triangles split along the diagonal from node (i, j) to node (i + 1, j + 1), as MuJoCo
collides with it (:mod:`common.motion.terrain`); off the grid the terrain's floor, and height 0 for a clip on the flat
floor. Heights, origins and cell sizes are stored in float32, so the two flavours agree within float32 rounding
(``tests/common/test_torch_terrain.py``). The height is continuous and piecewise linear in (x, y): its gradient is the
triangle's slope, and it is undefined only on cell edges and diagonals, where either side's slope is taken.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from common.maths import torch_rotations as R
from common.sim.terrain import ClipTerrains


class TerrainField(nn.Module):
    """Every terrain of a library's clips as padded tensors (module buffers, so ``.to(device)`` moves them).

    Slot 0 is the flat floor (a 2 x 2 grid of zeros whose off-grid floor is 0 too: height 0 everywhere); slot t + 1
    is :attr:`ClipTerrains.unique` [t], its heights padded with zeros to the largest grid (padding is never read: a
    point's cell is clamped to its own terrain's grid).

    Args:
        terrains: The clips' terrains.
    """

    def __init__(self, terrains: ClipTerrains) -> None:
        super().__init__()
        grids = [np.zeros((2, 2)), *(t.heights for t in terrains.unique)]
        rows, cols = max(g.shape[0] for g in grids), max(g.shape[1] for g in grids)
        padded = np.zeros((len(grids), rows, cols))
        for k, g in enumerate(grids):
            padded[k, : g.shape[0], : g.shape[1]] = g
        self.padded_cols = cols

        def buffer(name: str, values: object, dtype: torch.dtype = torch.float32) -> None:
            self.register_buffer(name, torch.as_tensor(np.asarray(values), dtype=dtype), persistent=False)

        buffer("heights", padded.ravel())  # (S R C,): slot k's node (i, j) at (k R + i) C + j
        buffer("slot_base", np.arange(len(grids)) * rows * cols, torch.int64)  # (S,)
        buffer("grid_rows", [g.shape[0] for g in grids], torch.int64)  # (S,)
        buffer("grid_cols", [g.shape[1] for g in grids], torch.int64)  # (S,)
        buffer("cell", [1.0, *(t.cell_size for t in terrains.unique)])  # (S,) m
        buffer("origin", [[0.0, 0.0], *(t.origin for t in terrains.unique)])  # (S, 2) m
        buffer("floor", [0.0, *(t.floor for t in terrains.unique)])  # (S,) m, the height off the grid
        buffer("clip_slot", terrains.index + 1, torch.int64)  # (C,): the clip's slot, 0 for the flat floor

    def height(self, clip: Tensor, x: Tensor, y: Tensor) -> Tensor:
        """The ground's height at (x, y) of each point's clip (0 on the flat floor): the cell's triangle, the terrain's
        floor off its grid.

        Args:
            clip: Clip index, broadcastable to x's and y's shape. Shape: (...).
            x, y: World coordinates (m). Shape: (...).

        Returns:
            Heights (m), the broadcast shape.
        """
        x, y, slot = torch.broadcast_tensors(x, y, self.clip_slot[clip])
        rows, cols = self.grid_rows[slot], self.grid_cols[slot]
        cell, origin = self.cell[slot], self.origin[slot]
        u = (x - origin[..., 0]) / cell
        v = (y - origin[..., 1]) / cell
        inside = (u >= 0) & (u <= cols - 1) & (v >= 0) & (v <= rows - 1)
        # The cell's corner, clamped into the grid before the cast (truncation is floor there); a NaN or infinite
        # coordinate (a blown-up prediction) lands on a valid cell whose height the off-grid floor replaces, so the
        # gather never reads out of bounds.
        j = torch.minimum(torch.nan_to_num(u, 0.0, 0.0, 0.0).clamp_min(0.0), (cols - 2).to(u.dtype)).long()
        i = torch.minimum(torch.nan_to_num(v, 0.0, 0.0, 0.0).clamp_min(0.0), (rows - 2).to(v.dtype)).long()
        fu, fv = u - j, v - i
        corner = self.slot_base[slot] + i * self.padded_cols + j
        h00, h11 = self.heights[corner], self.heights[corner + self.padded_cols + 1]
        # Below the diagonal (fu >= fv) the triangle (0, 0), (1, 0), (1, 1): h00 + fu (h10 - h00) + fv (h11 - h10);
        # above it (0, 0), (0, 1), (1, 1): the same with fu and fv swapped and h01 for h10.
        below = fu >= fv
        mid = self.heights[torch.where(below, corner + 1, corner + self.padded_cols)]
        p, q = torch.where(below, fu, fv), torch.where(below, fv, fu)
        return torch.where(inside, h00 + p * (mid - h00) + q * (h11 - mid), self.floor[slot])


def heightmap(field: TerrainField, clip: Tensor, root_pos: Tensor, root_rot: Tensor, offsets: Tensor) -> Tensor:
    """How high the root is above the ground at points around it, the points turned with the root's heading: the
    torch flavour of :func:`common.sim.terrain.heightmap`.

    Args:
        field: The clips' terrains.
        clip: Clip of each character. Shape: (...).
        root_pos: Root position, world. Shape: (..., 3).
        root_rot: Root rotation, world (w, x, y, z). Shape: (..., 4).
        offsets: Sample points in the heading frame (:func:`common.sim.terrain.heightmap_offsets`). Shape: (P, 2).

    Returns:
        root height - ground height at each point (m). Shape: (..., P).
    """
    yaw = R.quat_yaw(root_rot)[..., None]
    c, s = torch.cos(yaw), torch.sin(yaw)
    x = root_pos[..., :1] + c * offsets[:, 0] - s * offsets[:, 1]
    y = root_pos[..., 1:2] + s * offsets[:, 0] + c * offsets[:, 1]
    return root_pos[..., 2:3] - field.height(clip[..., None], x, y)
