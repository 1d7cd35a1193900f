"""benchmarks/run_curve.py: one row per evaluation, training columns averaged since the previous one, by hand."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.benchmark_module import benchmark_module


def _module():
    return benchmark_module("run_curve")


def test_each_evaluation_gets_the_mean_of_the_training_records_before_it() -> None:
    """A PPO run from before the shared chart keys (``charts/mean_reward``): read as ``charts/reward``."""
    records = [
        {"iteration": 10, "samples": 1000, "wall_clock_s": 10.0, "charts/mean_reward": 0.5,
         "charts/term/body_pos_per_1k": 4.0, "reward/root_pos": 0.9},
        {"iteration": 20, "samples": 2000, "wall_clock_s": 20.0, "charts/mean_reward": 0.7,
         "charts/term/body_pos_per_1k": 2.0, "reward/root_pos": 0.8},
        {"iteration": 20, "samples": 2000, "wall_clock_s": 30.0, "eval/mpjpe_g": 123.45, "eval/mpjpe_l": 50.0,
         "eval/survival": 0.75, "eval/success": 0.5},
        {"iteration": 30, "samples": 3_500_000, "wall_clock_s": 600.0, "charts/mean_reward": 0.9},
        {"iteration": 30, "samples": 3_500_000, "wall_clock_s": 600.0, "eval/mpjpe_g": 60.0, "eval/mpjpe_l": 30.0,
         "eval/survival": 1.0, "eval/success": 1.0},
    ]  # fmt: skip
    header, rows = _module().curve_rows(records)
    assert header == ["min", "samples", "MPJPE-g", "MPJPE-l", "surv", "succ", "reward", "body_pos/1k",
                      "reward/root_pos"]  # fmt: skip
    # First evaluation: reward (0.5 + 0.7) / 2, body_pos ends (4 + 2) / 2, root_pos term (0.9 + 0.8) / 2.
    assert rows[0] == ["0.5", "0.00M", "123.5", "50.0", "0.75", "0.50", "0.600", "3.0", "0.850"]
    # Second: only the one record since; the keys it lacks are "-".
    assert rows[1] == ["10.0", "3.50M", "60.0", "30.0", "1.00", "1.00", "0.900", "-", "-"]


def test_a_broken_record_is_named_by_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "metrics.jsonl"
    path.write_text(json.dumps({"iteration": 1}) + "\n{not json\n", encoding="utf-8")
    with pytest.raises(ValueError, match=r"metrics.jsonl:2: not a JSON record"):
        _module().read_metrics(path)


def test_either_learners_run_shows_the_shared_keys() -> None:
    """Both learners log charts/reward, charts/terminated_share, charts/term/* and reward/* today."""
    records = [
        {"iteration": 1, "samples": 64, "wall_clock_s": 6.0, "charts/reward": 0.25, "charts/terminated_share": 0.5,
         "charts/episode_length": 30.0, "charts/term/root_pos_per_1k": 1.5, "reward/pose": 0.5},
        {"iteration": 2, "samples": 128, "wall_clock_s": 12.0, "charts/reward": 0.75, "charts/terminated_share": 0.0,
         "charts/episode_length": 50.0, "charts/term/root_pos_per_1k": 0.5, "reward/pose": 0.75},
        {"iteration": 2, "samples": 128, "wall_clock_s": 18.0, "eval/mpjpe_g": 90.0, "eval/mpjpe_l": 40.0,
         "eval/survival": 0.5, "eval/success": 0.25},
    ]  # fmt: skip
    header, rows = _module().curve_rows(records)
    assert header == ["min", "samples", "MPJPE-g", "MPJPE-l", "surv", "succ", "ep len", "failed", "reward",
                      "root_pos/1k", "reward/pose"]  # fmt: skip
    # Means of the two training records: length (30 + 50) / 2, failed (0.5 + 0) / 2, reward (0.25 + 0.75) / 2, ...
    assert rows == [["0.3", "0.00M", "90.0", "40.0", "0.50", "0.25", "40.0", "0.25", "0.500", "1.0", "0.625"]]
