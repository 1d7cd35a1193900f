"""Live against averaged policy weights, checkpoint by checkpoint, in one SuperTrack run.

A run trained with ``policy.average_decay`` > 0 stores both the live policy and its weight average in every
checkpoint. This evaluates both at each numbered checkpoint with the run's own protocol and prints MPJPE-g,
survival and success side by side, then the spread of each over the checkpoints: whether averaging steadies the
score that swings from one evaluation to the next.

Keep the checkpoints to compare by training with e.g. ``--set train.checkpoint_every_minutes=5
--set train.keep_checkpoints=13``.

Usage: python benchmarks/policy_average.py RUN_DIR [--starts 16] [--threads 1] [--last 4]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
import torch

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import evaluate
from common.motion.dataset import load_motions
from common.run.checkpoint import load_checkpoint_file
from common.run.directory import numbered_checkpoints
from report.runs import load_run
from supertrack.export import load_eval_policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", metavar="RUN_DIR", help="a train-supertrack run directory with policy.average_decay > 0")
    parser.add_argument("--starts", type=int, default=None, help="episodes per clip (default: the run's protocol)")
    parser.add_argument("--threads", type=int, default=1, help="rollout threads")
    parser.add_argument("--last", type=int, default=4, help="checkpoints in the final spread summary (the newest)")
    args = parser.parse_args()

    torch.set_num_threads(1)
    run = load_run(args.run)
    if run.learner != "supertrack":
        raise SystemExit(f"{args.run}: a {run.learner} run; this compares SuperTrack's averaged policy")
    protocol = run.eval_config()
    protocol = replace(protocol, threads=args.threads, starts_per_clip=args.starts or protocol.starts_per_clip)
    humanoid = Humanoid(run.physics())
    library = load_motions(run.motions, humanoid)
    checkpoints = dict(numbered_checkpoints(run.path / "checkpoints"))
    if not checkpoints:
        raise SystemExit(f"{args.run}: no numbered checkpoints")
    print(f"{run.path}: {len(checkpoints)} checkpoints, {protocol.starts_per_clip} starts per clip, "
          f"{len(library.names)} clip(s)")  # fmt: skip
    header = f"{'iteration':>10}{'samples':>10}  {'MPJPE-g live':>13}{'averaged':>10}  {'survival live':>14}" \
             f"{'averaged':>10}  {'success live':>13}{'averaged':>10}"  # fmt: skip
    print(header)
    rows = []
    for iteration in sorted(checkpoints):
        path = checkpoints[iteration]
        samples = int(load_checkpoint_file(path)["samples"])
        row = [iteration, samples]
        results = [evaluate(load_eval_policy(run.path, path, humanoid, library, average=a), library, humanoid,
                            protocol) for a in (False, True)]  # fmt: skip
        for key in ("mpjpe_g", "survival", "success"):
            row += [r.overall[key] for r in results]
        rows.append(row)
        r = row
        print(f"{r[0]:>10}{r[1]:>10}  {r[2]:>13.1f}{r[3]:>10.1f}  {r[4]:>14.3f}{r[5]:>10.3f}  "
              f"{r[6]:>13.3f}{r[7]:>10.3f}", flush=True)  # fmt: skip
    last = np.array(rows[-args.last:], dtype=float)
    print(f"\nOver the newest {len(last)} checkpoints (iterations {int(last[0, 0])}-{int(last[-1, 0])}):")
    for name, col in (("live", 2), ("averaged", 3)):
        g = last[:, col]
        print(f"  {name:<9} MPJPE-g mean {g.mean():7.1f} mm, min {g.min():7.1f}, max {g.max():7.1f}, "
              f"std {g.std():6.1f}; survival mean {last[:, col + 2].mean():.3f}")


if __name__ == "__main__":
    main()
