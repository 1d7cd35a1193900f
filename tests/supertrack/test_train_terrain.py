"""``train-supertrack``'s debug run on a clip with a terrain (simulated on it; SuperTrack does not observe it yet): a
resumed run continues exactly."""

from __future__ import annotations

import shutil
from pathlib import Path

import torch

from common.motion.dataset import bundled_motion_dir
from common.motion.terrain import write_sidecar
from common.motion.terrain_generator import slope
from common.run.directory import read_checkpoint
from supertrack.train import run

DEBUG = str(Path(__file__).resolve().parents[2] / "configs" / "supertrack" / "debug.yaml")


def test_terrain_debug_run_resumes_exactly(tmp_path: Path) -> None:
    clip = tmp_path / "walk_slope.txt"
    shutil.copy(bundled_motion_dir() / "humanoid3d_walk.txt", clip)
    write_sidecar(clip, slope(angle_deg=6.0, seed=0))
    base = ["--config", DEBUG, "--motions", str(clip), "walk", "--set", "train.eval_every_iterations=2"]
    run([*base, "--out", str(tmp_path / "a"), "--max-iterations", "4"])
    run([*base, "--out", str(tmp_path / "b"), "--max-iterations", "2"])
    run(["--out", str(tmp_path / "b"), "--resume", "--max-iterations", "4"])
    a, b = (read_checkpoint(tmp_path / k)[1] for k in ("a", "b"))
    assert a["iteration"] == b["iteration"] == 4 and a["samples"] == b["samples"]
    for net in ("world_model", "policy"):
        for name, value in a["learner"][net].items():
            assert torch.equal(value, b["learner"][net][name]), f"{net}.{name} differs after resume"
