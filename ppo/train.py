"""``train-ppo``: trains the PPO motion tracker (DeepMimic / PARC baseline) with the shared trainer.

The run directory, progress display, metrics (JSON lines + TensorBoard), atomic checkpoints, ``--resume`` and the
periodic evaluation are those of ``train-supertrack`` (:mod:`common.train.training`).
"""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path
from types import FrameType

import numpy as np

from common.train.training import Trainer, add_common_arguments, compat_meta, setup
from ppo.config import PPOTrackerConfig
from ppo.learner import PPOLearner

DEFAULT_CONFIG = str(Path(__file__).resolve().parents[1] / "configs" / "ppo" / "default.yaml")

DESCRIPTION = """\
Train the PPO motion tracker: N simulated DeepMimic humanoids track motion capture; the policy outputs PD-target
offsets from the reference (a zero action plays the clip back open loop) and learns by PPO with GAE on rollouts of
rollout_length x num_envs steps, with a running observation normaliser and PARC's adaptive clip weights.

Every run writes RUN_DIR/config.yaml (resolved config), run_info.json, metrics.jsonl and tb/ (losses/..., reward/...,
charts/..., perf/..., eval/...), and checkpoints/ (atomic; latest.json names the newest). Ctrl-C stops at the end of
the current iteration, evaluates and checkpoints (press it twice to abort without saving).
"""

EPILOG = """\
configs: configs/ppo/default.yaml (CPU default), configs/ppo/paper.yaml (PARC scale, for a big machine),
configs/ppo/debug.yaml (tiny, for tests). Examples:
  train-ppo --motions walk --max-minutes 15 --out runs/ppo-walk
  train-ppo --out runs/ppo-walk --resume --max-minutes 30
  train-ppo --config configs/ppo/debug.yaml --set ppo.actor_lr=1e-4 --set gym.num_envs=32
"""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="train-ppo", description=DESCRIPTION, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_common_arguments(parser, DEFAULT_CONFIG)
    return parser


class _GracefulStop:
    """First SIGINT: finish the iteration, evaluate and checkpoint; second SIGINT: abort at once."""

    def __init__(self) -> None:
        self.requested = False

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        print("\nstopping after this iteration (Ctrl-C again to abort without saving)", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    cfg, run_dir, humanoid, library = setup(PPOTrackerConfig, args, "ppo")
    rng = np.random.default_rng(cfg.train.seed)
    try:
        learner = PPOLearner(cfg, library, humanoid, rng)
    except ValueError as e:
        sys.exit(f"error: {e}")
    meta = compat_meta(cfg, humanoid, "ppo")
    trainer = Trainer(learner, cfg.train, run_dir, library, humanoid, meta, "ppo", rng)
    try:
        if args.resume:
            try:
                trainer.resume()
            except (ValueError, KeyError) as e:
                sys.exit(f"error: cannot resume: {e}")
        stop = _GracefulStop()
        previous = signal.signal(signal.SIGINT, stop)
        try:
            result = trainer.run(stop=lambda: stop.requested)
        except FloatingPointError as e:
            sys.exit(f"error: {e}\nthe run directory {run_dir.path} keeps its last good checkpoint")
        finally:
            signal.signal(signal.SIGINT, previous)
    finally:
        learner.close()
    print(result.table())
    print(f"run directory: {run_dir.path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
