"""``train-ppo``'s debug run on a clip with a terrain, observing the heightmap and contact labels: it trains, and a
resumed run continues exactly."""

from __future__ import annotations

import shutil
from pathlib import Path

import torch

from common.motion.dataset import bundled_motion_dir
from common.motion.terrain import write_sidecar
from common.motion.terrain_generator import stairs
from common.run.directory import read_checkpoint
from ppo.train import main

DEBUG = str(Path(__file__).resolve().parents[2] / "configs" / "ppo" / "debug.yaml")
TERRAIN_FEATURES = ("--set", "observation.heightmap_extent=0.3", "--set", "observation.contact_frames=[1, 4]")


def _run(out: Path, clip: Path, *extra: str) -> None:
    assert main(["--config", DEBUG, "--out", str(out), "--motions", str(clip), "walk", *TERRAIN_FEATURES, *extra]) == 0


def test_terrain_debug_run_resumes_exactly(tmp_path: Path) -> None:
    clip = tmp_path / "walk_up.txt"
    shutil.copy(bundled_motion_dir() / "humanoid3d_walk.txt", clip)
    write_sidecar(clip, stairs("up", steps=4, step_height=0.08, seed=0))
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    _run(straight, clip, "--max-iterations", "4")
    _run(resumed, clip, "--max-iterations", "2")
    _run(resumed, clip, "--resume", "--max-iterations", "4")
    a, b = read_checkpoint(straight)[1]["learner"], read_checkpoint(resumed)[1]["learner"]
    for name, value in a["net"].items():
        torch.testing.assert_close(b["net"][name], value, rtol=0, atol=0, msg=name)
    mask = a["normalizer"]["mask"]
    assert mask.sum() < mask.size  # the heightmap and contact labels (and nothing else here) are left raw
    assert mask.size - mask.sum() == 49 + 2 * 15
