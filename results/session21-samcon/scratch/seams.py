"""Where a looped reference's residual force peaks, and its centre of mass's velocity either side of the loop seams.

    python seams.py CLIP...   (seams.txt: dance_a cartwheel zombie_walk dance_spin)
"""

import sys

import numpy as np

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from samcon.assist import residual_per_frame
from samcon.feasibility import com_and_clearance
from samcon.search import reference_frames

humanoid = Humanoid()
weight = humanoid.model.body_subtreemass[1] * 9.81
for clip in sys.argv[1:]:
    library = load_motions([clip], humanoid)
    ref = reference_frames(library, 0, 512)
    residual = np.linalg.norm(residual_per_frame(humanoid, ref.qpos, library.dt, 2), axis=-1) / weight
    cycle = library.num_frames[0] - 1
    print(f"{clip}: cycle {cycle} frames, residual mean {residual.mean():.3f} body weights, frames above 0.4:",
          np.flatnonzero(residual > 0.4).tolist())
    velocity = np.diff(com_and_clearance(humanoid, ref.qpos)[0], axis=0) / library.dt
    for seam in range(cycle, 512 - 3, cycle)[:2]:
        before, after = velocity[seam - 3 : seam], velocity[seam : seam + 3]
        print(f"  seam at {seam}: centre-of-mass velocity (m/s) before", np.round(before, 2).tolist(), "after",
              np.round(after, 2).tolist())
