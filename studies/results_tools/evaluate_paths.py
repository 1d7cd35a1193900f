"""The open-loop paths of a ``samcon.assist --paths`` file, judged by the shared evaluator itself: each clip's path of
one stage played from the clip's start (one episode, t = 0, the evaluator's full-horizon protocol) with no root
force, as ``compare-trackers`` judges a SAMCON run's open-loop trajectory. Only meaningful for a stage made without
help (``--then-search ... 0:0``): the evaluator applies none.

    python studies/results_tools/evaluate_paths.py results/samcon-study-root-assist/search-anew/cont-cartwheel.npz \
        then_search_1
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from common.character.humanoid import Humanoid  # noqa: E402
from common.evaluation.evaluate import EvalConfig, evaluate  # noqa: E402
from common.motion.dataset import load_motions  # noqa: E402
from samcon.feedback import ClipPlan, open_loop_policy  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("paths", help="a samcon.assist --paths file")
    parser.add_argument("stage", help="the stage to judge, e.g. then_search_1")
    parser.add_argument("--max-frames", type=int, default=512, help="the evaluator's horizon (default: 512)")
    args = parser.parse_args(argv)
    saved = np.load(args.paths)
    clips = sorted({key.split("/")[0] for key in saved.files})
    humanoid = Humanoid()
    library = load_motions(clips, humanoid)
    plans = {}
    for name in library.names:
        targets = saved[f"{name}/{args.stage}"]
        plans[name] = ClipPlan(targets, np.array([0, len(targets)]), np.zeros((1, humanoid.nu, 16)),
                               np.zeros((1, humanoid.nu)))  # fmt: skip
    ev = EvalConfig(starts_per_clip=1, max_frames=args.max_frames, threads=1)
    result = evaluate(open_loop_policy(plans, library, humanoid), library, humanoid, ev)
    for c, name in enumerate(library.names):
        print(
            f"{name} ({args.stage}, {len(plans[name].targets)} frames): MPJPE-g {result.per_clip['mpjpe_g'][c]:.1f} "
            f"mm, MPJPE-l {result.per_clip['mpjpe_l'][c]:.1f} mm, survival {result.per_clip['survival'][c]:.2f}"
        )


if __name__ == "__main__":
    main()
