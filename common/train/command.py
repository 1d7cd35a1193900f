"""The one ``main()`` of every training command (``train-supertrack``, ``train-ppo``).

A learner's command is a :class:`TrainingCommand`: its name, config class, texts, and how to build its learner.
:func:`train_main` does the rest the same way for every learner: parse the options, validate config and motions
before anything is written (:func:`common.train.training.setup`), build the learner, resume if asked, train to the
budget with a clean Ctrl-C (the first finishes the iteration, evaluates and checkpoints; the second aborts without
saving), print the final table. An error a user can fix ends in one line (``error: ...``) and exit status 1 or 2;
a bug keeps its traceback.
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from types import FrameType
from typing import Any

import numpy as np

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import EvalResult
from common.motion.library import MotionLibrary
from common.sim.collect import CollectorError
from common.train.training import Learner, Trainer, add_common_arguments, compat_meta, setup

COMMON_EPILOG = """\
Every run writes RUN_DIR/config.yaml (the resolved config), run_info.json, metrics.jsonl and tb/ (losses/...,
reward/..., charts/..., perf/..., eval/...) and checkpoints/ (atomic; latest.json names the newest). --out DIR
--resume continues a run exactly. Ctrl-C stops at the end of the current iteration, evaluates and checkpoints
(press it twice to abort without saving)."""


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
        make_learner: ``(cfg, humanoid, library, rng, prepared) -> learner``; may raise one of ``user_errors``.
        add_arguments: Adds the learner's own options to the parser.
        prepare: ``(args) -> prepared``: reads what the learner's own options name (e.g. a checkpoint to start
            from) before the config is resolved; exits with one line on bad input.
        check: ``(cfg, humanoid, library, prepared)``: what only the model and motions can validate (ValueError
            naming the key), before the run directory is made.
        info: ``(prepared) -> dict`` added to run_info.json.
        user_errors: Exceptions from building the learner that are the user's to fix (one line, exit 1). A
            collector worker's failure during the run always ends in one line (its traceback in the message).
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

    def parser(self) -> argparse.ArgumentParser:
        """The command's argument parser: the shared options, then the learner's own."""
        epilog = COMMON_EPILOG
        if self.examples:
            epilog += "\n\nexamples:\n" + "\n".join(f"  {e}" for e in self.examples)
        parser = argparse.ArgumentParser(prog=self.prog, description=self.description, epilog=epilog,
                                         formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
        add_common_arguments(parser, self.name)
        if self.add_arguments is not None:
            self.add_arguments(parser)
        return parser


class GracefulStop:
    """A SIGINT handler: the first asks the loop to stop after the iteration; the second aborts at once."""

    def __init__(self) -> None:
        self.requested = False

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        print("\nstopping after this iteration (Ctrl-C again to abort without saving)", file=sys.stderr)


def train_main(command: TrainingCommand, argv: Sequence[str] | None = None) -> EvalResult:
    """Parses ``argv``, trains ``command``'s learner to its budget and returns the final evaluation."""
    args = command.parser().parse_args(argv)
    prepared = command.prepare(args) if command.prepare is not None else None

    def check(cfg: Any, humanoid: Humanoid, library: MotionLibrary) -> None:
        if command.check is not None:
            command.check(cfg, humanoid, library, prepared)

    info = command.info(prepared) if command.info is not None else None
    cfg, run_dir, humanoid, library = setup(command.config_cls, args, command.name, check=check, info=info)
    rng = np.random.default_rng(cfg.train.seed)
    assert command.make_learner is not None, f"{command.prog}: no make_learner"
    try:
        learner = command.make_learner(cfg, humanoid, library, rng, prepared)
    except command.user_errors as e:
        sys.exit(f"error: {e}")
    try:
        trainer = Trainer(learner, cfg.train, run_dir, library, humanoid, compat_meta(cfg, humanoid, command.name),
                          command.name, rng)  # fmt: skip
        if args.resume:
            try:
                trainer.resume()
            except (ValueError, KeyError) as e:
                sys.exit(f"error: cannot resume: {e}")
        stop = GracefulStop()
        previous = signal.signal(signal.SIGINT, stop)
        try:
            result = trainer.run(stop=lambda: stop.requested)
        except FloatingPointError as e:
            sys.exit(f"error: {e}\nthe run directory {run_dir.path} keeps its last good checkpoint")
        except CollectorError as e:  # a collector worker failed (its traceback is in the message)
            sys.exit(f"error: {e}\nthe run directory {run_dir.path} keeps its last checkpoint")
        finally:
            signal.signal(signal.SIGINT, previous)
    finally:
        learner.close()
    print(result.table())
    print(f"run directory: {run_dir.path}")
    return result
