"""What a SAMCON run's LQR recovery paths add: per clip, the stored LQR policy judged under the shared protocol with
its first k paths (the main path alone, then more), beside the regressed per-segment policies of the same run.

Recovery paths (``lqr.visit_rounds``) are stored in the order the rounds added them, so the first k paths are the
policy after the rounds that had added them. The main path alone never needs a cost-to-go (it is the only choice).

Usage: python benchmarks/samcon_lqr_paths.py RUN_DIR [--starts 16] [--paths 1 8 0] [--threads 1]
       (0 in --paths: all of them)
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from common.character.humanoid import Humanoid
from common.config import load_config
from common.evaluation.evaluate import evaluate
from common.motion.dataset import load_motions
from samcon import store
from samcon.config import SamconConfig
from samcon.feedback import FeedbackPolicy
from samcon.lqr import evaluation_policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a track-samcon run directory (lqr.enabled)")
    parser.add_argument("--starts", type=int, default=16, help="evaluator starts per clip")
    parser.add_argument("--paths", type=int, nargs="+", default=[1, 0], help="path counts to judge (0: all)")
    parser.add_argument("--threads", type=int, default=1, help="MuJoCo threads of the evaluator")
    args = parser.parse_args()
    cfg = load_config(SamconConfig, str(args.run / "config.yaml"))
    humanoid = Humanoid(cfg.gym.physics)
    plans, _ = store.load_plans(args.run / store.FILE_NAME, humanoid.physics.control_hz)
    ev = replace(cfg.train.eval, starts_per_clip=args.starts, threads=args.threads)
    print(f"{args.run}: {args.starts} starts per clip, {ev.max_frames} frames; survival, episode length ratio, "
          "MPJPE-g (mm, full horizon)")  # fmt: skip
    for name, plan in plans.items():
        library = load_motions([name], humanoid)
        if not plan.lqr:
            print(f"{name}: no LQR paths")
            continue
        rows = []
        for k in args.paths:
            count = len(plan.lqr) if k == 0 else min(k, len(plan.lqr))
            paths = plan.lqr[:count]
            if count == 1:
                paths = [replace(paths[0], cost_to_go=None)]
            res = evaluate(evaluation_policy({name: replace(plan, lqr=paths)}, library, humanoid), library,
                           humanoid, ev)  # fmt: skip
            rows.append((f"LQR, {count} path{'s' if count > 1 else ''}", res))
        res = evaluate(FeedbackPolicy({name: replace(plan, lqr=None)}, library, humanoid), library, humanoid, ev)
        rows.append(("regressed per-segment", res))
        for label, res in rows:
            o = res.overall
            print(f"{name:<16} {label:<24} survival {o['survival']:.3f}  episode {o['episode_len_ratio']:.3f}  "
                  f"MPJPE-g {o['mpjpe_g']:8.1f}  lengths {res.episode_length[0].tolist()}")  # fmt: skip


if __name__ == "__main__":
    main()
