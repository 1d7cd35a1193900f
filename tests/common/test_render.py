"""MP4 output: frames -> video with synthetic frames (always), and a clip rendered offscreen (where GL works)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common.tools import render
from common.tools.motions import main as mimic_motions


def _read_video(path: Path) -> tuple[dict, list[np.ndarray]]:
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    w, h = meta["size"]
    return meta, [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in reader]


def test_frames_to_mp4_round_trip(tmp_path: Path) -> None:
    # Ten 64 x 48 frames: a flat grey that brightens by 20 a frame, with a red left half.
    frames = []
    for k in range(10):
        f = np.full((48, 64, 3), 40 + 20 * k, np.uint8)
        f[:, :32] = [200, 30, 30]
        frames.append(f)
    out = tmp_path / "synthetic.mp4"
    out.write_bytes(b"old")
    assert render.write_video(iter(frames), out, fps=30.0) == 10
    meta, back = _read_video(out)
    assert meta["size"] == (64, 48) and meta["fps"] == pytest.approx(30.0)
    assert len(back) == 10
    for k, f in enumerate(back):
        # Lossy H.264 with chroma subsampling: flat areas come back within a few levels.
        assert abs(float(f[:, 40:].mean()) - (40 + 20 * k)) < 6
        np.testing.assert_allclose(f[8:40, 4:28].reshape(-1, 3).mean(0), [200, 30, 30], atol=12)


def test_no_frames_keeps_the_old_file(tmp_path: Path) -> None:
    out = tmp_path / "kept.mp4"
    out.write_bytes(b"old")
    with pytest.raises(ValueError, match="no frames"):
        render.write_video(iter([]), out, fps=30.0)
    assert out.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["kept.mp4"]


@pytest.fixture(scope="module")
def backend() -> str:
    found, why = render.find_backend()
    if found is None:
        pytest.skip(why)
    return found


def test_render_command_plays_a_clip(tmp_path: Path, backend: str) -> None:
    out = tmp_path / "walk.mp4"
    assert mimic_motions(["render", "walk", "--seconds", "0.5", "--size", "96", "64", "--out", str(out)]) == 0
    meta, frames = _read_video(out)
    assert meta["size"] == (96, 64) and len(frames) == 31  # 0.5 s at 60 Hz, both ends included
    # The character moves: consecutive frames differ, and a frame is not one flat colour.
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).max() > 30
    assert frames[0].std() > 10


def test_kinematic_playback_has_no_ghost(tmp_path: Path, backend: str) -> None:
    from tests.report.test_watch import _orange

    out = tmp_path / "jog.mp4"
    assert mimic_motions(["render", "jog", "--seconds", "0.1", "--size", "96", "64", "--out", str(out)]) == 0
    _, frames = _read_video(out)
    assert all(_orange(f) == 0 for f in frames)


def test_render_draws_the_clips_terrain(tmp_path: Path, backend: str) -> None:
    from dataclasses import replace

    from common.motion.dataset import resolve_clips
    from common.motion.motion_import.deepmimic import write_deepmimic
    from common.motion.terrain import Terrain

    # The walk on the flat floor, on a level terrain at height 0, and on it with a 25 cm box to the character's
    # right (x 0.8 to 1.4 m, |y| <= 0.3 m; the camera looks along +y, +x to the right of the picture).
    walk = resolve_clips(["walk"])[0]
    xs, ys = -1.0 + 0.05 * np.arange(81), -1.0 + 0.05 * np.arange(41)
    box = np.zeros((41, 81))
    box[np.ix_(np.abs(ys) <= 0.3 + 1e-9, (xs >= 0.8 - 1e-9) & (xs <= 1.4 + 1e-9))] = 0.25
    clips = {"flat": walk, "level": replace(walk, terrain=Terrain(np.zeros((41, 81)), 0.05, np.array([-1.0, -1.0]))),
             "box": replace(walk, terrain=Terrain(box, 0.05, np.array([-1.0, -1.0])))}  # fmt: skip
    first = {}
    for name, clip in clips.items():
        write_deepmimic(tmp_path / f"{name}.txt", clip)  # the terrain in its .terrain.h5 sidecar
        out = tmp_path / f"{name}.mp4"
        assert mimic_motions(["render", str(tmp_path / f"{name}.txt"), "--seconds", "0.05", "--size", "96", "64",
                              "--out", str(out)]) == 0  # fmt: skip
        first[name] = _read_video(out)[1][0].astype(int)
    # The box is drawn: where it stands, and only there, the picture differs from the level terrain's (measured: 89
    # pixels in columns 66-80, rows 48-53, the character in the middle of the picture).
    changed = np.abs(first["box"] - first["level"]).max(axis=-1) > 40
    rows, cols = np.nonzero(changed)
    assert changed.sum() > 30 and cols.min() > 60 and rows.min() > 40
    # And it differs from the flat clip's picture there.
    assert (np.abs(first["box"] - first["flat"]).max(axis=-1) > 40)[changed].mean() > 0.9
