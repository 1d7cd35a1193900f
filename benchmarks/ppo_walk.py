"""Learning benchmark of the PPO tracker: the CPU default on the bundled walk clip, evaluated at minute marks.

Trains ``configs/ppo/default.yaml`` (any ``train-ppo`` option applies, e.g. ``--set gym.num_envs=128``) and, at every
mark of training wall-clock (evaluation excluded), evaluates with the shared evaluator and checkpoints. Prints the
open-loop baseline first, then per mark: samples, samples/s, the gym and update shares of the training time and the
tracking metrics; a summary table at the end. The run directory holds the usual metrics and checkpoints.

Run: ``.venv/bin/python benchmarks/ppo_walk.py --marks 15 30 60 --out runs/ppo-walk-bench``
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.evaluation.evaluate import EvalResult, evaluate, reference_policy  # noqa: E402
from common.train.startup import setup  # noqa: E402
from common.train.training import Trainer, compat_meta  # noqa: E402
from ppo.config import PPOTrackerConfig  # noqa: E402
from ppo.learner import PPOLearner  # noqa: E402
from ppo.train import build_parser  # noqa: E402

KEYS = ("mpjpe_g", "mpjpe_l", "root_pos_err", "body_rot_err", "success", "survival", "episode_len_ratio")


def _row(label: str, samples: int, rate: float, shares: dict[str, float], result: EvalResult) -> str:
    metrics = "".join(f"{result.overall[k]:>18.4g}" for k in KEYS)
    gym, update = shares.get("gym", float("nan")), shares.get("update", float("nan"))
    return f"{label:>10}{samples:>12}{rate:>12.0f}{gym:>8.2f}{update:>8.2f}{metrics}"


def main() -> int:
    parser = build_parser()
    parser.prog = "ppo_walk.py"
    parser.description = __doc__
    parser.add_argument("--marks", type=float, nargs="+", default=[15.0, 30.0, 60.0],
                        help="training minutes at which to evaluate and print (default: 15 30 60)")  # fmt: skip
    args = parser.parse_args()
    marks = sorted(args.marks)
    args.motions = args.motions or ["walk"]
    args.max_minutes = marks[-1]
    args.out = args.out or f"runs/ppo-walk-bench-{int(marks[-1])}min"
    cfg, run_dir, humanoid, library = setup(PPOTrackerConfig, args, "ppo")
    rng = np.random.default_rng(cfg.train.seed)
    learner = PPOLearner(cfg, library, humanoid, rng)
    trainer = Trainer(learner, cfg.train, run_dir, library, humanoid, compat_meta(cfg, humanoid, "ppo"), "ppo", rng)
    header = f"{'minutes':>10}{'samples':>12}{'samples/s':>12}{'gym':>8}{'update':>8}"
    header += "".join(f"{k:>18}" for k in KEYS)
    baseline = evaluate(lambda r: reference_policy(r, humanoid), library, humanoid, cfg.train.eval)
    rows = [_row("open-loop", 0, 0.0, {}, baseline)]
    print(header + "\n" + rows[0], flush=True)
    try:
        for mark in marks:
            trainer.train = dataclasses.replace(cfg.train, max_minutes=mark)
            result = trainer.run()
            rate = trainer.samples / max(trainer.train_seconds, 1e-9)
            minutes = f"{trainer.train_seconds / 60:.1f}"
            rows.append(_row(minutes, trainer.samples, rate, trainer.timers.shares(), result))
            print(header + "\n" + rows[-1], flush=True)
            print(result.table(), flush=True)
    finally:
        learner.close()
    print("\nsummary (shares: fraction of training time in gym.collect and in the update)")
    print(header + "\n" + "\n".join(rows))
    print(f"run directory: {run_dir.path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
