"""Training-loop logging shared by ``train-supertrack`` and ``train-ppo``.

``metrics.jsonl`` and TensorBoard writing (:class:`MetricsLogger`, :func:`read_metrics`), named wall-clock
timers (:class:`Timers`), a periodic trigger (:class:`Every`) and the progress display (:class:`Progress`).
The run directory itself is in :mod:`common.run.directory`.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any, TextIO

import tqdm

from common.cli import one_line, take_thread_failure
from common.config import atomic_output
from common.run.directory import RunDir
from common.strict_json import parse_json

log = logging.getLogger(__name__)

_RESERVED_METRIC_KEYS = ("iteration", "samples", "wall_clock_s")
_tb_warned = False


def _import_summary_writer() -> type | None:
    """``SummaryWriter`` if the tensorboard package is importable, else None (after one warning)."""
    global _tb_warned
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        if not _tb_warned:
            log.warning("tensorboard is not installed; logging metrics to metrics.jsonl only")
            _tb_warned = True
        return None
    return SummaryWriter


class MetricsLogger:
    """Append metrics to ``metrics.jsonl`` and, when available, TensorBoard (global step = samples).

    A write that fails (a full disk) raises ``OSError`` naming ``metrics.jsonl`` or ``tb/``, at the record it failed
    on: TensorBoard's writer thread is flushed after every record, and its failure, which a command keeps from
    printing a traceback (:func:`common.cli.one_line_errors`), is raised here.

    Args:
        run_dir: A :class:`RunDir` or a directory path.
        tensorboard: Also write TensorBoard events under ``tb/`` if the package is installed.
    """

    def __init__(self, run_dir: RunDir | str | Path, tensorboard: bool = True) -> None:
        root = run_dir.path if isinstance(run_dir, RunDir) else Path(run_dir)
        self.path = root / "metrics.jsonl"
        self.tb_dir = root / "tb"
        root.mkdir(parents=True, exist_ok=True)
        self._drop_partial_last_line()
        self._file: TextIO = self.path.open("a", encoding="utf-8")
        self._writer_cls = _import_summary_writer() if tensorboard else None
        # Created at the first log so that a resume (truncate_after, then log) opens one events file, not two.
        self._writer: Any = None
        self._purge_step: int | None = None
        self._failed = False  # a write failed: the error is on its way, close() adds none

    def log(self, step: int, metrics: Mapping[str, float], samples: int, wall_clock_s: float) -> dict[str, Any]:
        """Write one line ``{"iteration", "samples", "wall_clock_s", **metrics}``; non-finite values become null.

        Args:
            step: Training iteration.
            metrics: Scalars keyed like ``"eval/mpjpe_g"`` or ``"losses/policy"``.
            samples: Environment samples so far (TensorBoard's global step).
            wall_clock_s: Seconds of training so far.

        Returns:
            The record written.
        """
        clash = [k for k in _RESERVED_METRIC_KEYS if k in metrics]
        if clash:
            raise ValueError(f"metric names {clash} are reserved")
        values = {k: float(v) for k, v in metrics.items()}
        record: dict[str, Any] = {"iteration": int(step), "samples": int(samples), "wall_clock_s": float(wall_clock_s)}
        # JSON has no NaN/Infinity; null keeps every line parseable by strict readers.
        record.update({k: v if math.isfinite(v) else None for k, v in values.items()})
        try:
            self._file.write(json.dumps(record, allow_nan=False) + "\n")
            self._file.flush()
        except OSError as e:
            raise self._failure(e, self.path) from None
        if self._writer_cls is None:
            return record
        try:
            if self._writer is None:
                self._writer = self._writer_cls(log_dir=str(self.tb_dir), purge_step=self._purge_step)
            for key, value in values.items():
                self._writer.add_scalar(key, value, global_step=int(samples))
            self._writer.flush()  # a failure of its thread surfaces now, at this record
        except OSError as e:
            raise self._failure(e, self.tb_dir) from None
        return record

    def _failure(self, e: OSError, path: Path) -> OSError:
        """``e`` naming ``path`` (TensorBoard's thread names no file); later errors of the same cause are dropped."""
        self._failed = True
        take_thread_failure()  # the same error, taken here: the command is ending with it
        return OSError(e.errno, e.strerror or one_line(e), str(path))

    def truncate_after(self, iteration: int) -> int:
        """Drop lines logged after ``iteration`` (on resume from a checkpoint of that iteration).

        TensorBoard events past the last kept line are purged: the next writer opens with ``purge_step``.

        Returns:
            Number of lines dropped.
        """
        self._file.close()
        records = read_metrics(self.path)
        kept = [r for r in records if r["iteration"] <= iteration]
        with atomic_output(self.path) as tmp:
            tmp.write_text("".join(json.dumps(r, allow_nan=False) + "\n" for r in kept), encoding="utf-8")
        self._file = self.path.open("a", encoding="utf-8")
        self._purge_step = kept[-1]["samples"] + 1 if kept else 0
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        return len(records) - len(kept)

    def close(self) -> None:
        """Flush and close the files.

        Raises:
            OSError: Naming the file, if the last records cannot be written (none after a write that failed).
        """
        writer, self._writer = self._writer, None
        failures: list[tuple[OSError, Path]] = []
        for close, path in ((self._file.close, self.path), (writer.close if writer else None, self.tb_dir)):
            try:
                if close is not None:
                    close()
            except OSError as e:
                failures.append((e, path))
        failure = take_thread_failure()  # TensorBoard's thread, on its last records
        if failure is not None:
            failures.append((failure, self.tb_dir))
        if failures and not self._failed:
            raise self._failure(*failures[0])

    def abandon(self) -> None:
        """Closes the files after a failure that is on its way, raising nothing (that failure is the one to report)."""
        self._failed = True
        with contextlib.suppress(OSError):
            self.close()

    def __enter__(self) -> MetricsLogger:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _drop_partial_last_line(self) -> None:
        """Remove a last line cut off by a crash, so the next record does not get glued to it."""
        if not self.path.exists() or self.path.stat().st_size == 0:
            return
        data = self.path.read_bytes()
        if data.endswith(b"\n"):
            return
        with atomic_output(self.path) as tmp:
            tmp.write_bytes(data[: data.rfind(b"\n") + 1])


def read_metrics(path: str | Path) -> list[dict[str, Any]]:
    """Parse a ``metrics.jsonl`` file (a run directory is accepted too); a cut-off last line is skipped.

    Raises:
        ValueError: If a line other than the last is not valid JSON.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "metrics.jsonl"
    lines = [line for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    records = []
    for i, line in enumerate(lines):
        try:
            records.append(parse_json(line))
        except json.JSONDecodeError as e:
            if i == len(lines) - 1:
                log.warning("%s: skipping cut-off last line", path)
                break
            raise ValueError(f"{path}:{i + 1}: invalid JSON line: {e}") from e
    return records


class Timers:
    """Named cumulative wall-clock timers; do not nest them, or the shares count time twice.

    Args:
        clock: Monotonic clock in seconds.
    """

    def __init__(self, clock: Callable[[], float] = time.perf_counter) -> None:
        self._clock = clock
        self.totals: dict[str, float] = {}

    @contextlib.contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        """Time the ``with`` block under ``name``."""
        start = self._clock()
        try:
            yield
        finally:
            self.totals[name] = self.totals.get(name, 0.0) + self._clock() - start

    def shares(self) -> dict[str, float]:
        """Fraction of the timed total spent in each timer (empty if nothing was timed yet)."""
        total = sum(self.totals.values())
        if total <= 0.0:
            return {name: 0.0 for name in self.totals}
        return {name: t / total for name, t in self.totals.items()}

    def metrics(self, prefix: str = "perf/") -> dict[str, float]:
        """``{prefix + name + "_share": ..., prefix + name + "_s": ...}`` for :meth:`MetricsLogger.log`."""
        out = {f"{prefix}{name}_share": share for name, share in self.shares().items()}
        out.update({f"{prefix}{name}_s": t for name, t in self.totals.items()})
        return out

    def reset(self) -> None:
        """Forget all accumulated time."""
        self.totals.clear()


class Every:
    """Periodic trigger on the iteration count (stateless, so it behaves the same after a resume).

    Args:
        period: Fire when ``step`` is a positive multiple of ``period``; ``period <= 0`` never fires.
        at_start: Also fire at step 0 (e.g. evaluate the untrained policy).
    """

    def __init__(self, period: int, at_start: bool = False) -> None:
        self.period = int(period)
        self.at_start = at_start

    def should(self, step: int) -> bool:
        """Whether the periodic action is due at ``step``."""
        if self.period <= 0:
            return False
        if step == 0:
            return self.at_start
        return step % self.period == 0

    __call__ = should


class Progress:
    """Progress display over tqdm: iterations, samples/s and a postfix of chosen metrics, on stderr.

    When the stream is not a TTY (CI logs) tqdm's redraws would be noise, so a plain line is printed
    every ``plain_every`` iterations and at :meth:`close` instead.

    Args:
        total: Number of iterations of the run; None when the budget is not in iterations (wall-clock, samples).
        desc: Label in front of the bar.
        initial: Iterations already done (resume).
        initial_samples: Samples already collected (resume); excluded from the samples/s rate.
        keys: Metric keys shown in the postfix (the last value seen of each); None shows all passed.
        plain_every: Iterations between plain lines in non-TTY mode.
        stream: Output stream (default ``sys.stderr``).
        clock: Monotonic clock in seconds.
    """

    def __init__(
        self,
        total: int | None,
        desc: str,
        *,
        initial: int = 0,
        initial_samples: int = 0,
        keys: tuple[str, ...] | None = None,
        plain_every: int = 100,
        stream: TextIO | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.total, self.desc, self.keys = total, desc, keys
        self.iteration, self.samples = initial, initial_samples
        self._start_samples, self._clock = initial_samples, clock
        self._start = clock()
        self._stream = stream if stream is not None else sys.stderr
        self._plain = Every(plain_every)
        self._shown: dict[str, float] = {}
        isatty = getattr(self._stream, "isatty", None)
        self._bar = (
            tqdm.tqdm(total=total, desc=desc, initial=initial, file=self._stream, dynamic_ncols=True)
            if isatty is not None and isatty()
            else None
        )

    def update(self, n: int = 1, samples: int | None = None, metrics: Mapping[str, float] | None = None) -> None:
        """Advance by ``n`` iterations; ``samples`` is the new total sample count."""
        self.iteration += n
        if samples is not None:
            self.samples = samples
        for key, value in (metrics or {}).items():
            if self.keys is None or key in self.keys:
                self._shown[key] = float(value)
        if self._bar is not None:
            self._bar.set_postfix_str(self._postfix(), refresh=False)
            self._bar.update(n)
        elif self._plain.should(self.iteration):
            self._print_line()

    def samples_per_s(self) -> float:
        """Samples collected per second since this display started."""
        elapsed = self._clock() - self._start
        return (self.samples - self._start_samples) / elapsed if elapsed > 0 else 0.0

    def close(self) -> None:
        """Finish the bar (or print a last plain line)."""
        if self._bar is not None:
            self._bar.close()
        elif not self._plain.should(self.iteration):
            self._print_line()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _postfix(self) -> str:
        parts = [f"{self.samples_per_s():.0f} samples/s"]
        parts += [f"{key}={value:.4g}" for key, value in self._shown.items()]
        return ", ".join(parts)

    def _print_line(self) -> None:
        elapsed = self._clock() - self._start
        print(
            f"{self.desc}: {self.iteration}{'' if self.total is None else f'/{self.total}'} [{elapsed:.0f}s] "
            f"{self._postfix()}",
            file=self._stream,
            flush=True,
        )
