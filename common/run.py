"""Run-directory tools shared by ``train-supertrack`` and ``train-ppo``.

Layout of a run directory::

    config.yaml               resolved config (common.config.save_config)
    run_info.json             machine, versions, command line, seed, start time (+ one entry per resume)
    metrics.jsonl             one JSON object per logged iteration
    tb/                       TensorBoard events (only if the ``tensorboard`` package is installed)
    checkpoints/ckpt_<iteration:08d>.pt   newest K numbered checkpoints
    checkpoints/latest.pt     hard link to (or copy of) the newest numbered checkpoint

Every file that a crash could leave half-written is written to a temporary file in the same folder and
moved into place with ``os.replace``, so a reader only ever sees a complete old or a complete new file.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import platform
import random
import re
import shlex
import shutil
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import torch
import tqdm

from common.config import atomic_output, save_config

log = logging.getLogger(__name__)

_CKPT_RE = re.compile(r"^ckpt_(\d{8,})\.pt$")
_RESERVED_METRIC_KEYS = ("iteration", "samples", "wall_clock_s")
_tb_warned = False


class RunDirError(RuntimeError):
    """A run directory cannot be used as asked (existing run without --resume, nothing to resume)."""


class RunDir:
    """A run's output directory: config, run info, metrics and checkpoints.

    Args:
        path: Directory; created with its parents if needed.
        resume: Continue the run stored in ``path``; requires at least one checkpoint.
        keep_checkpoints: Number of newest numbered checkpoints kept (``latest.pt`` is always kept).

    Raises:
        RunDirError: If ``path`` already holds a run and ``resume`` is False, or ``resume`` is True and
            there is no checkpoint to resume from.
        ValueError: If ``keep_checkpoints < 1``.
    """

    def __init__(self, path: str | Path, resume: bool, keep_checkpoints: int = 3) -> None:
        if keep_checkpoints < 1:
            raise ValueError(f"keep_checkpoints must be >= 1, got {keep_checkpoints}")
        self.path = Path(path)
        self.resume = resume
        self.keep_checkpoints = keep_checkpoints
        self.config_path = self.path / "config.yaml"
        self.metrics_path = self.path / "metrics.jsonl"
        self.tb_dir = self.path / "tb"
        self.run_info_path = self.path / "run_info.json"
        self.checkpoint_dir = self.path / "checkpoints"
        self.latest_path = self.checkpoint_dir / "latest.pt"
        self.start_time = datetime.now(timezone.utc)
        if self.path.exists() and not self.path.is_dir():
            raise RunDirError(f"run directory {self.path} exists and is not a directory")
        holds_run = self.config_path.exists() or self.checkpoint_dir.exists()
        if holds_run and not resume:
            raise RunDirError(
                f"run directory {self.path} already holds a run; pass --resume to continue it or choose another --out"
            )
        if resume and self.latest_checkpoint_path() is None:
            raise RunDirError(
                f"cannot resume: run directory {self.path} has no checkpoint in {self.checkpoint_dir}; "
                "start without --resume in another --out (or delete the directory)"
            )
        self.checkpoint_dir.mkdir(parents=True, exist_ok=True)

    def save_config(self, cfg: Any) -> None:
        """Write the resolved config dataclass to ``config.yaml`` (atomically)."""
        save_config(cfg, self.config_path)

    def write_run_info(self, extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """Record machine, versions, command line and start time (plus ``extra``, e.g. the seed).

        On resume the original record is kept and this one is appended to its ``resumes`` list, so the
        file tells on which machines each part of the run was trained.

        Args:
            extra: JSON-serialisable additions, e.g. ``{"seed": 3, "learner": "ppo"}``.

        Returns:
            The record written for this start.
        """
        info = {**machine_info(), "command": shlex.join(sys.argv), "start_time": self.start_time.isoformat()}
        info.update(extra or {})
        record: dict[str, Any] = info
        if self.resume and self.run_info_path.exists():
            record = json.loads(self.run_info_path.read_text(encoding="utf-8"))
            record.setdefault("resumes", []).append(info)
        with atomic_output(self.run_info_path) as tmp:
            tmp.write_text(json.dumps(record, indent=2, default=str) + "\n", encoding="utf-8")
        return info

    def checkpoint_path(self, iteration: int) -> Path:
        """Path of the numbered checkpoint of ``iteration``."""
        return self.checkpoint_dir / f"ckpt_{iteration:08d}.pt"

    def numbered_checkpoints(self) -> list[tuple[int, Path]]:
        """(iteration, path) of the numbered checkpoints, oldest first."""
        if not self.checkpoint_dir.is_dir():
            return []
        found = [(int(m.group(1)), p) for p in self.checkpoint_dir.iterdir() if (m := _CKPT_RE.match(p.name))]
        return sorted(found)

    def latest_checkpoint_path(self) -> Path | None:
        """The newest numbered checkpoint, else ``latest.pt``, else None.

        Numbered files come first because a crash between writing one and relinking ``latest.pt`` leaves
        ``latest.pt`` one checkpoint behind.
        """
        numbered = self.numbered_checkpoints()
        if numbered:
            return numbered[-1][1]
        return self.latest_path if self.latest_path.is_file() else None

    def save_checkpoint(self, state: Mapping[str, Any], iteration: int) -> Path:
        """Save ``state`` as checkpoint ``iteration``, update ``latest.pt`` and prune old checkpoints.

        ``state`` gets an ``iteration`` entry if it has none. It should hold a ``meta`` dict (config
        fingerprint) for :func:`check_compatible`.

        Args:
            state: Picklable mapping (model/optimizer state dicts, RNG state, counters, ``meta``).
            iteration: Training iteration the state belongs to.

        Returns:
            Path of the numbered checkpoint.

        Raises:
            ValueError: If ``state["iteration"]`` exists and differs from ``iteration``.
        """
        saved = dict(state)
        if saved.setdefault("iteration", iteration) != iteration:
            raise ValueError(f"state['iteration'] = {saved['iteration']} but saving as iteration {iteration}")
        path = self.checkpoint_path(iteration)
        with atomic_output(path) as tmp:
            torch.save(saved, tmp)
        with atomic_output(self.latest_path) as tmp:
            tmp.unlink()
            try:
                # A hard link costs no space and, unlike a symlink, survives pruning of its target.
                os.link(path, tmp)
            except OSError:
                shutil.copyfile(path, tmp)
        for _, old in self.numbered_checkpoints()[: -self.keep_checkpoints]:
            old.unlink(missing_ok=True)
        return path

    def load_latest_checkpoint(self, map_location: str | torch.device | None = "cpu") -> dict[str, Any]:
        """Load the newest checkpoint.

        Args:
            map_location: Passed to ``torch.load``.

        Returns:
            The saved state dict.

        Raises:
            RunDirError: If there is no checkpoint.
        """
        path = self.latest_checkpoint_path()
        if path is None:
            raise RunDirError(f"no checkpoint in {self.checkpoint_dir}")
        # Our own file, and it holds numpy RNG state and learner objects that weights_only=True refuses.
        return torch.load(path, map_location=map_location, weights_only=False)


def check_compatible(saved_meta: Mapping[str, Any], current_meta: Mapping[str, Any], path: str | Path) -> None:
    """Refuse to resume a checkpoint whose ``meta`` differs from the current run's.

    Nested mappings are compared key by key (dotted keys); tuples and lists compare equal.

    Args:
        saved_meta: ``meta`` stored in the checkpoint.
        current_meta: ``meta`` the current run would store.
        path: Checkpoint path, for the message.

    Raises:
        ValueError: Listing every differing key with its saved and current value.
    """
    saved, current = _flatten(saved_meta), _flatten(current_meta)
    missing = "<missing>"
    lines = [
        f"  {key}: saved {saved.get(key, missing)!r}, current {current.get(key, missing)!r}"
        for key in sorted(saved.keys() | current.keys())
        if saved.get(key, missing) != current.get(key, missing)
    ]
    if lines:
        raise ValueError(
            f"checkpoint {path} is incompatible with the current run ({len(lines)} differences):\n" + "\n".join(lines)
        )


def _flatten(meta: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested mapping -> {dotted key: leaf}, with tuples as lists so YAML/torch round trips compare equal."""
    flat: dict[str, Any] = {}
    for key, value in meta.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(_flatten(value, f"{name}."))
        else:
            flat[name] = list(value) if isinstance(value, tuple) else value
    return flat


def rng_state(np_rng: np.random.Generator) -> dict[str, Any]:
    """Capture python ``random``, the numpy Generator and torch (CPU and, if available, CUDA) RNG states."""
    state: dict[str, Any] = {
        "python": random.getstate(),
        "numpy": np_rng.bit_generator.state,
        "torch": torch.get_rng_state(),
    }
    if torch.cuda.is_available():
        state["torch_cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: Mapping[str, Any], np_rng: np.random.Generator) -> None:
    """Restore the states captured by :func:`rng_state` (``np_rng`` is updated in place)."""
    random.setstate(state["python"])
    np_rng.bit_generator.state = state["numpy"]
    # set_rng_state needs a CPU ByteTensor even if the checkpoint was loaded with map_location="cuda".
    torch.set_rng_state(state["torch"].cpu())
    cuda_states = state.get("torch_cuda")
    if cuda_states is not None and torch.cuda.is_available():
        if len(cuda_states) != torch.cuda.device_count():
            log.warning(
                "CUDA RNG not restored: checkpoint has %d device states, %d visible",
                len(cuda_states),
                torch.cuda.device_count(),
            )
        else:
            torch.cuda.set_rng_state_all([s.cpu() for s in cuda_states])


def machine_info() -> dict[str, Any]:
    """CPU model, torch threads, GPU name and library versions of this process."""
    info: dict[str, Any] = {
        "hostname": platform.node(),
        "platform": platform.platform(),
        "cpu": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": np.__version__,
    }
    try:
        import mujoco

        info["mujoco"] = mujoco.__version__
    except ImportError:
        info["mujoco"] = None
    return info


def _cpu_model() -> str:
    """CPU model name from /proc/cpuinfo (Linux), else what ``platform`` knows."""
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace").splitlines():
            key, _, value = line.partition(":")
            if key.strip() in ("model name", "Model", "Hardware"):
                return value.strip()
    return platform.processor() or platform.machine()


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
        self._file.write(json.dumps(record, allow_nan=False) + "\n")
        self._file.flush()
        if self._writer is None and self._writer_cls is not None:
            self._writer = self._writer_cls(log_dir=str(self.tb_dir), purge_step=self._purge_step)
        if self._writer is not None:
            for key, value in values.items():
                self._writer.add_scalar(key, value, global_step=int(samples))
        return record

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
        """Flush and close the files."""
        self._file.close()
        if self._writer is not None:
            self._writer.close()
            self._writer = None

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
            records.append(json.loads(line))
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
        total: Number of iterations of the run.
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
        total: int,
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
            f"{self.desc}: {self.iteration}/{self.total} [{elapsed:.0f}s] {self._postfix()}",
            file=self._stream,
            flush=True,
        )
