"""Does the root force's central difference in samcon.lqr.linearise depend on what its scratch MjData did before?
MuJoCo's mjSTATE_FULLPHYSICS leaves out the solver's warm start.

    python warmstart.py   (warmstart.txt)
"""

import mujoco
import numpy as np

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from samcon.lqr import _force_response, nominal_states
from samcon.search import reference_frames, start_state

humanoid = Humanoid()
library = load_motions(["roll"], humanoid)
targets = reference_frames(library, 0, 6).qpos[1:, humanoid.hinge_qpos]
states = nominal_states(humanoid, start_state(library, humanoid, 0), targets)
m = humanoid.model
force = np.zeros(m.nv)
force[2] = 300.0  # N up at the root
fresh = _force_response(humanoid, mujoco.MjData(m), states[3], targets[3], force, 2)
used = mujoco.MjData(m)
_force_response(humanoid, used, states[1], targets[1], force, 0)  # an earlier call leaves its warm start behind
reused = _force_response(humanoid, used, states[3], targets[3], force, 2)
print("max |fresh - reused|", np.abs(fresh - reused).max(), "max |fresh|", np.abs(fresh).max())
print("FULLPHYSICS includes WARMSTART:", bool(mujoco.mjtState.mjSTATE_FULLPHYSICS & mujoco.mjtState.mjSTATE_WARMSTART))
