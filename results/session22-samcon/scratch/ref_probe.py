"""Probe: iLQR (samcon.polish, the whole path at once) on a clip's first F frames from the reference's own targets
(no search), against the plain reference targets, judged open loop by the shared evaluator.

    python ref_probe.py CLIP F [JSON overrides of PolishConfig]
"""

import json
import sys
from dataclasses import replace

import numpy as np

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from common.train.config import load_config
from common.train.evaluate import evaluate
from samcon.config import PolishConfig, SamconConfig
from samcon.feedback import ClipPlan, open_loop_policy
from samcon.polish import polish
from samcon.search import reference_frames, start_state

clip, frames = sys.argv[1], int(sys.argv[2])
over = json.loads(sys.argv[3]) if len(sys.argv) > 3 else {}
cfg = load_config(SamconConfig, "configs/samcon/polish.yaml", [f"train.max_frames={frames}"])
pcfg = PolishConfig(**{"iterations": 40, "tolerance": 0.0, "alphas": (1.0, 0.5, 0.25, 0.1, 0.03, 0.01, 0.003), **over})
humanoid = Humanoid(cfg.gym.physics)
library = load_motions([clip], humanoid)
ref = reference_frames(library, 0, frames)
targets = ref.qpos[1:, humanoid.hinge_qpos]
start = start_state(library, humanoid, 0)
new, summary = polish(humanoid, start, targets, ref, targets, pcfg, cfg.cost.fall_head_error, clip, sys.stdout)
ev = replace(cfg.train.eval, starts_per_clip=1, max_frames=frames)
for label, t in (("reference targets", targets), ("polished", new)):
    plan = ClipPlan(targets=t, bounds=np.array([0, frames]), gain=np.zeros((1, 28, 16)), bias=np.zeros((1, 28)))
    r = evaluate(open_loop_policy({clip: plan}, library, humanoid), library, humanoid, ev)
    print(clip, frames, label, {k: round(float(r.per_clip[k][0]), 2) for k in ("mpjpe_g", "mpjpe_l", "survival")})
