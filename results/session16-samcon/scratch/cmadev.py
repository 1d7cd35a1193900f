"""Session 16's scratch harness: CMA-ES over closed-loop gains on a stored SAMCON walk plan, judged before and after by
the shared evaluator (16 starts, 512 frames).

    .venv/bin/python results/session16-samcon/scratch/cmadev.py RUN/samcon.h5 GENERATIONS nearest|path '{"sigma": 0.1}'

RUN: session 15's walk feedback run (`track-samcon --config configs/samcon/feedback-walk.yaml --set
optimise.generations=0 --motions walk --out RUN`); the JSON holds `optimise:` keys (see samcon.config.OptimiseConfig).
"""

import json
import sys
import time
from dataclasses import replace

import numpy as np

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from common.train.evaluate import EvalConfig, evaluate
from samcon import store
from samcon.config import OptimiseConfig
from samcon.feedback import FeedbackPolicy
from samcon.optimise import optimise_gains


def main() -> None:
    src, generations, anchor = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    keys = json.loads(sys.argv[4]) if len(sys.argv) > 4 else {}
    humanoid = Humanoid()
    library = load_motions(["walk"], humanoid)
    plan = store.load_plans(src, humanoid.physics.control_hz)[0]["walk"]
    if anchor == "path":  # the same gains anchored on the first path alone
        plan = replace(plan, anchor_features=None, anchor_offsets=None, feature_scale=None)
    ev = EvalConfig(starts_per_clip=16, max_frames=512, threads=1)
    t0 = time.time()
    r = evaluate(FeedbackPolicy({"walk": plan}, library, humanoid), library, humanoid, ev).overall
    print(f"before: survival {r['survival']:.3f} len {r['episode_len_ratio']:.3f} g {r['mpjpe_g']:.0f}", flush=True)
    cfg = OptimiseConfig(generations=generations, **keys)
    new, _ = optimise_gains(plan, "walk", library, humanoid, cfg, ev, np.random.default_rng(7), log=sys.stdout)
    minutes = (time.time() - t0) / 60
    r = evaluate(FeedbackPolicy({"walk": new}, library, humanoid), library, humanoid, ev).overall
    print(f"after {generations} generations ({minutes:.1f} min): survival {r['survival']:.3f} "
          f"len {r['episode_len_ratio']:.3f} g {r['mpjpe_g']:.0f}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
