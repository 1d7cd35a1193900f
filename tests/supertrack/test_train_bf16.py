"""A SuperTrack debug run with both networks under bf16 autocast trains and resumes exactly (issue 58)."""

from __future__ import annotations

import math
from pathlib import Path

import torch

from common.run.directory import read_checkpoint
from common.run.logs import read_metrics
from supertrack.train import run

DEBUG = str(Path(__file__).resolve().parents[2] / "configs" / "supertrack" / "debug.yaml")
BF16 = ("--set", "world_model.bf16=true", "--set", "policy.bf16=true")


def test_bf16_debug_run_trains_and_resumes_exactly(tmp_path: Path) -> None:
    run(["--config", DEBUG, "--out", str(tmp_path / "a"), *BF16])
    run(["--config", DEBUG, "--out", str(tmp_path / "b"), "--max-iterations", "3", *BF16])
    run(["--out", str(tmp_path / "b"), "--resume", "--max-iterations", "6"])
    (_, a), (_, b) = read_checkpoint(tmp_path / "a"), read_checkpoint(tmp_path / "b")
    assert a["iteration"] == b["iteration"] == 6
    for net in ("world_model", "policy"):
        for name, value in a["learner"][net].items():
            assert value.dtype == torch.float32 or not value.is_floating_point(), f"{net}.{name}: {value.dtype}"
            assert torch.equal(value, b["learner"][net][name]), f"{net}.{name} differs after resume"
    records = read_metrics(tmp_path / "a" / "metrics.jsonl")
    losses = [r for r in records if "losses/policy" in r]
    assert losses and all(math.isfinite(r["losses/world_model"]) and math.isfinite(r["losses/policy"]) for r in losses)
    final_a, final_b = records[-1], read_metrics(tmp_path / "b" / "metrics.jsonl")[-1]
    assert final_a["eval/mpjpe_g"] == final_b["eval/mpjpe_g"] > 0.0
