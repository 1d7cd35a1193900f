"""Where a SAMCON path's open-loop error lies: per 64-frame block, MPJPE-g and -l, the root's horizontal and vertical
error, and the bodies with the largest mean error over the path (replayed from its saved start, bit-exact).

    python errors.py RUN_DIR CLIP [--seam-bridge S]   (S: the library's seam bridge the run was made with: 0.1 for
                                                       session 22's bridged runs; default 0, the library's)
"""

import argparse
from pathlib import Path

import h5py
import numpy as np

from common.character.humanoid import Humanoid
from common.character.kinematics import ForwardKinematics
from common.motion.dataset import resolve_clips
from common.motion.library import MotionLibrary
from common.train.config import load_config
from samcon import store
from samcon.config import SamconConfig
from samcon.search import reference_frames, replay

parser = argparse.ArgumentParser()
parser.add_argument("run", type=Path)
parser.add_argument("clip")
parser.add_argument("--seam-bridge", type=float, default=0.0)
args = parser.parse_args()
cfg = load_config(SamconConfig, args.run / "config.yaml")
humanoid = Humanoid(cfg.gym.physics)
library = MotionLibrary.from_clips(resolve_clips([args.clip]), humanoid, seam_bridge=args.seam_bridge)
with h5py.File(args.run / store.FILE_NAME, "r") as f:
    g = f["clips"][args.clip]
    targets = g["targets"][()]
    states = replay(humanoid, g["start_state"][()], targets, cfg.gym.max_speed)  # after every step
nq, nv = humanoid.nq, humanoid.nv
fk = ForwardKinematics(humanoid)
sim = fk(states[:, 1 : 1 + nq].copy(), states[:, 1 + nq : 1 + nq + nv].copy())
fk.close()
ref = reference_frames(library, 0, len(targets))[1:]
err = np.linalg.norm(sim.body_pos - ref.body_pos, axis=-1)  # (F, B)
root_s, root_r = sim.body_pos[:, :1], ref.body_pos[:, :1]
local = np.linalg.norm((sim.body_pos - root_s) - (ref.body_pos - root_r), axis=-1)
print(f"{args.clip}: {len(targets)} frames, MPJPE-g {1000 * err.mean():.1f} mm, -l {1000 * local.mean():.1f} mm")
for s in range(0, len(targets), 64):
    b = slice(s, s + 64)
    dxy = np.linalg.norm(root_s[b, 0, :2] - root_r[b, 0, :2], axis=-1).mean()
    dz = (root_s[b, 0, 2] - root_r[b, 0, 2]).mean()
    g, loc = 1000 * err[b].mean(), 1000 * local[b].mean()
    print(f"  frames {s:3d}-{min(s + 64, len(targets)):3d}: MPJPE-g {g:6.1f}  -l {loc:6.1f}"
          f"  root horizontal {1000 * dxy:6.1f}  root height {1000 * dz:+6.1f} mm")
order = np.argsort(err.mean(0))[::-1]
print("  bodies, mean error (mm):", ", ".join(f"{humanoid.body_names[i]} {1000 * err[:, i].mean():.0f}" for i in order))
