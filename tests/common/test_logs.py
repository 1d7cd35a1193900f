"""Tests of common.run.logs: metrics logging, TensorBoard, timers, periodic triggers and progress."""

from __future__ import annotations

import io
import json
import logging
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import common.run.logs as logs_mod
from common.run.directory import RunDir
from common.run.logs import (
    Every,
    MetricsLogger,
    Progress,
    Timers,
    read_metrics,
)


class _FakeClock:
    """Clock that returns the queued times, for exact timing tests."""

    def __init__(self, *times: float) -> None:
        self._times = list(times)

    def __call__(self) -> float:
        return self._times.pop(0)


def test_metrics_lines_parse_and_nan_is_null(tmp_path: Path) -> None:
    with MetricsLogger(tmp_path, tensorboard=False) as logger:
        logger.log(1, {"losses/policy": 0.5, "eval/mpjpe_g": float("nan")}, samples=100, wall_clock_s=1.5)
        logger.log(2, {"losses/policy": np.float32(0.25), "eval/mpjpe_g": float("inf")}, samples=200, wall_clock_s=3)
        lines = (tmp_path / "metrics.jsonl").read_text().splitlines()
        assert len(lines) == 2  # flushed while the logger is still open
    assert json.loads(lines[0]) == {
        "iteration": 1,
        "samples": 100,
        "wall_clock_s": 1.5,
        "losses/policy": 0.5,
        "eval/mpjpe_g": None,
    }
    assert read_metrics(tmp_path)[1] == {
        "iteration": 2,
        "samples": 200,
        "wall_clock_s": 3.0,
        "losses/policy": 0.25,
        "eval/mpjpe_g": None,
    }
    with MetricsLogger(tmp_path, tensorboard=False) as logger, pytest.raises(ValueError, match="reserved"):
        logger.log(3, {"samples": 1.0}, samples=1, wall_clock_s=0)


def test_truncate_after_drops_later_lines(tmp_path: Path) -> None:
    with MetricsLogger(tmp_path, tensorboard=False) as logger:
        for it in range(1, 6):
            logger.log(it, {"m": it * 1.0}, samples=it * 10, wall_clock_s=it)
    with MetricsLogger(tmp_path, tensorboard=False) as logger:
        assert logger.truncate_after(3) == 2
        logger.log(4, {"m": 40.0}, samples=40, wall_clock_s=4)
    records = read_metrics(tmp_path / "metrics.jsonl")
    assert [(r["iteration"], r["m"]) for r in records] == [(1, 1.0), (2, 2.0), (3, 3.0), (4, 40.0)]


def test_cut_off_last_line_is_dropped_before_appending(tmp_path: Path) -> None:
    path = tmp_path / "metrics.jsonl"
    path.write_text('{"iteration": 1, "samples": 1, "wall_clock_s": 0.1}\n{"iteration": 2, "sam')
    assert [r["iteration"] for r in read_metrics(path)] == [1]
    with MetricsLogger(tmp_path, tensorboard=False) as logger:
        logger.log(2, {}, samples=2, wall_clock_s=0.2)
    assert [r["iteration"] for r in read_metrics(path)] == [1, 2]
    path.write_text('{"iteration": 1\n{"iteration": 2}\n')
    with pytest.raises(ValueError, match="metrics.jsonl:1: invalid JSON"):
        read_metrics(path)


class _FakeWriter:
    """Stands in for SummaryWriter; records every call."""

    instances: list[_FakeWriter] = []

    def __init__(self, log_dir: str, purge_step: int | None = None) -> None:
        self.log_dir, self.purge_step = log_dir, purge_step
        self.scalars: list[tuple[str, float, int]] = []
        self.closed = False
        _FakeWriter.instances.append(self)

    def add_scalar(self, tag: str, value: float, global_step: int) -> None:
        self.scalars.append((tag, value, global_step))

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self.closed = True


def test_tensorboard_gets_scalars_with_samples_as_step(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _FakeWriter.instances = []
    monkeypatch.setattr(logs_mod, "_import_summary_writer", lambda: _FakeWriter)
    logger = MetricsLogger(RunDir(tmp_path / "r", resume=False))
    assert _FakeWriter.instances == []  # opened lazily at the first log
    logger.log(1, {"a": 1.0}, samples=64, wall_clock_s=0.1)
    logger.log(2, {"a": 2.0}, samples=128, wall_clock_s=0.2)
    logger.truncate_after(1)
    logger.log(2, {"a": 3.0}, samples=128, wall_clock_s=0.3)
    logger.close()
    first, second = _FakeWriter.instances
    assert first.log_dir == str(tmp_path / "r" / "tb") and first.purge_step is None and first.closed
    assert first.scalars == [("a", 1.0, 64), ("a", 2.0, 128)]
    assert second.purge_step == 65 and second.scalars == [("a", 3.0, 128)] and second.closed


def test_missing_tensorboard_warns_once_and_keeps_json(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    import builtins

    real_import = builtins.__import__

    def no_tensorboard(name: str, *args: Any, **kwargs: Any) -> Any:
        if name.startswith("torch.utils.tensorboard"):
            raise ImportError("No module named 'tensorboard'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_tensorboard)
    monkeypatch.setattr(logs_mod, "_tb_warned", False)
    with caplog.at_level(logging.WARNING, logger="common.run.logs"):
        for sub in ("a", "b"):
            with MetricsLogger(tmp_path / sub) as logger:
                logger.log(1, {"x": 1.0}, samples=1, wall_clock_s=0)
    messages = [r.getMessage() for r in caplog.records]
    assert messages == ["tensorboard is not installed; logging metrics to metrics.jsonl only"]
    assert read_metrics(tmp_path / "b")[0]["x"] == 1.0
    assert not (tmp_path / "b" / "tb").exists()


def test_timer_shares_sum_to_one() -> None:
    timers = Timers(clock=_FakeClock(0.0, 1.0, 1.0, 4.0, 10.0, 12.0))
    with timers("gym"):
        pass
    with timers("update"):
        pass
    with timers("gym"):
        pass
    assert timers.totals == {"gym": 3.0, "update": 3.0}
    assert timers.shares() == {"gym": 0.5, "update": 0.5}
    assert math.isclose(sum(timers.shares().values()), 1.0)
    shares = {"perf/gym_share": 0.5, "perf/update_share": 0.5}
    assert timers.metrics() == {**shares, "perf/gym_s": 3.0, "perf/update_s": 3.0}
    timers.reset()
    assert timers.shares() == {}


def test_timer_counts_time_of_block_that_raises() -> None:
    timers = Timers(clock=_FakeClock(2.0, 2.5))
    with pytest.raises(KeyError), timers("gym"):
        raise KeyError("x")
    assert timers.totals == {"gym": 0.5}


def test_every() -> None:
    every = Every(3)
    assert [s for s in range(10) if every.should(s)] == [3, 6, 9]
    assert [s for s in range(5) if Every(2, at_start=True)(s)] == [0, 2, 4]
    assert not any(Every(0).should(s) for s in range(5))


def test_progress_prints_plain_lines_when_not_a_tty() -> None:
    stream = io.StringIO()
    clock = _FakeClock(0.0, 2.0, 2.0, 4.0, 4.0, 5.0, 5.0)
    keys = ("eval/mpjpe_g",)
    with Progress(5, "ppo", initial_samples=100, keys=keys, plain_every=2, stream=stream, clock=clock) as p:
        for it in range(1, 6):
            p.update(samples=100 + 100 * it, metrics={"eval/mpjpe_g": 0.125 * it, "losses/policy": 9.0})
    assert stream.getvalue().splitlines() == [
        "ppo: 2/5 [2s] 100 samples/s, eval/mpjpe_g=0.25",
        "ppo: 4/5 [4s] 100 samples/s, eval/mpjpe_g=0.5",
        "ppo: 5/5 [5s] 100 samples/s, eval/mpjpe_g=0.625",
    ]
