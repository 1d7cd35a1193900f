"""Probe: iLQR polish (samcon.polish) of one clip's stored open-loop path, judged open loop by the shared evaluator.

    python polish_probe.py RUN_DIR CLIP [JSON overrides of PolishConfig]
"""

import json
import sys
from dataclasses import replace

import h5py
import numpy as np

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from common.train.config import load_config
from common.train.evaluate import evaluate
from samcon.config import PolishConfig, SamconConfig
from samcon.feedback import ClipPlan, open_loop_policy
from samcon.polish import polish
from samcon.search import reference_frames

run, clip = sys.argv[1], sys.argv[2]
over = json.loads(sys.argv[3]) if len(sys.argv) > 3 else {}
no_lqr = over.pop("no_lqr", False)
cfg = load_config(SamconConfig, f"{run}/config.yaml", [])
pcfg = PolishConfig(**{"iterations": 20, **over})
humanoid = Humanoid(cfg.gym.physics)
library = load_motions([clip], humanoid)
with h5py.File(f"{run}/samcon.h5") as f:
    g = f[f"clips/{clip}"]
    start, targets = g["start_state"][()], g["targets"][()]
frames = len(targets)
ref = reference_frames(library, 0, frames)
ref_targets = ref.qpos[1:, humanoid.hinge_qpos]
new, summary = polish(humanoid, start, targets, ref, ref_targets, pcfg, cfg.cost.fall_head_error, clip, sys.stdout,
                      lqr=None if no_lqr else cfg.lqr)
ev = replace(cfg.train.eval, starts_per_clip=1, max_frames=cfg.train.max_frames)
for label, t in (("searched", targets), ("polished", new)):
    plan = ClipPlan(targets=t, bounds=np.array([0, frames]), gain=np.zeros((1, 28, 16)), bias=np.zeros((1, 28)))
    r = evaluate(open_loop_policy({clip: plan}, library, humanoid), library, humanoid, ev)
    print(label, {k: round(float(r.per_clip[k][0]), 2) for k in ("mpjpe_g", "mpjpe_l", "survival")})
if len(sys.argv) > 4:
    np.save(sys.argv[4], new)
