"""The terrains in torch (common/sim/torch_terrain.py) against the numpy heights and heightmap (common/sim/terrain.py),
on generated terrains; the slope of a hand-made cell's two triangles as the gradient; blown-up coordinates."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from common.motion.terrain import OFF_GRID_DROP, check_terrain
from common.motion.terrain_generator import boxes, rough, slope, stairs
from common.sim.terrain import ClipTerrains, heightmap, heightmap_offsets
from common.sim.torch_terrain import TerrainField
from common.sim.torch_terrain import heightmap as torch_heightmap

# float32 keeps 24 bits: u = (x - x0) / cell is off by about 2^-24 |x - x0| / cell cells, which moves the height by
# that times the steepest cell's rise (a 15 cm riser over one 5 cm cell: 3 cell sizes per cell), i.e. 2^-24 * 8 m * 3
# = 1.4e-6 m at 8 m from the origin, plus the heights' own rounding (2^-24 * 0.9 m). 5e-6 m bounds both.
FLOAT32_HEIGHT_TOL = 5e-6


@pytest.fixture(scope="module")
def terrains() -> ClipTerrains:
    """Clip 1 on the flat floor; the others on one terrain of each kind (two clips share the slope)."""
    up, sloped = stairs("up", step_height=0.15, seed=1), slope(angle_deg=-9.0, seed=2)
    return ClipTerrains([up, None, sloped, rough(seed=3), boxes(seed=4), sloped, stairs("down", seed=5)])


def test_torch_heights_equal_the_numpy_ones_on_random_points_of_generated_terrains(terrains: ClipTerrains) -> None:
    rng = np.random.default_rng(0)
    n = 40_000
    clip = rng.integers(0, len(terrains.index), n)
    x, y = rng.uniform(-2.0, 7.0, n), rng.uniform(-1.5, 1.5, n)  # beyond every strip's ends and sides too
    expected = terrains.height(clip, x, y)
    f32 = torch.float32
    got = TerrainField(terrains).height(torch.as_tensor(clip), torch.tensor(x, dtype=f32), torch.tensor(y, dtype=f32))
    assert got.dtype == torch.float32 and got.shape == (n,)
    np.testing.assert_allclose(got.numpy(), expected, atol=FLOAT32_HEIGHT_TOL, rtol=0)
    # The sample reaches every kind of place: the floor plane's 0, the features, and the off-grid floor.
    assert (expected[clip == 1] == 0).all() and np.isclose(expected, 0.15 * 6).any()
    assert np.isclose(expected, terrains.unique[0].floor).any()


def test_torch_heightmap_equals_the_numpy_one(terrains: ClipTerrains) -> None:
    rng = np.random.default_rng(1)
    n = 64
    clip = rng.integers(0, len(terrains.index), n)
    root = np.stack([rng.uniform(-1.0, 5.0, n), rng.uniform(-0.6, 0.6, n), rng.uniform(0.6, 1.3, n)], axis=-1)
    rot = rng.normal(size=(n, 4))
    rot /= np.linalg.norm(rot, axis=-1, keepdims=True)
    offsets = heightmap_offsets(1.0, 0.1)
    expected = heightmap(terrains, clip, root, rot, offsets)
    f32 = torch.float32
    got = torch_heightmap(TerrainField(terrains), torch.as_tensor(clip), torch.tensor(root, dtype=f32),
                          torch.tensor(rot, dtype=f32), torch.tensor(offsets, dtype=f32))  # fmt: skip
    assert got.shape == (n, 441)
    np.testing.assert_allclose(got.numpy(), expected, atol=FLOAT32_HEIGHT_TOL, rtol=0)


def test_the_gradient_is_the_slope_of_the_cells_triangle() -> None:
    """One cell of 0.5 m, heights h00 = 0, h10 = 1 (x + 1 cell), h01 = 2 (y + 1 cell), h11 = 4. Below the diagonal
    h = h00 + fu (h10 - h00) + fv (h11 - h10) = fu + 3 fv: (2, 6) per m; above it h = 2 fv + 2 fu: (4, 4) per m; off
    the grid the floor, 0.5 m under the lowest node, flat."""
    terrain = check_terrain(np.array([[0.0, 1.0], [2.0, 4.0]]), 0.5, np.array([1.0, -1.0]), "cell")
    field = TerrainField(ClipTerrains([terrain]))
    x = torch.tensor([1.0 + 0.5 * 0.75, 1.0 + 0.5 * 0.25, 0.5], requires_grad=True)
    y = torch.tensor([-1.0 + 0.5 * 0.25, -1.0 + 0.5 * 0.75, 0.0], requires_grad=True)
    h = field.height(torch.zeros(3, dtype=torch.int64), x, y)
    torch.testing.assert_close(h, torch.tensor([0.75 + 3 * 0.25, 2 * 0.75 + 2 * 0.25, -OFF_GRID_DROP]))
    h.sum().backward()
    torch.testing.assert_close(x.grad, torch.tensor([2.0, 4.0, 0.0]))
    torch.testing.assert_close(y.grad, torch.tensor([6.0, 4.0, 0.0]))


def test_a_blown_up_coordinate_reads_the_floor_instead_of_out_of_the_grid() -> None:
    terrain = check_terrain(np.array([[0.0, 1.0], [2.0, 4.0]]), 0.5, np.array([1.0, -1.0]), "cell")
    field = TerrainField(ClipTerrains([terrain, None]))
    bad = torch.tensor([float("nan"), float("inf"), -float("inf"), 3e38])
    h = field.height(torch.tensor([0, 0, 0, 1]), bad, torch.tensor([-0.8, -0.8, -0.8, 3e38]))
    torch.testing.assert_close(h, torch.tensor([-OFF_GRID_DROP, -OFF_GRID_DROP, -OFF_GRID_DROP, 0.0]))
