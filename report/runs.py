"""Reading training run directories for the comparison report.

A run directory (written by :mod:`common.train.training`) holds ``config.yaml``, ``run_info.json``, ``metrics.jsonl``
and ``checkpoints/``. This module reads them without importing any learner: the learner-specific policy loading lives in
``<learner>/export.py`` and is reached through the learner registry (:mod:`report.learners`, :func:`export_module`).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

from common.bundled_configs import resolve_run
from common.character.humanoid import PhysicsConfig
from common.config import ConfigError, from_dict, parse_yaml
from common.evaluation.evaluate import EvalConfig
from common.run.contained import check_run_directory, run_file
from common.run.logs import read_metrics
from common.strict_json import parse_json
from report.learners import LEARNERS, known, missing_extra


class ReportError(ValueError):
    """A run directory cannot be used in the report (not a run, unfinished, unreadable)."""


@dataclass
class Run:
    """One training run as the report sees it.

    Attributes:
        path: The run directory.
        label: Unique display name (the learner plus the directory name).
        learner: Learner name from run_info.json (``supertrack``, ``ppo``): also the package holding ``export.py``.
        config: The resolved config as a plain mapping.
        info: run_info.json.
        metrics: The metrics log, one dict per line.
        checkpoint: The checkpoint to evaluate.
        iteration: Iteration stored in that checkpoint.
        samples: Environment samples at that checkpoint.
        train_seconds: Training wall-clock at that checkpoint.
    """

    path: Path
    label: str
    learner: str
    config: dict[str, Any]
    info: dict[str, Any]
    metrics: list[dict[str, Any]]
    checkpoint: Path
    iteration: int
    samples: int
    train_seconds: float

    @property
    def seed(self) -> int | None:
        return self.info.get("seed", self.config.get("train", {}).get("seed"))

    @property
    def motions(self) -> list[str]:
        """Clip names the run trained on (run_info.json), else the motion specs of its config."""
        return list(self.info.get("motions") or self.config.get("train", {}).get("motions", []))

    def physics(self) -> PhysicsConfig:
        """The physics settings the run trained with."""
        return from_dict(PhysicsConfig, self.config.get("gym", {}).get("physics", {}), source=str(self.path))

    def eval_config(self) -> EvalConfig:
        """The evaluation protocol of the run's config."""
        return from_dict(EvalConfig, self.config.get("train", {}).get("eval", {}), source=str(self.path))

    def curve(self, key: str) -> tuple[list[int], list[float], list[float]]:
        """(samples, wall_clock_s, value) of every log line that holds ``key``."""
        rows = [m for m in self.metrics if key in m and m[key] is not None]
        return ([int(m["samples"]) for m in rows], [float(m["wall_clock_s"]) for m in rows],
                [float(m[key]) for m in rows])  # fmt: skip


def _checkpoint(path: Path, iteration: int | None) -> tuple[Path, dict[str, Any]]:
    """The checkpoint of ``iteration`` (None: the newest intact one) and its state, read without running anything."""
    # Imported here (they import torch): reading curves alone stays cheap.
    from common.run.checkpoint import CheckpointError, load_checkpoint_file, recorded_digest
    from common.run.directory import load_newest_checkpoint, newest_checkpoint, numbered_checkpoints

    numbered = dict(numbered_checkpoints(path / "checkpoints"))
    if iteration is None and newest_checkpoint(path / "checkpoints") is None:
        raise ReportError(f"{path}: unfinished run: no checkpoint in {path / 'checkpoints'}")
    if iteration is not None and iteration not in numbered:
        have = ", ".join(str(i) for i in sorted(numbered)) or "none"
        raise ReportError(f"{path}: no checkpoint of iteration {iteration} (numbered checkpoints: {have})")
    try:
        if iteration is None:
            found, state, _ = load_newest_checkpoint(path / "checkpoints")
            return found, state
        chosen = numbered[iteration]
        return chosen, load_checkpoint_file(chosen, sha256=recorded_digest(chosen))
    except CheckpointError as e:
        raise ReportError(str(e)) from None


def _read(file: Path, parse: Callable[[Path], Any]) -> Any:
    """``parse(file)``, or a ReportError naming the file (binary bytes, bad JSON or YAML, unreadable)."""
    try:
        return parse(file)
    except UnicodeDecodeError as e:
        raise ReportError(f"{file}: unreadable run file: not text (byte 0x{e.object[e.start]:02x} at offset "
                          f"{e.start} is not UTF-8)") from None  # fmt: skip
    except (OSError, ValueError, ConfigError) as e:
        raise ReportError(f"{file}: unreadable run file: {str(e).splitlines()[0]}") from None


def load_run(path: str | Path, iteration: int | None = None) -> Run:
    """Reads a run directory.

    Args:
        path: The run directory, or ``pretrained`` / ``pretrained:NAME`` for a policy bundled with the project.
        iteration: Checkpoint iteration to evaluate; None: the newest.

    Raises:
        ReportError: If ``path`` is not a run directory, has no (such) checkpoint, its files are unreadable, or it
            names a file outside itself (:mod:`common.run.contained`); a checkpoint whose pickle asks for anything
            but tensors, arrays and plain values is refused unopened.
    """
    path = resolve_run(path)
    if not path.is_dir():
        raise ReportError(f"{path}: not a directory")
    check_run_directory(path, ReportError)
    missing = [n for n in ("config.yaml", "run_info.json") if not (path / n).is_file()]
    if missing:
        raise ReportError(f"{path}: not a run directory (missing {', '.join(missing)})")
    config = _read(path / "config.yaml", lambda f: parse_yaml(f.read_text(encoding="utf-8")) or {})
    info = _read(path / "run_info.json", lambda f: parse_json(f.read_text(encoding="utf-8")))
    metrics = _read(path / "metrics.jsonl", read_metrics) if (path / "metrics.jsonl").is_file() else []
    if not isinstance(config, dict) or not isinstance(info, dict):
        raise ReportError(f"{path}: unreadable run files: config.yaml and run_info.json must each hold a mapping")
    learner = info.get("learner")
    if not learner:
        raise ReportError(f"{path}: run_info.json names no learner")
    if learner not in LEARNERS:
        raise ReportError(f"{path}: run_info.json names an unknown learner {learner!r} (known: {known()})")
    if info.get("policy_file"):
        # A run without training checkpoints (SAMCON): its learner's export module reads this one file.
        ckpt = run_file(path, str(info["policy_file"]), ReportError, "run_info.json's policy_file")
        if not ckpt.is_file():
            raise ReportError(f"{path}: unfinished run: no {info['policy_file']} (run_info.json names it)")
        return Run(path=path, label=f"{learner}:{path.name}", learner=learner, config=dict(config), info=info,
                   metrics=metrics, checkpoint=ckpt, iteration=0, samples=int(info.get("samples", 0)),
                   train_seconds=float(info.get("train_seconds", 0.0)))  # fmt: skip
    ckpt, state = _checkpoint(path, iteration)
    meta = state.get("meta")
    meta_learner = meta.get("learner") if isinstance(meta, dict) else None
    if meta_learner not in (None, learner):
        raise ReportError(f"{ckpt}: checkpoint is from learner {meta_learner!r}, run_info.json says {learner!r}")
    return Run(
        path=path, label=f"{learner}:{path.name}", learner=learner, config=dict(config), info=info, metrics=metrics,
        checkpoint=ckpt, iteration=int(state.get("iteration", 0)), samples=int(state.get("samples", 0)),
        train_seconds=float(state.get("train_seconds", 0.0)),
    )  # fmt: skip


def export_module(learner: str) -> ModuleType:
    """The registered export module of ``learner`` (the registry :data:`report.learners.LEARNERS`), which provides
    ``load_eval_policy``.

    Raises:
        ReportError: If the learner is not registered, or its optional dependencies are not installed (nothing is
            imported then).
    """
    if learner not in LEARNERS:
        raise ReportError(f"unknown learner {learner!r} (known: {known()})")
    missing = missing_extra(learner)
    if missing:
        raise ReportError(missing)
    module = importlib.import_module(LEARNERS[learner].export)
    if not hasattr(module, "load_eval_policy"):
        raise ReportError(f"{LEARNERS[learner].export} defines no load_eval_policy")
    return module


def unique_labels(runs: list[Run]) -> None:
    """Makes labels unique in place (two runs of the same directory name get a numeric suffix)."""
    seen: dict[str, int] = {}
    for run in runs:
        n = seen.get(run.label, 0)
        seen[run.label] = n + 1
        if n:
            run.label = f"{run.label}#{n + 1}"


# Config keys that do not make a different method: the seed, budgets, logging and threads of the machine it ran on.
_NOT_METHOD = {"train.seed", "gym.seed", "train.device", "train.motions", "train.torch_threads", "train.max_minutes",
               "train.max_samples", "train.max_iterations", "train.log_every", "train.eval_every_minutes",
               "train.checkpoint_every_minutes", "train.keep_checkpoints", "train.eval.threads", "gym.threads"}


def _flat(config: Any, prefix: str = "") -> dict[str, str]:
    if not isinstance(config, dict):
        return {prefix: repr(config)}
    out: dict[str, str] = {}
    for key, value in config.items():
        out.update(_flat(value, f"{prefix}.{key}" if prefix else str(key)))
    return out


def method_groups(runs: list[Run]) -> dict[str, list[int]]:
    """{method: indices of its runs}, in first-seen order: the runs that are seeds of one method.

    Runs are seeds of each other when they share the learner, the motion set and the config except the seed, the
    budgets, logging and thread counts (``_NOT_METHOD``). A learner with several groups names each by its motion set
    (``learner (clips)``) where those differ, and by the config values that tell its groups apart
    (``learner [key=value, ...]``) where the configs differ.
    """
    flats = [{k: v for k, v in _flat(run.config).items() if k not in _NOT_METHOD} for run in runs]
    keys: dict[tuple[str, tuple[str, ...], tuple[tuple[str, str], ...]], list[int]] = {}
    for i, run in enumerate(runs):
        keys.setdefault((run.learner, tuple(run.motions), tuple(sorted(flats[i].items()))), []).append(i)
    names: dict[str, list[int]] = {}
    for (learner, motions, config), idx in keys.items():
        same = [k for k in keys if k[0] == learner]
        name = learner
        if len({k[1] for k in same}) > 1:
            name += f" ({', '.join(motions)})"
        if len({k[2] for k in same if k[1] == motions}) > 1:
            mine = dict(config)
            others = [dict(k[2]) for k in same if k[1] == motions and k[2] != config]
            differ = sorted(key for key in mine if any(o.get(key) != mine[key] for o in others))
            differ += sorted({key for o in others for key in o if key not in mine})
            shown = [f"{key}={mine.get(key, '-')}" for key in differ[:3]] + (["..."] if len(differ) > 3 else [])
            name += f" [{', '.join(shown)}]"
        names.setdefault(name, []).extend(idx)
    return names
