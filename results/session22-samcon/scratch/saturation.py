"""How often a SAMCON path's PD servos are at their torque limits: replayed substep by substep in plain MuJoCo (the
gym's physics), the share of substeps each actuator's force is within 1 % of its forcerange.

    python saturation.py RUN_DIR CLIP
"""

import argparse
from pathlib import Path

import h5py
import mujoco
import numpy as np

from common.character.humanoid import Humanoid
from common.train.config import load_config
from samcon import store
from samcon.config import SamconConfig

parser = argparse.ArgumentParser()
parser.add_argument("run", type=Path)
parser.add_argument("clip")
args = parser.parse_args()
cfg = load_config(SamconConfig, args.run / "config.yaml")
humanoid = Humanoid(cfg.gym.physics)
m = humanoid.model
d = mujoco.MjData(m)
with h5py.File(args.run / store.FILE_NAME, "r") as f:
    g = f["clips"][args.clip]
    targets, start = g["targets"][()], g["start_state"][()]
mujoco.mj_setState(m, d, start, mujoco.mjtState.mjSTATE_FULLPHYSICS)
forces = []
for target in targets:
    d.ctrl[:] = target
    for _ in range(humanoid.physics.substeps):
        mujoco.mj_step(m, d)
        forces.append(d.actuator_force.copy())
forces = np.array(forces)
limit = m.actuator_forcerange[:, 1]
at = np.abs(forces) >= 0.99 * limit
names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(m.nu)]
order = np.argsort(at.mean(0))[::-1]
print(f"{args.clip}: {len(targets)} frames; substeps at the torque limit, by actuator:")
print("  " + ", ".join(f"{names[i]} {100 * at[:, i].mean():.0f}%" for i in order[:10]))
print(f"  any actuator at its limit in {100 * at.any(1).mean():.0f}% of substeps")
