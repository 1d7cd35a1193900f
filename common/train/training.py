"""The training loop shared by ``train-supertrack`` and ``train-ppo``.

A learner implements :class:`Learner` (collect frames from the gym into its buffer, one update, a deterministic
policy, state dicts); :class:`Trainer` drives it: wall-clock/sample/iteration budgets, periodic evaluation with the
shared evaluator, JSON-lines + TensorBoard metrics, atomic checkpoints and exact ``--resume``. The command line and
the start of a run (validation, the run directory) are in :mod:`common.train.startup`.

Log keys (shared by both learners so that the report reads either run): ``eval/...`` (the evaluator's metrics),
``losses/...``, ``reward/...``, ``world_model/...``, ``perf/...`` (samples/s, time shares), ``charts/...``.
"""

from __future__ import annotations

import copy
import math
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch

from common.character.humanoid import Humanoid
from common.cli import (
    EXIT_RUN_FAILED,
    CommandError,
    one_line,
)
from common.config import to_dict
from common.evaluation.evaluate import EvalConfig, EvalResult, Policy, evaluate
from common.motion.library import MotionLibrary
from common.run.checkpoint import load_checkpoint_file, recorded_digest
from common.run.directory import RunDir, check_compatible, rng_state, set_rng_state
from common.run.logs import MetricsLogger, Progress, Timers
from common.sim.gym import GymConfig
from common.train.distributed import World

# The entries of a training checkpoint (Trainer._state): one without them is not a checkpoint to resume.
_STATE_KEYS = ("meta", "iteration", "samples", "train_seconds", "learner", "rng")


@dataclass(frozen=True)
class TrainConfig:
    """The run section common to both learners.

    Attributes:
        motions: Motion specs (bundled clip names, ``all``, files, folders, a dataset ``.h5``).
        seed: Seed of python, numpy and torch RNGs; the gym's seed is this plus ``gym.seed`` (see :func:`gym_config`).
        device: ``cpu`` or ``cuda`` (``cuda:1``, ...) for the networks; the physics always runs on the CPU.
        torch_threads: CPU threads torch may use (the physics uses the gym's own threads). 1 by default: with 2,
            torch's spinning threads made updates 3-10x slower whenever the other core was busy (measured here).
        max_minutes: Stop after this much training wall-clock time (evaluation and torch.compile warm-up excluded);
            None: no limit.
        max_samples: Stop after this many environment samples (character steps); None: no limit.
        max_iterations: Stop after this many iterations; None: no limit.
        log_every: Iterations between metric lines.
        eval_every_minutes: Training minutes between evaluations (None: use eval_every_iterations).
        eval_every_iterations: Iterations between evaluations (used when eval_every_minutes is None).
        checkpoint_every_minutes: Training minutes between checkpoints (a final one is always written).
        keep_checkpoints: Numbered checkpoints kept.
        eval: The evaluation protocol.
    """

    motions: tuple[str, ...] = ("walk",)
    seed: int = 0
    device: str = "cpu"
    torch_threads: int = 1
    max_minutes: float | None = 60.0
    max_samples: int | None = None
    max_iterations: int | None = None
    log_every: int = 10
    eval_every_minutes: float | None = 5.0
    eval_every_iterations: int = 1000
    checkpoint_every_minutes: float = 10.0
    keep_checkpoints: int = 3
    eval: EvalConfig = field(default_factory=EvalConfig)

    def __post_init__(self) -> None:
        if not self.motions:
            raise ValueError("motions must name at least one clip")
        if self.max_minutes is None and self.max_samples is None and self.max_iterations is None:
            raise ValueError("set at least one of max_minutes, max_samples, max_iterations")
        if not 0 <= self.seed < 2**32:
            raise ValueError(f"seed must be an integer from 0 to 2**32 - 1, got {self.seed}")
        check_device(self.device)
        at_least = {"torch_threads": 1, "log_every": 1, "eval_every_iterations": 1, "keep_checkpoints": 1,
                    "max_samples": 0, "max_iterations": 0}  # fmt: skip
        for key, low in at_least.items():
            value = getattr(self, key)
            if value is not None and value < low:
                raise ValueError(f"{key} must be >= {low}, got {value}")
        for key in ("max_minutes", "eval_every_minutes", "checkpoint_every_minutes"):
            value = getattr(self, key)
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{key} must be a finite number of minutes >= 0, got {value}")


def check_device(device: str) -> None:
    """Refuses a string that names no torch device (``cpu``, ``cuda``, ``cuda:1``, ``mps``, ...).

    Raises:
        ValueError: Naming the device and the kinds torch knows.
    """
    try:
        torch.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(f"device {device!r} is not a torch device (cpu, cuda, cuda:1, mps, ...)") from None


class Learner(Protocol):
    """What :class:`Trainer` needs from a learning method."""

    def collect(self) -> int:
        """Steps the gym and stores the frames; returns the number of environment samples added."""

    def update(self) -> dict[str, float]:
        """One training iteration on stored data; returns metrics (``losses/...`` etc.)."""

    def policy(self) -> Policy:
        """The current deterministic policy (no exploration noise), as a callable for the evaluator."""

    def diagnostics(self) -> dict[str, float]:
        """Extra periodic measurements logged with each evaluation (e.g. ``world_model/...``); may be empty."""

    def state_dict(self) -> dict[str, Any]:
        """Networks, optimisers, normalisers, gym and buffer state: all needed to continue exactly."""

    def load_state_dict(self, state: dict[str, Any]) -> None: ...

    # Optional: ``warm_up() -> None``, work to do before the training clock starts (e.g. ``torch.compile``); the
    # Trainer calls it when the learner has it and logs its duration as ``perf/compile_s``.


def gym_config(cfg: Any) -> GymConfig:
    """The gym section of a learner's config with its seed offset by ``train.seed`` (one seed drives a run)."""
    return replace(cfg.gym, seed=cfg.train.seed + cfg.gym.seed)


def compat_meta(cfg: Any, humanoid: Humanoid, learner: str) -> dict[str, Any]:
    """What must match to resume: the learner, the character and the config except run-length settings."""
    plain = to_dict(cfg)
    for key in ("max_minutes", "max_samples", "max_iterations", "device", "log_every", "eval_every_minutes",
                "eval_every_iterations", "checkpoint_every_minutes", "keep_checkpoints", "torch_threads"):  # fmt: skip
        plain["train"].pop(key, None)
    return {"learner": learner, "bodies": list(humanoid.body_names), "config": plain}


class Trainer:
    """Runs a learner to its budget with evaluation, logging and checkpoints.

    Args:
        learner: The learning method, already built on its gym.
        train: The run section of the config.
        run_dir: Output directory.
        library: The motions (for evaluation).
        humanoid: The model.
        meta: Config fingerprint stored in checkpoints and checked on resume.
        name: Label for the progress display.
        rng: The learner's numpy generator (saved and restored with the other RNGs).
        default_meta: The fingerprint of the learner's default config: a checkpoint written before an option
            existed resumes when the run holds that option at its default (see ``check_compatible``).
        world: This process's rank in a data-parallel run (default: a single process). Rank 0 alone evaluates,
            logs and writes checkpoints (holding every rank's state); its clock and a stop request on any rank
            decide, for every rank, when to checkpoint and when to stop; ``samples`` counts every rank's.
    """

    def __init__(self, learner: Learner, train: TrainConfig, run_dir: RunDir, library: MotionLibrary,
                 humanoid: Humanoid, meta: dict[str, Any], name: str, rng: np.random.Generator,
                 default_meta: dict[str, Any] | None = None, world: World | None = None) -> None:  # fmt: skip
        self.world = World() if world is None else world
        self.default_meta = default_meta
        self.learner, self.train, self.run_dir = learner, train, run_dir
        self.library, self.humanoid, self.meta, self.name, self.rng = library, humanoid, meta, name, rng
        self.iteration = 0
        self.samples = 0
        self.train_seconds = 0.0
        self.timers = Timers()
        self.last_eval: EvalResult | None = None

    def _state(self) -> dict[str, Any] | None:
        """What :meth:`resume` needs (the entries :data:`_STATE_KEYS`), on rank 0; None on the other ranks.

        A data-parallel run's checkpoint also holds ``world_size`` and, under ``ranks``, the learner state and random
        state of ranks 1 .. N - 1 (their gyms, buffers and generators; the networks are rank 0's everywhere)."""
        state = {"meta": self.meta, "iteration": self.iteration, "samples": self.samples,
                 "train_seconds": self.train_seconds, "learner": self.learner.state_dict(),
                 "rng": rng_state(self.rng)}  # fmt: skip
        if not self.world.distributed:
            return state
        ranks = self.world.gather_to_main({"learner": state["learner"], "rng": state["rng"]})
        return None if ranks is None else {**state, "world_size": self.world.size, "ranks": ranks[1:]}

    def resume(self) -> None:
        """Restores the newest intact checkpoint (saying which, and why any newer one was passed over). Every rank
        of a data-parallel run reads the file rank 0 chose and restores its own part.

        Raises:
            ValueError: If no checkpoint reads (:class:`common.run.checkpoint.CheckpointError`), the newest intact
                one belongs to another config or learner, or it was written by a run of another number of ranks.
        """
        world = self.world
        found: tuple[Path, list[Path]] | BaseException | None = None
        if world.is_main:
            try:
                path, state, passed_over = self.run_dir.load_latest_checkpoint(map_location="cpu",
                                                                               required=_STATE_KEYS)  # fmt: skip
                found = (path, passed_over)
            except ValueError as e:
                found = e
        found = world.from_main(found)  # every rank fails alike, or restores from the same file
        if isinstance(found, BaseException):
            raise found
        path, passed_over = found
        if not world.is_main:
            state = load_checkpoint_file(path, map_location="cpu", sha256=recorded_digest(path))
        check_compatible(state["meta"], self.meta, path, self.default_meta)
        saved_size = int(state.get("world_size", 1))
        if saved_size != world.size:
            raise ValueError(f"checkpoint {path} was written by a run of {saved_size} rank(s), this run has "
                             f"{world.size}: resume it with torchrun --nproc_per_node={saved_size} (one machine) "
                             "or the same total number of ranks")  # fmt: skip
        mine = state if world.rank == 0 else state["ranks"][world.rank - 1]
        try:
            self.learner.load_state_dict(mine["learner"])
        except (KeyError, ValueError, RuntimeError) as e:  # a damaged or hand-edited checkpoint; the files stay
            raise CommandError(f"checkpoint {path}: cannot restore the learner: {one_line(e)}") from e
        set_rng_state(mine["rng"], self.rng)
        self.iteration, self.samples = int(state["iteration"]), int(state["samples"])
        self.train_seconds = float(state["train_seconds"])
        if world.is_main:
            print(f"resuming from {path} (iteration {self.iteration}"
                  + (f", {world.size} ranks)" if world.distributed else ")"), file=sys.stderr)  # fmt: skip
            self.run_dir.confirm_resume(passed_over)

    def evaluate(self) -> EvalResult:
        return evaluate(self.learner.policy(), self.library, self.humanoid, self.train.eval)

    def run(self, stop: Callable[[], bool] | None = None) -> EvalResult | None:
        """Trains until a budget is spent; checkpoints, then evaluates at the end. Returns the last evaluation (None
        on the ranks other than 0 of a data-parallel run, which neither evaluate nor log)."""
        t = self.train
        lead = self.world.is_main
        logger = MetricsLogger(self.run_dir) if lead else None
        if logger is not None and self.run_dir.resume:
            logger.truncate_after(self.iteration)
        progress = Progress(
            t.max_iterations,
            self.name,
            initial=self.iteration,
            initial_samples=self.samples,
            keys=("eval/mpjpe_g", "eval/survival", "losses/policy"),
            plain_every=max(1, t.log_every),
        ) if lead else None  # fmt: skip
        next_eval = self._next(t.eval_every_minutes, t.eval_every_iterations)
        next_ckpt = self.train_seconds + 60.0 * t.checkpoint_every_minutes
        pending: dict[str, list[float]] = {}
        warm_up = getattr(self.learner, "warm_up", None)
        if warm_up is not None:
            # Compilation is a fixed cost per process start, not training: it stays off the clock and the budget.
            start = time.perf_counter()
            warm_up()
            pending["perf/compile_s"] = [time.perf_counter() - start]
        evaluated_at = -1
        try:
            decision = self._decide(stop, checkpoint=False)
            while not decision["stop"]:
                start = time.perf_counter()
                with self.timers("gym"):
                    self.samples += self.learner.collect() * self.world.size
                with self.timers("update"):
                    stats = self.learner.update()
                self.iteration += 1
                self.train_seconds += time.perf_counter() - start
                if lead:
                    for k, v in stats.items():
                        pending.setdefault(k, []).append(float(v))
                    metrics: dict[str, float] = {}
                    if self.iteration % t.log_every == 0:
                        metrics.update({k: float(np.nanmean(v)) for k, v in pending.items()})
                        metrics.update(self.timers.metrics())
                        metrics.update(self.world.pop_metrics(t.log_every))
                        metrics["perf/samples_per_s"] = self.samples / max(self.train_seconds, 1e-9)
                        pending.clear()
                    if self._due(next_eval):
                        metrics.update(self._evaluate())
                        evaluated_at = self.iteration
                        next_eval = self._next(t.eval_every_minutes, t.eval_every_iterations)
                    if metrics:
                        logger.log(self.iteration, metrics, self.samples, self.train_seconds)
                    progress.update(1, samples=self.samples, metrics=metrics)
                decision = self._decide(stop, checkpoint=self.train_seconds >= next_ckpt)
                if decision["checkpoint"]:
                    self._save()
                    next_ckpt = self.train_seconds + 60.0 * t.checkpoint_every_minutes
            # The checkpoint first (a stop signal under torchrun leaves 30 s before the kill), then what was gathered
            # since the last log line (a run shorter than log_every: perf/compile_s too) in the last record, with the
            # final evaluation unless the last iteration was just evaluated.
            self._save()
            if lead:
                final = {k: float(np.nanmean(v)) for k, v in pending.items()}
                if evaluated_at != self.iteration:
                    final.update(self._evaluate())
                if final:
                    logger.log(self.iteration, final, self.samples, self.train_seconds)
        except BaseException:
            if lead:  # the failure on its way is the one to report: closing adds none
                progress.close()
                logger.abandon()
            raise
        if lead:
            progress.close()
            logger.close()
        return self.last_eval

    def _decide(self, stop: Callable[[], bool] | None, checkpoint: bool) -> dict[str, bool]:
        """Whether to stop (a budget spent by rank 0's count and clock, or a stop request on any rank) and whether
        to checkpoint now (rank 0's clock): the same answer on every rank."""
        flags = self.world.decide(any_request=stop is not None and stop(), budget=self._budget_spent(),
                                  checkpoint=checkpoint)  # fmt: skip
        return {"stop": flags["any_request"] or flags["budget"], "checkpoint": flags["checkpoint"]}

    def _save(self) -> None:
        state = self._state()  # every rank's part (a collective in a data-parallel run)
        if state is None:
            return
        try:
            self.run_dir.save_checkpoint(state, self.iteration)
        except OSError as e:  # a full disk or a lost mount: what is saved stays, the run cannot go on
            raise CommandError(f"cannot write the checkpoint of iteration {self.iteration} in "
                               f"{self.run_dir.checkpoint_dir}: {e.strerror or e}; the checkpoints already there are "
                               "intact (continue with --resume once it can be written)", EXIT_RUN_FAILED) from None

    def _evaluate(self) -> dict[str, float]:
        self.last_eval = self.evaluate()
        return {**self.last_eval.as_metrics(), **self.learner.diagnostics()}

    def _next(self, minutes: float | None, iterations: int) -> tuple[str, float]:
        if minutes is not None:
            return ("seconds", next_mark(self.train_seconds, 60.0 * minutes))
        return ("iterations", next_mark(self.iteration, iterations))

    def _due(self, when: tuple[str, float]) -> bool:
        kind, value = when
        return (self.train_seconds if kind == "seconds" else self.iteration) >= value

    def _budget_spent(self) -> bool:
        t = self.train
        return (
            (t.max_minutes is not None and self.train_seconds >= 60.0 * t.max_minutes)
            or (t.max_samples is not None and self.samples >= t.max_samples)
            or (t.max_iterations is not None and self.iteration >= t.max_iterations)
        )


def next_mark(now: float, every: float) -> float:
    """The first multiple of ``every`` after ``now``. Evaluations fall on this grid, so a run resumed from a checkpoint
    is evaluated at the same training minutes (iterations) as one run straight, and a late evaluation does not push
    the later ones back."""
    return (math.floor(now / every) + 1) * every


class NanGuard:
    """Protects training from non-finite losses.

    Call :meth:`check` with a step's losses before ``optimizer.step()``. A non-finite loss skips the step, logs which
    loss and the batch statistics, and restores the last good weights and optimiser states (snapshotted every
    ``snapshot_every`` good steps); more than ``max_consecutive`` bad steps in a row raise ``FloatingPointError``.

    Args:
        objects: Modules and optimisers to snapshot, by name.
        snapshot_every: Good steps between snapshots.
        max_consecutive: Bad steps in a row tolerated before giving up.
    """

    def __init__(self, objects: Mapping[str, Any], snapshot_every: int = 50, max_consecutive: int = 10) -> None:
        self.objects = dict(objects)
        self.snapshot_every = snapshot_every
        self.max_consecutive = max_consecutive
        self.good_steps = 0
        self.bad_in_a_row = 0
        self.bad_total = 0
        self._snapshot = self._take()

    def _take(self) -> dict[str, Any]:
        return {k: copy.deepcopy(o.state_dict()) for k, o in self.objects.items()}

    def check(self, losses: Mapping[str, torch.Tensor], batch_stats: Mapping[str, float] | None = None) -> bool:
        """True when every loss is finite (go on with the step); False when the step must be skipped."""
        bad = [k for k, v in losses.items() if not bool(torch.isfinite(v).all())]
        if not bad:
            self.bad_in_a_row = 0
            self.good_steps += 1
            if self.good_steps % self.snapshot_every == 0:
                self._snapshot = self._take()
            return True
        self.bad_in_a_row += 1
        self.bad_total += 1
        stats = ", ".join(f"{k}={v:.4g}" for k, v in (batch_stats or {}).items())
        print(f"warning: non-finite loss {bad} (batch: {stats}); restoring the last good weights", file=sys.stderr)
        for k, o in self.objects.items():
            o.load_state_dict(copy.deepcopy(self._snapshot[k]))
        if self.bad_in_a_row > self.max_consecutive:
            raise FloatingPointError(
                f"non-finite losses {bad} in {self.bad_in_a_row} steps in a row; last batch: {stats}. "
                "Lower the learning rate or check the data (the last checkpoint is intact)."
            )
        return False
