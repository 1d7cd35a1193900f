"""Run-directory tools shared by ``train-supertrack`` and ``train-ppo``.

Layout of a run directory::

    config.yaml               resolved config (common.config.save_config)
    run_info.json             machine, versions, command line, seed, start time (+ one entry per resume)
    metrics.jsonl             one JSON object per logged iteration (common.logs.MetricsLogger)
    tb/                       TensorBoard events (only if the ``tensorboard`` package is installed)
    checkpoints/ckpt_<iteration:08d>.pt   newest K numbered checkpoints
    checkpoints/latest.pt     hard link to (or copy of) the newest numbered checkpoint

Every file that a crash could leave half-written is written to a temporary file in the same folder and
moved into place with ``os.replace``, so a reader only ever sees a complete old or a complete new file.
Metrics logging, timers and the progress display live in :mod:`common.logs`.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import platform
import random
import re
import shlex
import shutil
import sys
from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import torch

from common.config import atomic_output, load_config, save_config

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
    """The newest numbered checkpoint in ``checkpoint_dir``, else its ``latest.pt``, else None.

    Numbered files come first because a crash between writing one and relinking ``latest.pt`` leaves ``latest.pt``
    one checkpoint behind.
    """
    numbered = numbered_checkpoints(checkpoint_dir)
    if numbered:
        return numbered[-1][1]
    latest = checkpoint_dir / "latest.pt"
    return latest if latest.is_file() else None


def checkpoint_file(path: str | Path) -> Path:
    """A checkpoint file given as itself or as the run directory holding it (then its newest checkpoint).

    Raises:
        RunDirError: Naming ``path`` if it is neither a file nor a run directory with a checkpoint.
    """
    path = Path(path)
    if path.is_file():
        return path
    if not path.is_dir():
        raise RunDirError(f"{path}: no such checkpoint file or run directory")
    found = newest_checkpoint(path / "checkpoints")
    if found is None:
        raise RunDirError(f"{path}: no checkpoint in {path / 'checkpoints'}")
    return found


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
        return numbered_checkpoints(self.checkpoint_dir)

    def latest_checkpoint_path(self) -> Path | None:
        """The newest numbered checkpoint, else ``latest.pt``, else None (see :func:`newest_checkpoint`)."""
        return newest_checkpoint(self.checkpoint_dir)

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
        ValueError: Naming the checkpoint and the missing entry if the file is not this learner's checkpoint.
    """
    cfg = load_config(config_cls, Path(run_dir) / "config.yaml")
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    learner = state.get("learner") if isinstance(state, Mapping) else None
    if not isinstance(learner, Mapping):
        raise ValueError(f"{checkpoint}: no learner state in this file (not a checkpoint of a training run)")
    missing = [k for k in keys if k not in learner]
    if missing:
        raise ValueError(f"{checkpoint}: the learner state has no {', '.join(missing)}; "
                         f"it is not a checkpoint of {config_cls.__name__}'s learner")  # fmt: skip
    return cfg, dict(learner)


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
