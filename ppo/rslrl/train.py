"""``train-rsl-rl``: trains rsl_rl's PPO (rsl-rl-lib 5.x) on the tracking gym with the shared trainer.

The command is the shared :func:`common.train.command.train_main` (run directory, progress display, metrics, atomic
checkpoints, ``--resume``, periodic evaluation, Ctrl-C) with :class:`ppo.rslrl.learner.RslRlLearner`. rsl-rl-lib is
an optional extra: without it the command says in one line how to install it.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from common.character.humanoid import Humanoid
from common.cli import fail, one_line_errors
from common.motion.library import MotionLibrary
from common.train.command import TrainingCommand, train_main
from common.train.distributed import World
from common.train.training import Learner
from ppo.rslrl import require_rsl_rl
from ppo.rslrl.config import RslRlConfig

DESCRIPTION = """\
Train rsl_rl's PPO (rsl-rl-lib, ETH Zurich's reference implementation) as a second PPO arm on the shared tracking
gym: the gym is presented as rsl_rl's VecEnv (our PPO's PARC observation, rewards, termination, reference state
initialisation, adaptive clip weights, and PD targets = reference + action_scale * clip(a)), and rsl_rl's
OnPolicyRunner and PPO train on it with rsl_rl's defaults except the network widths, the observation normalisation
and the samples per update, which match our PPO (docs/rsl-rl.md). One process (no torchrun: rsl_rl's data-parallel
mode is its own). Bundled configs: default (CPU), debug (tests)."""

EXAMPLES = (
    "train-rsl-rl --motions walk --max-minutes 15 --out runs/rsl-walk",
    "train-rsl-rl --out runs/rsl-walk --resume --max-minutes 30",
    "train-rsl-rl --config debug --set algorithm.learning_rate=1e-4 --set gym.num_envs=32",
)


def _make_learner(cfg: RslRlConfig, humanoid: Humanoid, library: MotionLibrary, rng: np.random.Generator,
                  prepared: Any, world: World) -> Learner:  # fmt: skip
    from ppo.rslrl.learner import RslRlLearner  # imports rsl_rl (checked by main)

    return RslRlLearner(cfg, library, humanoid, rng, world)


COMMAND = TrainingCommand(
    name="rsl_rl", prog="train-rsl-rl", config_cls=RslRlConfig, description=DESCRIPTION, examples=EXAMPLES,
    make_learner=_make_learner, user_errors=(ValueError,), module="ppo.rslrl.train",
)  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    """The command's argument parser (for ``--help`` and tests)."""
    return COMMAND.parser()


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if not {"-h", "--help"} & set(args):  # the help needs no rsl_rl
        with one_line_errors():
            try:
                require_rsl_rl()
            except ModuleNotFoundError as e:
                fail(str(e))
    train_main(COMMAND, argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
