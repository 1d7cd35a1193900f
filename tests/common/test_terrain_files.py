"""A clip's terrain through every writer and reader (the ``.txt`` sidecar, clip packs, motion datasets), and bad
terrains refused in one line."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.motion.dataset import (
    DATASET_TERRAIN_VERSION,
    DATASET_VERSION,
    bundled_motion_dir,
    load_dataset,
    resolve_clips,
    save_dataset,
)
from common.motion.library import MotionLibrary
from common.motion.motion import (
    CLIP_PACK_TERRAIN_VERSION,
    CLIP_PACK_VERSION,
    MotionFormatError,
    read_clip_pack,
    read_deepmimic,
    write_clip_pack,
)
from common.motion.motion_import.deepmimic import write_deepmimic
from common.motion.terrain import SIDECAR_FORMAT, Terrain, read_sidecar, sidecar_path, write_sidecar
from common.motion.terrain_generator import rough, stairs


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


@pytest.fixture()
def clip_on_stairs(tmp_path: Path) -> tuple[Path, Terrain]:
    path = tmp_path / "walk_up.txt"
    shutil.copy(bundled_motion_dir() / "humanoid3d_walk.txt", path)
    terrain = stairs("up", steps=3, seed=5)
    write_sidecar(path, terrain)
    return path, terrain


def _same(a: Terrain | None, b: Terrain) -> None:
    assert a is not None
    np.testing.assert_array_equal(a.heights, b.heights)
    np.testing.assert_array_equal(a.origin, b.origin)
    assert a.cell_size == b.cell_size


def test_sidecar_travels_with_a_txt_clip(clip_on_stairs: tuple[Path, Terrain], tmp_path: Path) -> None:
    path, terrain = clip_on_stairs
    assert sidecar_path(path) == tmp_path / "walk_up.terrain.h5"
    _same(read_deepmimic(path).terrain, terrain)
    _same(resolve_clips([str(path)])[0].terrain, terrain)
    _same(resolve_clips([str(tmp_path)])[0].terrain, terrain)  # a folder of clips
    assert resolve_clips(["walk"])[0].terrain is None
    # The .txt writer writes the sidecar, and removes a stale one when the clip is flat.
    clip = read_deepmimic(path)
    out = tmp_path / "out" / "copy.txt"
    out.parent.mkdir()
    write_deepmimic(out, clip)
    _same(read_deepmimic(out).terrain, terrain)
    write_deepmimic(out, replace(clip, terrain=None))
    assert not sidecar_path(out).exists() and read_deepmimic(out).terrain is None


def test_clip_pack_keeps_terrains_beside_the_rows(clip_on_stairs: tuple[Path, Terrain], tmp_path: Path) -> None:
    path, terrain = clip_on_stairs
    pack = tmp_path / "pack.h5"
    write_clip_pack(pack, [path, bundled_motion_dir() / "humanoid3d_run.txt"])
    with h5py.File(pack) as f:
        assert f.attrs["version"] == CLIP_PACK_TERRAIN_VERSION and list(f["terrains"]) == ["walk_up"]
    clips = {c.name: c for c in read_clip_pack(pack)}
    assert sorted(clips) == ["run", "walk_up"]
    _same(clips["walk_up"].terrain, terrain)
    assert all(c.terrain is None for name, c in clips.items() if name != "walk_up")
    flat = tmp_path / "flat.h5"
    write_clip_pack(flat, [bundled_motion_dir() / "humanoid3d_run.txt"])
    with h5py.File(flat) as f:
        assert f.attrs["version"] == CLIP_PACK_VERSION and "terrains" not in f


def test_motion_dataset_keeps_terrains_beside_the_frames(humanoid: Humanoid, tmp_path: Path) -> None:
    walk = resolve_clips(["walk"])[0]
    terrain = rough(seed=3)
    library = MotionLibrary.from_clips([walk, replace(walk, name="walk_rough", terrain=terrain)], humanoid)
    path = tmp_path / "motions.h5"
    save_dataset(path, library, humanoid)
    with h5py.File(path) as f:
        assert f.attrs["version"] == DATASET_TERRAIN_VERSION and "terrain" in f["clips/walk_rough"]
    loaded = load_dataset(path, humanoid)
    assert loaded.clips[0].terrain is None
    _same(loaded.clips[1].terrain, terrain)
    flat = tmp_path / "flat.h5"
    save_dataset(flat, MotionLibrary.from_clips([walk], humanoid), humanoid)
    with h5py.File(flat) as f:
        assert f.attrs["version"] == DATASET_VERSION


def _sidecar(tmp_path: Path, heights: Any, cell: Any = 0.1, origin: Any = (-1.0, -1.0), fmt: str = SIDECAR_FORMAT,
             drop: str = "") -> Path:  # fmt: skip
    """A clip with a hand-written sidecar (no writer's checks)."""
    path = tmp_path / "bad.txt"
    shutil.copy(bundled_motion_dir() / "humanoid3d_walk.txt", path)
    with h5py.File(sidecar_path(path), "w") as f:
        f.attrs["format"], f.attrs["version"] = fmt, 1
        g = f.create_group("terrain")
        for name, value in (("heights", heights), ("origin", origin)):
            if name != drop:
                g.create_dataset(name, data=value)
        if drop != "cell_size":
            g.attrs["cell_size"] = cell
    return path


GOOD = np.zeros((5, 6))


@pytest.mark.parametrize(
    ("kwargs", "problem"),
    [
        ({"heights": np.where(np.arange(30).reshape(5, 6) == 13, np.nan, 0.0)}, "row 2, column 1 is not finite"),
        ({"heights": np.full((5, 6), 1e4)}, "terrain height 10000 m at row 0, column 0 is beyond +-100 m"),
        ({"heights": np.zeros((1, 6))}, "shape (1, 6), expected (rows, cols) of at least 2 x 2"),
        ({"heights": np.zeros(6)}, "shape (6,), expected (rows, cols)"),
        ({"heights": np.array([["a", "b"], ["c", "d"]], dtype="S1")}, "not numbers"),
        ({"heights": GOOD, "cell": 0.0}, "cell_size 0.0 m is outside 0.005 to 1 m"),
        ({"heights": GOOD, "cell": "0.1"}, "attribute 'cell_size' must be a finite number"),
        ({"heights": GOOD, "origin": (0.0, 0.0, 0.0)}, "'origin' has shape (3,)"),
        ({"heights": GOOD, "origin": (500.0, 0.0)}, "reaches 500.5 m from the origin, farther than 200 m"),
        ({"heights": GOOD, "drop": "heights"}, "no 'heights' array"),
        ({"heights": GOOD, "fmt": "something.else"}, "not a terrain file (format 'something.else')"),
    ],
)
def test_a_bad_terrain_is_refused_in_one_line(tmp_path: Path, kwargs: dict, problem: str) -> None:
    path = _sidecar(tmp_path, **kwargs)
    with pytest.raises(MotionFormatError) as e:
        resolve_clips([str(path)])
    message = str(e.value)
    assert "\n" not in message and message.startswith(str(sidecar_path(path))) and problem in message, message


def test_a_bad_terrain_in_a_dataset_or_pack_is_refused(humanoid: Humanoid, tmp_path: Path,
                                                       clip_on_stairs: tuple[Path, Terrain]) -> None:  # fmt: skip
    path, _ = clip_on_stairs
    pack = tmp_path / "pack.h5"
    write_clip_pack(pack, [path])
    with h5py.File(pack, "r+") as f:
        f["terrains/walk_up/heights"][0, 0] = np.inf
    with pytest.raises(MotionFormatError, match=r"pack\.h5:walk_up: terrain height at row 0, column 0 is not finite"):
        read_clip_pack(pack)
    data = tmp_path / "motions.h5"
    save_dataset(data, MotionLibrary.from_clips([read_deepmimic(path)], humanoid), humanoid)
    with h5py.File(data, "r+") as f:
        f["clips/walk_up/terrain/heights"][1, 2] = 2e4
    with pytest.raises(MotionFormatError, match=r"clip 'walk_up': terrain height 20000 m at row 1, column 2"):
        load_dataset(data, humanoid)
    with pytest.raises(MotionFormatError, match="is not finite"):
        write_sidecar(tmp_path / "x.txt", Terrain(np.full((2, 2), np.nan), 0.1, np.zeros(2)))
    assert read_sidecar(tmp_path / "none.txt") is None
