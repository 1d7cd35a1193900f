"""Open-loop baseline: every clip played with PD targets = the reference's next-frame hinge angles, no policy.

Two tables per clip, both from the shared evaluator:
- the evaluation protocol the learners are judged by (starts evenly spaced, 512 frames, SuperTrack's head rule
  after 48 frames), with every tracking metric;
- "fall frame": from t = 0, the first frame at which the head is 25 cm off its reference height (no grace period),
  and the MPJPE-g over the frames before it.
These are the numbers every learner must beat.

Usage: python benchmarks/open_loop.py [--motions all] [--starts 4]
"""

from __future__ import annotations

import argparse
import functools

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import EvalConfig, evaluate, reference_policy
from common.motion.dataset import load_motions
from common.sim.rewards import TerminationConfig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--motions", nargs="+", default=["all"], help="clips to play (default: the 20 short clips)")
    parser.add_argument("--starts", type=int, default=4, help="episodes per clip in the evaluation protocol")
    parser.add_argument("--threads", type=int, default=2, help="rollout threads")
    args = parser.parse_args()

    humanoid = Humanoid()
    library = load_motions(args.motions, humanoid)
    policy = functools.partial(reference_policy, humanoid=humanoid)

    protocol = evaluate(policy, library, humanoid, EvalConfig(starts_per_clip=args.starts, threads=args.threads))
    print("Evaluation protocol (the learners' judge):")
    print(protocol.table())

    no_grace = EvalConfig(starts_per_clip=1, threads=args.threads, full_horizon=False,
                          termination=TerminationConfig(max_episode_frames=None, grace_frames=0))  # fmt: skip
    fall = evaluate(policy, library, humanoid, no_grace)
    print("\nFrom t = 0 until the head is 25 cm off (no grace period):")
    print(f"{'clip':<20}{'fall frame':>12}{'of':>6}{'MPJPE-g (mm)':>15}")
    for i, name in enumerate(fall.clips):
        length, most = int(fall.episode_length[i, 0]), int(fall.episode_max[i, 0])
        shown = "none" if length >= most and fall.per_clip["survival"][i] == 1.0 else str(length)
        print(f"{name:<20}{shown:>12}{most:>6}{fall.per_clip['mpjpe_g'][i]:>15.1f}")


if __name__ == "__main__":
    main()
