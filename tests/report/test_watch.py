"""``watch-policy``: a tiny PPO debug run played on the walk clip and written as an MP4 with the reference ghost."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import pytest
import torch

from common.tools import render
from ppo.train import main as train_ppo
from report import watch
from tests.common.test_render import _read_video

ROOT = Path(__file__).resolve().parents[2]


def _orange(frame: np.ndarray) -> int:
    """Pixels of the ghost's hue (render.GHOST_RGBA is orange: red high, blue low)."""
    r, g, b = (frame[..., i].astype(int) for i in range(3))
    return int(np.sum((r > b + 25) & (r > g + 5)))


def test_watch_writes_the_policy_with_its_ghost(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    if render.find_backend()[0] is None:
        pytest.skip(render.find_backend()[1])
    torch.set_num_threads(1)
    train_ppo(["--config", str(ROOT / "configs/ppo/debug.yaml"), "--out", str(tmp_path / "run")])
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert not watch.has_display()
    # No display and no --out: the video goes into the run directory.
    assert watch.main([str(tmp_path / "run"), "--frames", "12", "--size", "96", "64"]) == 0
    meta, frames = _read_video(tmp_path / "run" / "watch_walk.mp4")
    assert meta["size"] == (96, 64) and len(frames) == 12
    assert all(_orange(f) > 20 for f in frames)  # the translucent reference is drawn in every frame
    # A clip on a terrain: simulated on it by the gym, and drawn on it.
    from dataclasses import replace

    from common.motion.dataset import resolve_clips
    from common.motion.motion_import.deepmimic import write_deepmimic
    from common.motion.terrain_generator import stairs

    terrain = stairs("up", steps=3, step_height=0.05, seed=0)
    write_deepmimic(tmp_path / "walk_up.txt", replace(resolve_clips(["walk"])[0], terrain=terrain))
    drawn = []
    video = render.video
    monkeypatch.setattr(render, "video", lambda *a, **k: drawn.append(k["terrain"]) or video(*a, **k))
    out = tmp_path / "up.mp4"
    assert watch.main([str(tmp_path / "run"), "--motions", str(tmp_path / "walk_up.txt"), "--frames", "6", "--size",
                       "96", "64", "--out", str(out)]) == 0  # fmt: skip
    assert len(_read_video(out)[1]) == 6
    np.testing.assert_array_equal(drawn[0].heights, terrain.heights)


def test_watch_names_a_bad_run_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert watch.main([str(tmp_path / "nothing")]) == 2
    assert capsys.readouterr().err.strip() == f"error: {tmp_path / 'nothing'}: not a directory"


class _FakeViewer:
    """Stands in for mujoco.viewer's passive handle: three frames, each recorded at sync()."""

    def __init__(self, model: object, data: object) -> None:
        import mujoco

        self.model, self.data = model, data
        self.user_scn = mujoco.MjvScene(model, maxgeom=100)
        self.opt, self.perturb = mujoco.MjvOption(), mujoco.MjvPerturb()
        self.synced: list[tuple[np.ndarray, int, np.ndarray]] = []

    def __enter__(self) -> _FakeViewer:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def is_running(self) -> bool:
        return len(self.synced) < 3

    def lock(self) -> contextlib.AbstractContextManager:
        return contextlib.nullcontext()

    def sync(self) -> None:
        self.synced.append((self.data.qpos.copy(), self.user_scn.ngeom, self.user_scn.geoms[0].rgba.copy()))


def test_viewer_plays_the_episode_with_the_ghost(monkeypatch: pytest.MonkeyPatch) -> None:
    import mujoco.viewer

    from common.character.humanoid import Humanoid
    from common.motion.dataset import load_motions

    humanoid = Humanoid()
    ref = load_motions(["walk"], humanoid).frames.qpos[:2]
    sim = ref.copy()
    sim[:, 0] += 0.5
    viewers: list[_FakeViewer] = []
    monkeypatch.setattr(mujoco.viewer, "launch_passive", lambda m, d: viewers.append(_FakeViewer(m, d)) or viewers[-1])
    watch.view(sim, ref, humanoid, fps=1000.0)
    shown = viewers[0].synced
    # Frames 0, 1, then 0 again (the episode loops); one ghost geom per body, in the ghost's colour.
    for (qpos, ngeom, rgba), t in zip(shown, (0, 1, 0), strict=True):
        np.testing.assert_array_equal(qpos, sim[t])
        assert ngeom == humanoid.num_bodies
        np.testing.assert_allclose(rgba, render.GHOST_RGBA, atol=1e-6)
    assert viewers[0].model is humanoid.model  # a flat clip: the plain model


def test_viewer_shows_the_clips_terrain(monkeypatch: pytest.MonkeyPatch) -> None:
    import mujoco
    import mujoco.viewer

    from common.character.humanoid import Humanoid
    from common.motion.dataset import load_motions
    from common.motion.terrain_generator import stairs
    from common.sim.terrain import TERRAIN_GEOM

    humanoid = Humanoid()
    ref = load_motions(["walk"], humanoid).frames.qpos[:2]
    viewers: list[_FakeViewer] = []
    monkeypatch.setattr(mujoco.viewer, "launch_passive", lambda m, d: viewers.append(_FakeViewer(m, d)) or viewers[-1])
    terrain = stairs("up", steps=3, step_height=0.1, seed=0)
    watch.view(ref, ref, humanoid, fps=1000.0, terrain=terrain)
    # The gym's terrain model: the heightfield geom colliding like the floor, the floor moved under it.
    model = viewers[0].model
    geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, TERRAIN_GEOM)
    assert model.nhfield == 1 and model.geom_contype[geom] == 1
    assert model.hfield_nrow[0] == terrain.shape[0] and model.hfield_ncol[0] == terrain.shape[1]
    assert model.geom_pos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")][2] == terrain.floor
    assert len(viewers[0].synced) == 3
