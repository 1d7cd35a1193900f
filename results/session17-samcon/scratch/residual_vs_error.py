"""Scratch: a SAMCON open loop's per-frame body error next to its reference's residual force (feasibility)."""
import sys

import numpy as np

from common.character.humanoid import Humanoid
from common.character.kinematics import ForwardKinematics
from common.motion.dataset import load_motions
from samcon import feasibility as fz
from samcon import store
from samcon.search import cycle_frames, reference_frames, replay, start_state

humanoid = Humanoid()
run = sys.argv[1]
plans, _ = store.load_plans(run + "/samcon.h5", humanoid.physics.control_hz)
for name in sys.argv[2:]:
    library = load_motions([name], humanoid)
    plan = plans[name]
    F = len(plan.targets)
    st = replay(humanoid, start_state(library, humanoid, 0), plan.targets)
    nq, nv = humanoid.nq, humanoid.nv
    fk = ForwardKinematics(humanoid)
    sim = fk(st[:, 1:1+nq], st[:, 1+nq:1+nq+nv])
    ref = reference_frames(library, 0, F)[1:]
    err = np.linalg.norm(sim.body_pos - ref.body_pos, axis=-1).mean(axis=1) * 1000  # frame f+1
    step = 2
    q, v = fz.clip_reference(humanoid, library, 0, step)
    r = fz.measure(humanoid, q, v, library.dt, step).residual  # clip frames step..
    cyc = cycle_frames(library, 0)
    res = np.zeros(F)
    for f in range(F):
        k = (f + 1) % cyc if cyc else f + 1
        j = k - step
        res[f] = r[j] if 0 <= j < len(r) else 0.0
    # residual in the 30 frames before each frame
    win = np.array([res[max(0, f - 30):f + 1].max() for f in range(F)])
    hi = win > 0.3
    print(f"{name}: MPJPE-g {err.mean():.0f} mm; frames with residual > 0.3 BW in the last 0.5 s: {hi.mean():.0%}, "
          f"error there {err[hi].mean() if hi.any() else float('nan'):.0f} mm, elsewhere {err[~hi].mean():.0f} mm; "
          f"corr(err, max residual last 0.5 s) {np.corrcoef(err, win)[0, 1]:.2f}")
    idx = np.arange(0, F, max(1, F // 16))
    print("   frame", idx.tolist())
    print("   err mm", np.round(err[idx]).astype(int).tolist())
    print("   resid", np.round(res[idx], 2).tolist())
