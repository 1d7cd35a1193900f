"""Run-directory tools shared by ``train-supertrack`` and ``train-ppo``.

Layout of a run directory::

    config.yaml               resolved config (common.config.save_config)
    run_info.json             machine, versions, command line, seed, start time (+ one entry per resume)
    metrics.jsonl             one JSON object per logged iteration (common.run.logs.MetricsLogger)
    tb/                       TensorBoard events (only if the ``tensorboard`` package is installed)
    checkpoints/ckpt_<iteration:08d>.pt   newest K numbered checkpoints (tensors, arrays, plain values only)
    checkpoints/latest.json   names the newest numbered checkpoint; size and SHA-256 of each kept one

Every file that a crash could leave half-written is written to a temporary file in the same folder and
moved into place with ``os.replace``, so a reader only ever sees a complete old or a complete new file.
Checkpoints are read without running anything they hold, and ``--resume`` passes over a damaged newest
checkpoint to the newest intact one (:mod:`common.run.checkpoint`).
Metrics logging, timers and the progress display live in :mod:`common.run.logs`.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import platform
import random
import re
import sys
from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import torch

from common.cli import output_dir_problem
from common.config import atomic_output, load_config, save_config
from common.run.checkpoint import (
    LEGACY_LATEST_NAME,
    POINTER_NAME,
    CheckpointError,
    candidates,
    load_checkpoint_file,
    load_newest_intact,
    read_pointer,
    recorded_digest,
    save_checkpoint_file,
    set_aside,
    write_pointer,
)
from common.run.command_line import portable_command
from common.run.contained import check_run_directory
from common.run.lock import DirectoryLock
from common.strict_json import parse_json

log = logging.getLogger(__name__)

_CKPT_RE = re.compile(r"^ckpt_(\d{8,})\.pt$")


class RunDirError(RuntimeError):
    """A run directory cannot be used as asked (existing run without --resume, nothing to resume)."""


def numbered_checkpoints(checkpoint_dir: Path) -> list[tuple[int, Path]]:
    """(iteration, path) of the ``ckpt_<iteration>.pt`` files in ``checkpoint_dir``, oldest first."""
    if not checkpoint_dir.is_dir():
        return []
    return sorted((int(m.group(1)), p) for p in checkpoint_dir.iterdir() if (m := _CKPT_RE.match(p.name)))


def newest_checkpoint(checkpoint_dir: Path) -> Path | None:
    """The newest numbered checkpoint in ``checkpoint_dir``, else a legacy ``latest.pt``, else None (unread).

    Numbered files come first, not the one ``latest.json`` names, because a crash between writing a checkpoint and
    its pointer leaves the pointer one checkpoint behind.
    """
    return next(candidates(checkpoint_dir, numbered_checkpoints(checkpoint_dir)), None)


def load_newest_checkpoint(checkpoint_dir: Path, map_location: str | torch.device | None = "cpu",
                           required: tuple[str, ...] = ()) -> tuple[Path, dict[str, Any], list[Path]]:  # fmt: skip
    """The newest intact checkpoint of ``checkpoint_dir`` (holding the entries ``required``), its state and the newer
    ones passed over; one warning line on stderr for each of those (file and problem).

    Raises:
        CheckpointError: If none reads.
    """
    def warn(message: str) -> None:
        print(f"warning: {message}; passed over", file=sys.stderr)

    return load_newest_intact(checkpoint_dir, numbered_checkpoints(checkpoint_dir), warn, map_location, required)


def read_checkpoint(path: str | Path) -> tuple[Path, dict[str, Any]]:
    """A checkpoint given as a file, or as the run directory holding it (then its newest intact checkpoint).

    Returns:
        ``(file, state)``, the state on the CPU.

    Raises:
        CheckpointError: Naming the file and the problem (no such file or run, damaged, refused, a run holding a
            link that leads outside it).
    """
    path = Path(path)
    if path.is_file():
        return path, load_checkpoint_file(path, sha256=recorded_digest(path))
    if not path.is_dir():
        raise CheckpointError(f"{path}: no such checkpoint file or run directory")
    if not (path / "checkpoints").is_dir():
        raise CheckpointError(f"{path}: not a run directory (no checkpoints/)")
    check_run_directory(path, CheckpointError)
    found, state, _ = load_newest_checkpoint(path / "checkpoints")
    return found, state


class RunDir:
    """A run's output directory: config, run info, metrics and checkpoints.

    Args:
        path: Directory; created with its parents if needed (by :meth:`create`).
        resume: Continue the run stored in ``path``; requires at least one checkpoint.
        keep_checkpoints: Number of newest numbered checkpoints kept.
        create: Create the directory now; False only checks that it can be (a command creates it with
            :meth:`create` once everything else has been validated, so that a refused start leaves nothing behind).

    Raises:
        RunDirError: If ``path`` already holds a run and ``resume`` is False, ``resume`` is True and there is no
            checkpoint to resume from, ``path`` cannot be a directory of this user's (an existing file, inside a
            file, not writable), or it holds a link leading outside it (:mod:`common.run.contained`).
        ValueError: If ``keep_checkpoints < 1``.
    """

    def __init__(self, path: str | Path, resume: bool, keep_checkpoints: int = 3, create: bool = True) -> None:
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
        self.pointer_path = self.checkpoint_dir / POINTER_NAME
        self.start_time = datetime.now(timezone.utc)
        self._resume_info: dict[str, Any] | None = None
        self._lock = DirectoryLock(self.path, RunDirError, "run directory")
        problem = output_dir_problem(self.path)
        if problem is not None:
            raise RunDirError(f"run directory {self.path}: {problem}")
        check_run_directory(self.path, RunDirError)  # nothing it reads or writes may lie elsewhere
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
        if create:
            self.create()

    def create(self) -> None:
        """Creates the directory and its ``checkpoints/`` (nothing if they exist).

        Raises:
            RunDirError: Naming the directory if it cannot be created (read-only, no space).
        """
        try:
            self.checkpoint_dir.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise RunDirError(f"run directory {self.path}: cannot create it: {e.strerror or e}") from None

    def lock(self) -> None:
        """Makes the directory (not yet its ``checkpoints/``) and takes its lock until :meth:`unlock` or the process
        ends (:mod:`common.run.lock`). A new run then looks again whether the directory holds a run: another command
        may have started and finished one there since this one looked.

        Raises:
            RunDirError: If another process writes the directory (naming its id), a new run finds a run there now, or
                the directory or its lock file cannot be made.
        """
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            self._lock.acquire()
        except OSError as e:
            raise RunDirError(f"run directory {self.path}: cannot lock it: {e.strerror or e}") from None
        if not self.resume and (self.config_path.exists() or self.checkpoint_dir.exists()):
            self.unlock()
            raise RunDirError(f"run directory {self.path} already holds a run (another command wrote it meanwhile); "
                              "pass --resume to continue it or choose another --out")  # fmt: skip

    def unlock(self) -> None:
        """Drops the lock taken by :meth:`lock` (nothing if none is held)."""
        self._lock.release()

    def save_config(self, cfg: Any) -> None:
        """Write the resolved config dataclass to ``config.yaml`` (atomically)."""
        save_config(cfg, self.config_path)

    def write_run_info(self, extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """Record machine, versions, command line and start time (plus ``extra``, e.g. the seed).

        On resume the original record is kept and this one is appended to its ``resumes`` list (by
        :meth:`confirm_resume`, once the checkpoint is restored), so the file tells on which machines each part of
        the run was trained.

        Args:
            extra: JSON-serialisable additions, e.g. ``{"seed": 3, "learner": "ppo"}``.

        Returns:
            The record written for this start.
        """
        info = {**machine_info(), "command": portable_command(sys.argv), "start_time": self.start_time.isoformat()}
        info.update(extra or {})
        if self.resume:
            self._resume_info = info  # written by confirm_resume: a resume that fails changes nothing
        else:
            self._write_run_info(info)
        return info

    def _write_run_info(self, info: dict[str, Any]) -> None:
        record: dict[str, Any] = info
        if self.resume and self.run_info_path.exists():
            try:
                record = parse_json(self.run_info_path.read_text(encoding="utf-8"))
                record.setdefault("resumes", []).append(info)
            except (OSError, ValueError, AttributeError) as e:  # kept as it is: it is the only record of the start
                print(f"warning: {self.run_info_path}: unreadable ({e}); this resume is not recorded in it",
                      file=sys.stderr)  # fmt: skip
                return
        with atomic_output(self.run_info_path) as tmp:
            tmp.write_text(json.dumps(record, indent=2, default=str) + "\n", encoding="utf-8")

    def confirm_resume(self, passed_over: list[Path]) -> None:
        """Once a resume has restored its checkpoint: append this start to run_info.json, and keep the checkpoints
        passed over as ``<name>.damaged``, so that the continued run neither overwrites nor prunes them and no later
        resume tries them again."""
        if self._resume_info is not None:
            self._write_run_info(self._resume_info)
            self._resume_info = None
        for path in passed_over:
            print(f"warning: {path} kept as {set_aside(path).name}", file=sys.stderr)

    def checkpoint_path(self, iteration: int) -> Path:
        """Path of the numbered checkpoint of ``iteration``."""
        return self.checkpoint_dir / f"ckpt_{iteration:08d}.pt"

    def numbered_checkpoints(self) -> list[tuple[int, Path]]:
        """(iteration, path) of the numbered checkpoints, oldest first."""
        return numbered_checkpoints(self.checkpoint_dir)

    def latest_checkpoint_path(self) -> Path | None:
        """The newest checkpoint file, unread (see :func:`newest_checkpoint`); None if there is none."""
        return newest_checkpoint(self.checkpoint_dir)

    def save_checkpoint(self, state: Mapping[str, Any], iteration: int) -> Path:
        """Save ``state`` as checkpoint ``iteration``, point ``latest.json`` at it and prune old checkpoints.

        ``state`` gets an ``iteration`` entry if it has none. It should hold a ``meta`` dict (config
        fingerprint) for :func:`check_compatible`. A write that fails part-way (a full disk) raises and leaves
        every earlier checkpoint and ``latest.json`` as they were.

        Args:
            state: Tensors, numpy arrays and plain values (model/optimizer state dicts, RNG state, counters, ``meta``).
            iteration: Training iteration the state belongs to.

        Returns:
            Path of the numbered checkpoint.

        Raises:
            ValueError: If ``state["iteration"]`` exists and differs from ``iteration``.
            TypeError: If ``state`` holds another kind of object (see :func:`common.run.checkpoint.check_plain`).
            OSError: If the checkpoint cannot be written.
        """
        saved = dict(state)
        if saved.setdefault("iteration", iteration) != iteration:
            raise ValueError(f"state['iteration'] = {saved['iteration']} but saving as iteration {iteration}")
        path = self.checkpoint_path(iteration)
        record = save_checkpoint_file(saved, path)
        try:
            records = read_pointer(self.checkpoint_dir).get("checkpoints", {})
        except CheckpointError:
            records = {}  # rewritten whole below; the checkpoints do not depend on it
        kept = [p.name for _, p in self.numbered_checkpoints()[-self.keep_checkpoints :]]
        records = {name: records[name] for name in kept if name in records and name != path.name}
        write_pointer(self.checkpoint_dir, path.name, {**records, path.name: record})
        for _, old in self.numbered_checkpoints()[: -self.keep_checkpoints]:
            old.unlink(missing_ok=True)
        # The hard link of earlier versions, now a stale copy of an older state: the new checkpoint supersedes it.
        (self.checkpoint_dir / LEGACY_LATEST_NAME).unlink(missing_ok=True)
        return path

    def load_latest_checkpoint(self, map_location: str | torch.device | None = "cpu",
                               required: tuple[str, ...] = ()) -> tuple[Path, dict[str, Any], list[Path]]:  # fmt: skip
        """The newest intact checkpoint, its state and the newer ones passed over (:func:`load_newest_checkpoint`).

        Raises:
            CheckpointError: If no checkpoint reads.
        """
        return load_newest_checkpoint(self.checkpoint_dir, map_location, required)


def load_run_checkpoint(config_cls: type, run_dir: str | Path, checkpoint: str | Path,
                        *keys: str) -> tuple[Any, dict[str, Any]]:  # fmt: skip
    """A run's config and the learner entries ``keys`` of one of its checkpoints (CPU tensors), for export.

    Args:
        config_cls: The learner's config dataclass (the run's ``config.yaml`` is loaded into it).
        run_dir: The run directory.
        checkpoint: A checkpoint written by that run's trainer.
        *keys: Entries of the checkpoint's ``learner`` state that the caller needs.

    Returns:
        ``(config, learner_state)``.

    Raises:
        ValueError: Naming the checkpoint and the missing entry if the file is not this learner's checkpoint
            (:class:`CheckpointError` if it does not read).
    """
    cfg = load_config(config_cls, Path(run_dir) / "config.yaml", within=run_dir)
    state = load_checkpoint_file(checkpoint, sha256=recorded_digest(Path(checkpoint)))
    learner = state.get("learner")
    if not isinstance(learner, Mapping):
        raise ValueError(f"{checkpoint}: no learner state in this file (not a checkpoint of a training run)")
    missing = [k for k in keys if k not in learner]
    if missing:
        raise ValueError(f"{checkpoint}: the learner state has no {', '.join(missing)}; "
                         f"it is not a checkpoint of {config_cls.__name__}'s learner")  # fmt: skip
    return cfg, dict(learner)


def check_compatible(saved_meta: Mapping[str, Any], current_meta: Mapping[str, Any], path: str | Path,
                     defaults: Mapping[str, Any] | None = None) -> None:  # fmt: skip
    """Refuse to resume a checkpoint whose ``meta`` differs from the current run's.

    Nested mappings are compared key by key (dotted keys); tuples and lists compare equal. A key the checkpoint lacks
    is accepted when the current run holds it at its value in ``defaults``: an option added to the code since the
    checkpoint was written, left at its default, changes nothing the checkpoint's run did.

    Args:
        saved_meta: ``meta`` stored in the checkpoint.
        current_meta: ``meta`` the current run would store.
        path: Checkpoint path, for the message.
        defaults: ``meta`` of the learner's default config (None: every missing key is a difference).

    Raises:
        ValueError: Listing every differing key with its saved and current value.
    """
    if saved_meta.get("learner") != current_meta.get("learner"):  # one line, not every config key that differs
        raise ValueError(f"checkpoint {path} is a checkpoint of learner {saved_meta.get('learner')!r}, this run's "
                         f"learner is {current_meta.get('learner')!r}")  # fmt: skip
    saved, current = _flatten(saved_meta), _flatten(current_meta)
    missing = "<missing>"
    added_at_default = {k for k, v in _flatten(defaults or {}).items()
                        if k not in saved and current.get(k, missing) == v}  # fmt: skip
    lines = [
        f"  {key}: saved {saved.get(key, missing)!r}, current {current.get(key, missing)!r}"
        for key in sorted((saved.keys() | current.keys()) - added_at_default)
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
