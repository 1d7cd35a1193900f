"""What each looping clip's reference asks of the character at its loop seams, with and without the seam bridge.

The library closes a wrap clip's loop in pose (the bend) and, asked for (``seam_bridge``, off by default), in velocity:
the keyframes within ``SEAM_BRIDGE`` seconds either side of the seam are replaced by a cubic Hermite curve across it
(``common/motion/library.py``). This prints, per wrap clip and for the bridge off (0 s) and on, over the first 512
frames: the largest residual force (``studies.samcon.feasibility``: the force on the centre of mass no floor contact
can give, in body weights) within 4 frames of a seam and elsewhere, its mean, the largest frame-to-frame change of
the root's velocity at the seams and elsewhere (m/s), and how far the bridge moved the bodies (the largest per-frame
mean, mm).

Run: ``.venv/bin/python benchmarks/loop_seams.py [MOTIONS ...]`` (default: the 20 bundled clips)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.character.humanoid import Humanoid  # noqa: E402
from common.motion.dataset import resolve_clips  # noqa: E402
from common.motion.library import SEAM_BRIDGE, MotionLibrary  # noqa: E402
from samcon.search import reference_frames  # noqa: E402
from studies.samcon.assist import residual_per_frame  # noqa: E402

FRAMES = 512
NEAR = 4  # frames either side of a seam that count as the seam's


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="loop_seams.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("motions", nargs="*", default=["all"], help="clips or folders (default: all)")
    args = parser.parse_args(argv)
    humanoid = Humanoid()
    weight = humanoid.model.body_subtreemass[1] * 9.81
    print(f"seam bridge off -> on ({SEAM_BRIDGE} s either side); residual force in body weights, first {FRAMES} frames")
    print(f"{'clip':14} {'residual at seams':>17} {'elsewhere':>13} {'mean':>13} {'root dv at seams':>16} "
          f"{'elsewhere':>13} {'moved mm':>8}")  # fmt: skip
    for clip in resolve_clips(args.motions):
        if not clip.loop:
            print(f"{clip.name:14} one-shot: no seam")
            continue
        figures, bodies = [], []
        for bridge in (0.0, SEAM_BRIDGE):
            library = MotionLibrary.from_clips([clip], humanoid, seam_bridge=bridge)
            ref = reference_frames(library, 0, FRAMES)
            residual = np.linalg.norm(residual_per_frame(humanoid, ref.qpos, library.dt, 2), axis=-1) / weight
            cycle = library.num_frames[0] - 1
            near = np.zeros(len(residual), dtype=bool)
            for seam in range(cycle, len(residual), cycle):
                near[max(0, seam - NEAR) : seam + NEAR + 1] = True
            dv = np.linalg.norm(np.diff(ref.qvel[:, :3], axis=0), axis=-1)  # dv[i]: frame i -> i + 1
            near_dv = near[:-1] | near[1:]
            figures.append((residual[near].max(), residual[~near].max(), residual.mean(), dv[near_dv].max(),
                            dv[~near_dv].max()))  # fmt: skip
            bodies.append(ref.body_pos)
        moved = 1000 * np.linalg.norm(bodies[1] - bodies[0], axis=-1).mean(axis=-1).max()
        cols = [f"{a:.2f} -> {b:.2f}" for a, b in zip(*figures, strict=True)]
        print(f"{clip.name:14} {cols[0]:>17} {cols[1]:>13} {cols[2]:>13} {cols[3]:>16} {cols[4]:>13} {moved:8.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
