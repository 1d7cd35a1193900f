"""Scratch: decompose a SAMCON open loop's MPJPE-g into a vertical bias, horizontal root drift and the rest."""
import sys

import numpy as np

from common.character.humanoid import Humanoid
from common.character.kinematics import ForwardKinematics
from common.motion.dataset import load_motions
from samcon import store
from samcon.search import reference_frames, replay, start_state

run = sys.argv[1]
humanoid = Humanoid()
plans, info = store.load_plans(run + "/samcon.h5", humanoid.physics.control_hz)
names = sys.argv[2:] or list(plans)
library = load_motions(names, humanoid)
fk = ForwardKinematics(humanoid)
for name in names:
    c = library.clip_index(name)
    plan = plans[name]
    F = len(plan.targets)
    st = replay(humanoid, start_state(library, humanoid, c), plan.targets)
    nq, nv = humanoid.nq, humanoid.nv
    sim = fk(st[:, 1:1 + nq], st[:, 1 + nq:1 + nq + nv])
    ref = reference_frames(library, c, F)[1:]
    e = sim.body_pos - ref.body_pos  # (F, B, 3)
    g = np.linalg.norm(e, axis=-1).mean() * 1000
    root = e[:, :1, :]
    l = np.linalg.norm(e - root, axis=-1).mean() * 1000
    zb = e[..., 2].mean() * 1000
    horiz = np.linalg.norm(root[:, 0, :2], axis=-1).mean() * 1000
    e_noz = e.copy()
    e_noz[..., 2] -= e[..., 2].mean()
    g_noz = np.linalg.norm(e_noz, axis=-1).mean() * 1000
    # the reference's lowest body origin height vs sim's
    print(f"{name:15s} F={F} g={g:.1f} l={l:.1f} z-bias={zb:+.1f} mm, g without z-bias={g_noz:.1f}, "
          f"root horiz={horiz:.1f}, root z err={root[:, 0, 2].mean() * 1000:+.1f}, "
          f"minutes={info[name]['seconds'] / 60:.1f}")
    q = np.linalg.norm(root[:, 0, :2], axis=-1) * 1000
    idx = np.linspace(0, F - 1, 12).astype(int)
    print("   root horiz mm at", idx.tolist(), np.round(q[idx]).astype(int).tolist())
