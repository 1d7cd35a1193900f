"""``train-supertrack``'s debug run on clips with a terrain: without terrain inputs (simulated on it only) and with
them (the heightmap, W's contact output, the reference's contact labels, supertrack/terrain.py), a resumed run
continues exactly; the checkpoint's policy, rebuilt for the report, evaluates as the trainer did."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import pytest
import torch

from common.character.humanoid import Humanoid
from common.config import load_config
from common.evaluation.evaluate import evaluate
from common.motion.dataset import bundled_motion_dir, load_motions
from common.motion.terrain import write_sidecar
from common.motion.terrain_generator import slope, stairs
from common.run.directory import read_checkpoint
from common.run.logs import read_metrics
from supertrack.config import SuperTrackConfig
from supertrack.export import load_eval_policy, onnx_module
from supertrack.train import run

DEBUG = str(Path(__file__).resolve().parents[2] / "configs" / "supertrack" / "debug.yaml")
TERRAIN = ("--set", "terrain.heightmap_extent=0.5", "--set", "terrain.contact_weight=1.0", "--set",
           "terrain.contact_frames=[1, 4]")  # fmt: skip


def _clip(root: Path, name: str, terrain: object) -> str:
    clip = root / f"{name}.txt"
    shutil.copy(bundled_motion_dir() / "humanoid3d_walk.txt", clip)
    write_sidecar(clip, terrain)
    return str(clip)


def _assert_same_networks(a: Path, b: Path) -> None:
    (_, sa), (_, sb) = read_checkpoint(a), read_checkpoint(b)
    assert sa["iteration"] == sb["iteration"] == 4 and sa["samples"] == sb["samples"]
    for net in ("world_model", "policy"):
        for name, value in sa["learner"][net].items():
            assert torch.equal(value, sb["learner"][net][name]), f"{net}.{name} differs after resume"


def test_terrain_debug_run_resumes_exactly(tmp_path: Path) -> None:
    clip = _clip(tmp_path, "walk_slope", slope(angle_deg=6.0, seed=0))
    base = ["--config", DEBUG, "--motions", clip, "walk", "--set", "train.eval_every_iterations=2"]
    run([*base, "--out", str(tmp_path / "a"), "--max-iterations", "4"])
    run([*base, "--out", str(tmp_path / "b"), "--max-iterations", "2"])
    run(["--out", str(tmp_path / "b"), "--resume", "--max-iterations", "4"])
    _assert_same_networks(tmp_path / "a", tmp_path / "b")


def test_terrain_inputs_debug_run_trains_resumes_exactly_and_evaluates_as_trained(tmp_path: Path) -> None:
    """With a collector process (the terrain inputs travel to it with the actor) and 12-frame episodes (windows from
    all three clips)."""
    clips = [_clip(tmp_path, "walk_slope", slope(angle_deg=6.0, seed=0)), "walk",
             _clip(tmp_path, "walk_stairs", stairs("up", 6, 0.08))]  # fmt: skip
    base = ["--config", DEBUG, "--motions", *clips, "--set", "train.eval_every_iterations=2", "--set",
            "collect.processes=1", "--set", "gym.termination.max_episode_frames=12", *TERRAIN]  # fmt: skip
    run([*base, "--out", str(tmp_path / "a"), "--max-iterations", "4"])
    run([*base, "--out", str(tmp_path / "b"), "--max-iterations", "2"])
    run(["--out", str(tmp_path / "b"), "--resume", "--max-iterations", "4"])
    _assert_same_networks(tmp_path / "a", tmp_path / "b")
    a, b = (read_metrics(tmp_path / k / "metrics.jsonl") for k in ("a", "b"))
    last = [next(r for r in records if r["iteration"] == 4 and "losses/policy" in r) for records in (a, b)]
    assert {k: v for k, v in last[0].items() if k.startswith("losses/")} == \
        {k: v for k, v in last[1].items() if k.startswith("losses/")}  # fmt: skip
    assert math.isfinite(last[0]["losses/world_model_contact"]) and last[0]["losses/world_model_contact"] > 0.0
    cfg = load_config(SuperTrackConfig, tmp_path / "a" / "config.yaml")
    humanoid = Humanoid(cfg.gym.physics)
    library = load_motions(clips, humanoid)
    checkpoint, _ = read_checkpoint(tmp_path / "a")
    result = evaluate(load_eval_policy(tmp_path / "a", checkpoint, humanoid, library), library, humanoid,
                      cfg.train.eval)  # fmt: skip
    logged = next(r for r in reversed(a) if "eval/mpjpe_g" in r)
    assert logged["iteration"] == 4 and result.as_metrics()["eval/mpjpe_g"] == logged["eval/mpjpe_g"]
    with pytest.raises(ValueError, match="reads terrain inputs"):
        onnx_module(tmp_path / "a", checkpoint, humanoid)
