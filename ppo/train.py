"""``train-ppo``: trains the PPO motion tracker (DeepMimic / PARC baseline) with the shared trainer.

The command is the shared :func:`common.train.command.train_main` (run directory, progress display, metrics,
atomic checkpoints, ``--resume``, periodic evaluation, Ctrl-C) with PPO's learner.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from common.character.humanoid import Humanoid
from common.motion.library import MotionLibrary
from common.train.command import TrainingCommand, train_main
from common.train.distributed import World
from ppo.config import PPOTrackerConfig
from ppo.learner import PPOLearner

DESCRIPTION = """\
Train the PPO motion tracker: N simulated DeepMimic humanoids track motion capture; the policy outputs PD-target
offsets from the reference (a zero action plays the clip back open loop) and learns by PPO with GAE on rollouts of
rollout_length x num_envs steps, with a running observation normaliser and PARC's adaptive clip weights. Bundled
configs: default (CPU), paper (PARC's scale, for a big machine), debug (tests)."""

EXAMPLES = (
    "train-ppo --motions walk --max-minutes 15 --out runs/ppo-walk",
    "train-ppo --out runs/ppo-walk --resume --max-minutes 30",
    "train-ppo --config debug --set ppo.actor_lr=1e-4 --set gym.num_envs=32",
    "torchrun --standalone --nproc_per_node=2 -m ppo.train --set gym.threads=1 --out runs/ppo-2ranks   # 2 ranks",
)


def _make_learner(cfg: PPOTrackerConfig, humanoid: Humanoid, library: MotionLibrary, rng: np.random.Generator,
                  prepared: Any, world: World) -> PPOLearner:  # fmt: skip
    return PPOLearner(cfg, library, humanoid, rng, world)


COMMAND = TrainingCommand(
    name="ppo", prog="train-ppo", config_cls=PPOTrackerConfig, description=DESCRIPTION, examples=EXAMPLES,
    make_learner=_make_learner, user_errors=(ValueError,),
)  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    """The command's argument parser (for ``--help`` and tests)."""
    return COMMAND.parser()


def main(argv: Sequence[str] | None = None) -> int:
    train_main(COMMAND, argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
