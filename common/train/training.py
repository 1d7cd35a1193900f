"""The training loop, command line and run directory shared by ``train-supertrack`` and ``train-ppo``.

A learner implements :class:`Learner` (collect frames from the gym into its buffer, one update, a deterministic
policy, state dicts); :class:`Trainer` drives it: wall-clock/sample/iteration budgets, periodic evaluation with the
shared evaluator, JSON-lines + TensorBoard metrics, atomic checkpoints and exact ``--resume``.

Log keys (shared by both learners so that the report reads either run): ``eval/...`` (the evaluator's metrics),
``losses/...``, ``reward/...``, ``world_model/...``, ``perf/...`` (samples/s, time shares), ``charts/...``.
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from datetime import datetime
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch

from common.bundled_configs import config_help, default_config
from common.bundled_configs import resolve_config as find_config
from common.character.humanoid import Humanoid
from common.config import ConfigError, load_config, to_dict
from common.evaluation.evaluate import EvalConfig, EvalResult, Policy, evaluate
from common.motion.dataset import load_motions
from common.motion.library import MotionLibrary
from common.motion.motion import MotionFormatError
from common.run.directory import RunDir, RunDirError, check_compatible, rng_state, set_rng_state
from common.run.logs import MetricsLogger, Progress, Timers
from common.sim.gym import GymConfig

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


def add_common_arguments(parser: argparse.ArgumentParser, command: str) -> None:
    """The options both training commands share; ``command`` names the bundled config folder (``configs/<command>``)."""
    parser.add_argument("--config", default=None,
                        help=config_help(command) + " (with --resume: the run's own config.yaml, so that --out and "
                             "--resume are enough to continue a run)")  # fmt: skip
    parser.set_defaults(default_config=str(default_config(command)), config_command=command)
    parser.add_argument("--motions", nargs="+", default=None,
                        help="motions to track, overriding train.motions: bundled clip names (walk, run, ...), 'all', "
                             "'long', DeepMimic .txt files, folders, or a motion dataset .h5")  # fmt: skip
    parser.add_argument("--device", default=None, help="torch device for the networks, e.g. cpu or cuda (train.device)")
    parser.add_argument("--out", default=None,
                        help="run directory (default: runs/<learner>-<date>-<time>); must not hold a run unless "
                             "--resume")  # fmt: skip
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue the run in --out from its latest checkpoint (same config and character)",
    )
    parser.add_argument(
        "--max-minutes", type=float, default=None, help="training wall-clock budget in minutes (train.max_minutes)"
    )
    parser.add_argument("--max-iterations", type=int, default=None, help="iteration budget (train.max_iterations)")
    parser.add_argument("--seed", type=int, default=None, help="random seed (train.seed)")
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override any config value, e.g. --set gym.num_envs=128 (repeatable)",
    )


def resolve_config(cls: type, args: argparse.Namespace) -> Any:
    """Loads the config file with ``--set`` overrides and the dedicated options applied.

    Without ``--config`` it is the command's default, or with ``--resume`` the run's own ``config.yaml`` (the
    resolved config it was started with); ``args.config`` is set to the file read, for messages."""
    if args.config is None:
        saved = Path(args.out) / "config.yaml" if args.resume and args.out else None
        args.config = str(saved) if saved is not None and saved.is_file() else args.default_config
    else:
        args.config = str(find_config(args.config, args.config_command))
    overrides = list(args.overrides)
    if args.motions is not None:
        overrides.append("train.motions=[" + ", ".join(repr(m) for m in args.motions) + "]")
    for option, key in (("device", "train.device"), ("max_minutes", "train.max_minutes"),
                        ("max_iterations", "train.max_iterations"), ("seed", "train.seed")):  # fmt: skip
        value = getattr(args, option)
        if value is not None:
            overrides.append(f"{key}={value}")
    return load_config(cls, args.config, overrides)


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
    """

    def __init__(self, learner: Learner, train: TrainConfig, run_dir: RunDir, library: MotionLibrary,
                 humanoid: Humanoid, meta: dict[str, Any], name: str, rng: np.random.Generator) -> None:  # fmt: skip
        self.learner, self.train, self.run_dir = learner, train, run_dir
        self.library, self.humanoid, self.meta, self.name, self.rng = library, humanoid, meta, name, rng
        self.iteration = 0
        self.samples = 0
        self.train_seconds = 0.0
        self.timers = Timers()
        self.last_eval: EvalResult | None = None

    def _state(self) -> dict[str, Any]:
        """What :meth:`resume` needs (the entries :data:`_STATE_KEYS`)."""
        return {
            "meta": self.meta, "iteration": self.iteration, "samples": self.samples,
            "train_seconds": self.train_seconds, "learner": self.learner.state_dict(), "rng": rng_state(self.rng),
        }  # fmt: skip

    def resume(self) -> None:
        """Restores the newest intact checkpoint (saying which, and why any newer one was passed over).

        Raises:
            ValueError: If no checkpoint reads (:class:`common.run.checkpoint.CheckpointError`) or the newest intact
                one belongs to another config or learner.
        """
        path, state, passed_over = self.run_dir.load_latest_checkpoint(map_location="cpu", required=_STATE_KEYS)
        check_compatible(state["meta"], self.meta, path)
        try:
            self.learner.load_state_dict(state["learner"])
        except (KeyError, ValueError, RuntimeError) as e:  # a damaged or hand-edited checkpoint; the files stay
            raise SystemExit(f"checkpoint {path}: cannot restore the learner: {e}") from e
        set_rng_state(state["rng"], self.rng)
        self.iteration, self.samples = int(state["iteration"]), int(state["samples"])
        self.train_seconds = float(state["train_seconds"])
        print(f"resuming from {path} (iteration {self.iteration})", file=sys.stderr)
        self.run_dir.confirm_resume(passed_over)

    def evaluate(self) -> EvalResult:
        return evaluate(self.learner.policy(), self.library, self.humanoid, self.train.eval)

    def run(self, stop: Callable[[], bool] | None = None) -> EvalResult:
        """Trains until a budget is spent; evaluates and checkpoints at the end. Returns the last evaluation."""
        t = self.train
        logger = MetricsLogger(self.run_dir)
        if self.run_dir.resume:
            logger.truncate_after(self.iteration)
        progress = Progress(
            t.max_iterations,
            self.name,
            initial=self.iteration,
            initial_samples=self.samples,
            keys=("eval/mpjpe_g", "eval/survival", "losses/policy"),
            plain_every=max(1, t.log_every),
        )
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
            while not self._budget_spent() and not (stop is not None and stop()):
                start = time.perf_counter()
                with self.timers("gym"):
                    self.samples += self.learner.collect()
                with self.timers("update"):
                    stats = self.learner.update()
                self.iteration += 1
                self.train_seconds += time.perf_counter() - start
                for k, v in stats.items():
                    pending.setdefault(k, []).append(float(v))
                metrics: dict[str, float] = {}
                if self.iteration % t.log_every == 0:
                    metrics.update({k: float(np.nanmean(v)) for k, v in pending.items()})
                    metrics.update(self.timers.metrics())
                    metrics["perf/samples_per_s"] = self.samples / max(self.train_seconds, 1e-9)
                    pending.clear()
                if self._due(next_eval):
                    metrics.update(self._evaluate())
                    evaluated_at = self.iteration
                    next_eval = self._next(t.eval_every_minutes, t.eval_every_iterations)
                if metrics:
                    logger.log(self.iteration, metrics, self.samples, self.train_seconds)
                progress.update(1, samples=self.samples, metrics=metrics)
                if self.train_seconds >= next_ckpt:
                    self._save()
                    next_ckpt = self.train_seconds + 60.0 * t.checkpoint_every_minutes
            # What was gathered since the last log line (a run shorter than log_every: perf/compile_s too) goes into
            # the last record, with the final evaluation unless the last iteration was just evaluated.
            final = {k: float(np.nanmean(v)) for k, v in pending.items()}
            if evaluated_at != self.iteration:
                final.update(self._evaluate())
            if final:
                logger.log(self.iteration, final, self.samples, self.train_seconds)
            self._save()
        finally:
            progress.close()
            logger.close()
        return self.last_eval

    def _save(self) -> None:
        try:
            self.run_dir.save_checkpoint(self._state(), self.iteration)
        except OSError as e:  # a full disk or a lost mount: what is saved stays, the run cannot go on
            raise SystemExit(f"error: cannot write the checkpoint of iteration {self.iteration} in "
                             f"{self.run_dir.checkpoint_dir}: {e.strerror or e}; the checkpoints already there are "
                             "intact (continue with --resume once it can be written)") from None  # fmt: skip

    def _evaluate(self) -> dict[str, float]:
        self.last_eval = self.evaluate()
        return {**self.last_eval.as_metrics(), **self.learner.diagnostics()}

    def _next(self, minutes: float | None, iterations: int) -> tuple[str, float]:
        if minutes is not None:
            return ("seconds", self.train_seconds + 60.0 * minutes)
        return ("iterations", self.iteration + iterations)

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


def setup(
    cls: type,
    args: argparse.Namespace,
    learner_name: str,
    check: Callable[[Any, Humanoid, MotionLibrary], None] | None = None,
    info: Mapping[str, Any] | None = None,
) -> tuple[Any, RunDir, Humanoid, MotionLibrary]:
    """Config, run directory, model and motions for a training command; exits with a clear message on bad input.

    ``check(cfg, humanoid, library)`` validates what only the model and motions can (it raises ValueError naming the
    key); it runs before the run directory is created, so a refused start leaves nothing behind. ``info`` is added
    to run_info.json.
    """
    try:
        cfg = resolve_config(cls, args)
        humanoid = Humanoid(cfg.gym.physics)
        library = load_motions(list(cfg.train.motions), humanoid)
        if check is not None:
            try:
                check(cfg, humanoid, library)
            except ValueError as e:
                raise ConfigError(f"{args.config}: {e}") from e
        out = args.out or f"runs/{learner_name}-{datetime.now().strftime('%Y%m%d-%H%M%S')}"
        run_dir = RunDir(out, resume=args.resume, keep_checkpoints=cfg.train.keep_checkpoints)
    except (ConfigError, RunDirError, MotionFormatError, FileNotFoundError) as e:
        sys.exit(f"error: {e}")
    torch.manual_seed(cfg.train.seed)
    torch.set_num_threads(max(1, cfg.train.torch_threads))
    if not args.resume:
        run_dir.save_config(cfg)
    run_dir.write_run_info({"learner": learner_name, "seed": cfg.train.seed, "motions": list(library.names),
                            **(info or {})})  # fmt: skip
    return cfg, run_dir, humanoid, library


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
