"""Scratch: the walk feedback plan judged by the shared evaluator with parts of the policy removed."""
import sys
from dataclasses import replace

import numpy as np

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from common.train.evaluate import EvalConfig, evaluate
from samcon import store
from samcon.feedback import FeedbackPolicy

plan_path = sys.argv[1]
starts = int(sys.argv[2]) if len(sys.argv) > 2 else 16
humanoid = Humanoid()
plans, _ = store.load_plans(plan_path, humanoid.physics.control_hz)
library = load_motions(["walk"], humanoid)
p = plans["walk"]
variants = {
    "as stored": p,
    "no ref_gain": replace(p, ref_gain=None),
    "M=0 (anchors' offsets only)": replace(p, ref_gain=None, gain=np.zeros_like(p.gain)),
    "M=0, first path only": replace(p, ref_gain=None, gain=np.zeros_like(p.gain), anchor_features=None,
                                    anchor_offsets=None, feature_scale=None),
    "no offsets at all (reference PD)": replace(p, ref_gain=None, gain=np.zeros_like(p.gain), anchor_features=None,
                                    anchor_offsets=None, feature_scale=None, bias=np.zeros_like(p.bias)),
}
ev = EvalConfig(starts_per_clip=starts, max_frames=512, threads=1)
for k, v in variants.items():
    r = evaluate(FeedbackPolicy({"walk": v}, library, humanoid), library, humanoid, ev)
    o = r.overall
    print(f"{k:36s} survival {o['survival']:.3f} episode {o['episode_len_ratio']:.3f} mpjpe_g {o['mpjpe_g']:.0f}",
          flush=True)
