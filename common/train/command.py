"""The one ``main()`` of every training command (``train-supertrack``, ``train-ppo``).

A learner's command is a :class:`TrainingCommand`: its name, config class, texts, and how to build its learner.
:func:`train_main` does the rest the same way for every learner: parse the options, validate config and motions
before anything is written (:func:`common.train.startup.prepare`), build the learner, resume if asked, train to the
budget with a clean Ctrl-C or SIGTERM (the first finishes the iteration, checkpoints and evaluates; the second aborts
without saving), print the final table. Under ``torchrun`` the same command is one rank of a data-parallel run
(:mod:`common.train.distributed`): every rank validates its inputs and builds its learner; rank 0 alone writes. An
error a user can fix ends in one line (``error: ...``) and exit status 2 (bad input, nothing written) or 1 (a failure
during the run); a bug keeps its traceback (:mod:`common.cli`).
"""

from __future__ import annotations

import argparse
import os
import shlex
import signal
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from types import FrameType
from typing import Any

from common.character.humanoid import Humanoid
from common.cli import EXIT_RUN_FAILED, CommandParser, fail, one_line, one_line_errors, os_error_line
from common.config import ConfigError
from common.evaluation.evaluate import EvalResult
from common.motion.library import MotionLibrary
from common.motion.motion import MotionFormatError
from common.run.checkpoint import CheckpointError
from common.run.command_line import portable_args
from common.run.directory import RunDirError
from common.sim.collect import CollectorError
from common.train.distributed import DistributedError, World, from_environment
from common.train.startup import add_common_arguments, check_device_available, prepare, start
from common.train.training import Learner, Trainer, compat_meta

EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a process stopped by Ctrl-C

COMMON_EPILOG = """\
Every run writes RUN_DIR/config.yaml (the resolved config), run_info.json, metrics.jsonl and tb/ (losses/...,
reward/..., charts/..., perf/..., eval/...) and checkpoints/ (atomic; latest.json names the newest). --out DIR
--resume continues a run exactly. Ctrl-C (or SIGTERM) stops at the end of the current iteration, checkpoints and
evaluates (press it twice to abort without saving).

Data-parallel: torchrun --nproc_per_node=N -m <supertrack|ppo>.train ... runs N ranks, each with its own gym
(seeded apart) and buffer, gradients averaged by torch.distributed (gloo on the CPU, NCCL on CUDA); rank 0 evaluates,
logs and checkpoints every rank's state. --resume needs the same N. See docs/distributed.md."""


@dataclass(frozen=True)
class TrainingCommand:
    """What one learner's training command adds to the shared main.

    Attributes:
        name: The learner's name, written into run_info.json and checkpoints (``supertrack``, ``ppo``); also the
            bundled config folder ``configs/<name>``.
        prog: The command's name (``train-supertrack``).
        config_cls: The learner's config dataclass.
        description: The ``--help`` text's first part (plain text, wrapped as written).
        examples: Example command lines for the ``--help`` epilog.
        make_learner: ``(cfg, humanoid, library, rng, prepared, world) -> learner``; may raise one of
            ``user_errors``.
        add_arguments: Adds the learner's own options to the parser.
        prepare: ``(args) -> prepared``: reads what the learner's own options name (e.g. a checkpoint to start
            from) before the config is resolved; exits with one line on bad input.
        check: ``(cfg, humanoid, library, prepared)``: what only the model and motions can validate (ValueError
            naming the key), before the run directory is made.
        info: ``(prepared) -> dict`` added to run_info.json.
        user_errors: Exceptions from building the learner that are the user's to fix (one line, exit 2; a
            collector worker that fails to start: exit 1, its traceback on the lines after). A collector worker's
            failure during the run always ends so.
        module: The module ``python -m`` / ``torchrun -m`` runs (default ``<name>.train``).
    """

    name: str
    prog: str
    config_cls: type
    description: str
    examples: Sequence[str] = ()
    make_learner: Callable[..., Learner] | None = None
    add_arguments: Callable[[argparse.ArgumentParser], None] | None = None
    prepare: Callable[[argparse.Namespace], Any] | None = None
    check: Callable[[Any, Humanoid, MotionLibrary, Any], None] | None = None
    info: Callable[[Any], dict[str, Any]] | None = None
    user_errors: tuple[type[BaseException], ...] = field(default_factory=tuple)
    module: str = ""

    def __post_init__(self) -> None:
        if not self.module:
            object.__setattr__(self, "module", f"{self.name}.train")

    def parser(self) -> argparse.ArgumentParser:
        """The command's argument parser: the shared options, then the learner's own."""
        epilog = COMMON_EPILOG
        if self.examples:
            epilog += "\n\nexamples:\n" + "\n".join(f"  {e}" for e in self.examples)
        parser = CommandParser(prog=self.prog, description=self.description, epilog=epilog,
                               formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
        add_common_arguments(parser, self.name)
        if self.add_arguments is not None:
            self.add_arguments(parser)
        return parser


class GracefulStop:
    """A SIGINT / SIGTERM handler: the first asks the loop to stop after the iteration; the second aborts at once."""

    def __init__(self) -> None:
        self.requested = False

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        print("\nstopping after this iteration (Ctrl-C again to abort without saving)", file=sys.stderr)


def train_main(command: TrainingCommand, argv: Sequence[str] | None = None) -> EvalResult | None:
    """Parses ``argv``, trains ``command``'s learner to its budget and returns the final evaluation (None on the ranks
    other than 0 of a data-parallel run, which do not evaluate).

    Bad options or inputs end in one line and exit status 2 with nothing written (the run directory is created only
    once the config, the motions, ``--out`` and the learner are accepted); a failure during the run (a full disk, a
    NaN loss, a failed collector worker) ends in one line and exit status 1, the run directory keeping its last
    checkpoint (:mod:`common.cli`).
    """
    with one_line_errors(ConfigError, MotionFormatError, CheckpointError, RunDirError, DistributedError):
        world = from_environment()
        try:
            return _train(command, argv, world)
        finally:
            world.close()


def _rank_device(cfg: Any, world: World, config_path: str) -> Any:
    """The config with this rank's device (``cuda`` -> ``cuda:<LOCAL_RANK>`` in a data-parallel run)."""
    device = world.device(cfg.train.device)
    if device == cfg.train.device:
        return cfg
    try:
        check_device_available(device)
    except ValueError as e:
        fail(f"{config_path}: train.{e} (LOCAL_RANK {world.local_rank})")
    return replace(cfg, train=replace(cfg.train, device=device))


def _launch_info(command: TrainingCommand, world: World) -> dict[str, Any]:
    """run_info.json's record of a data-parallel launch: the world size and the command as torchrun ran it (a
    rank's own argv names the module's file), with no absolute path of this machine (:mod:`common.run.command_line`;
    a single process's command is recorded the same way by :meth:`common.run.directory.RunDir.write_run_info`)."""
    if not world.distributed:
        return {}
    per_node = os.environ.get("LOCAL_WORLD_SIZE", str(world.size))
    args = shlex.join(portable_args(sys.argv[1:]))
    return {"world_size": world.size, "command": f"torchrun --nproc_per_node={per_node} -m {command.module} {args}"}


def _train(command: TrainingCommand, argv: Sequence[str] | None, world: World) -> EvalResult | None:
    args = command.parser().parse_args(argv)
    prepared = command.prepare(args) if command.prepare is not None else None

    def check(cfg: Any, humanoid: Humanoid, library: MotionLibrary) -> None:
        if command.check is not None:
            command.check(cfg, humanoid, library, prepared)

    # Every rank validates the same inputs (so all refuse alike) before rank 0 makes the run directory.
    saved_cfg, run_dir, humanoid, library = prepare(command.config_cls, args, command.name, check=check)
    cfg = _rank_device(saved_cfg, world, args.config)
    world.init(cfg.train.device)
    rng = world.generator(cfg.train.seed)
    assert command.make_learner is not None, f"{command.prog}: no make_learner"
    try:
        learner = command.make_learner(cfg, humanoid, library, rng, prepared, world)
    except command.user_errors as e:
        if isinstance(e, CollectorError):  # its traceback stays on the lines after the first
            fail(str(e), EXIT_RUN_FAILED)
        fail(one_line(e))
    world.seed_torch(cfg.train.seed)
    try:
        if world.is_main:
            info = command.info(prepared) if command.info is not None else {}
            start(saved_cfg, run_dir, library, command.name, {**info, **_launch_info(command, world)})
        trainer = Trainer(learner, cfg.train, run_dir, library, humanoid, compat_meta(cfg, humanoid, command.name),
                          command.name, rng, compat_meta(command.config_cls(), humanoid, command.name),
                          world)  # fmt: skip
        if args.resume:
            try:
                trainer.resume()
            except (ValueError, KeyError) as e:
                fail(f"cannot resume: {one_line(e)}")
        stop = GracefulStop()
        previous = signal.signal(signal.SIGINT, stop)
        previous_term = signal.signal(signal.SIGTERM, stop)
        try:
            result = trainer.run(stop=lambda: stop.requested)
        except FloatingPointError as e:
            fail(f"{one_line(e)}; the run directory {run_dir.path} keeps its last good checkpoint", EXIT_RUN_FAILED)
        except CollectorError as e:  # a collector worker failed: its traceback on the lines after the first
            first, _, rest = str(e).partition("\n")
            fail(f"{first}; the run directory {run_dir.path} keeps its last checkpoint" + (f"\n{rest}" if rest else ""),
                 EXIT_RUN_FAILED)  # fmt: skip
        except OSError as e:  # a full disk while logging: the checkpoints written so far stay
            fail(f"run directory {run_dir.path}: cannot write {os_error_line(e)}; its checkpoints are intact "
                 "(continue with --resume once it can be written)", EXIT_RUN_FAILED)  # fmt: skip
        except KeyboardInterrupt:  # the second Ctrl-C
            fail(f"interrupted; the run directory {run_dir.path} keeps its last checkpoint", EXIT_INTERRUPTED)
        finally:
            signal.signal(signal.SIGINT, previous)
            signal.signal(signal.SIGTERM, previous_term)
    finally:
        learner.close()
        run_dir.unlock()  # taken by start() on the main process
    if result is None:  # a rank other than 0
        return None
    print(result.table())
    print(f"run directory: {run_dir.path}")
    return result
