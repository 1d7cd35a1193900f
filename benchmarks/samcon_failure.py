"""Where a SAMCON trajectory fails: per clip of a ``track-samcon`` run, the weighted cost terms of the chosen path
segment by segment up to its first fall, and which bodies are farthest from the reference at that frame.

The trajectory is replayed from its saved start state (bit-exact with the search), so the per-body errors are those
of the trajectory the evaluator scores.

Usage: python benchmarks/samcon_failure.py RUN_DIR [--segments 6]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import h5py
import numpy as np

from common.character.humanoid import Humanoid
from common.character.kinematics import ForwardKinematics
from common.config import load_config
from common.motion.dataset import load_motions
from samcon import store
from samcon.config import SamconConfig
from samcon.cost import COST_TERMS
from samcon.search import reference_frames, replay


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a track-samcon run directory")
    parser.add_argument("--segments", type=int, default=6, help="segments shown before the first fall")
    args = parser.parse_args()
    cfg = load_config(SamconConfig, args.run / "config.yaml")
    humanoid = Humanoid(cfg.gym.physics)
    fk = ForwardKinematics(humanoid)
    with h5py.File(args.run / store.FILE_NAME, "r") as f:
        for name, g in f["clips"].items():
            library = load_motions([name], humanoid)
            # Files written before a term existed lack it: shown as 0.
            terms = {k: g[f"terms/{k}"][()] if f"terms/{k}" in g else np.zeros(len(g["bounds"]) - 1)
                     for k in (*COST_TERMS, "fallen")}  # fmt: skip
            bounds = g["bounds"][()]
            fell = np.flatnonzero(terms["fallen"] > 0)
            last = int(fell[0]) if len(fell) else len(bounds) - 2
            span = f"frames {bounds[last]}-{bounds[last + 1]}"
            where = f"first fall in segment {last} ({span})" if len(fell) else "no fall"
            print(f"== {name}: {where}; weighted cost terms per segment:")
            print("segment " + "".join(f"{k:>13}" for k in COST_TERMS))
            for k in range(max(0, last - args.segments + 1), last + 1):
                print(f"{k:>7} " + "".join(f"{getattr(cfg.cost, t) * terms[t][k]:>13.4g}" for t in COST_TERMS))
            frame = int(bounds[last + 1]) - 1
            states = replay(humanoid, g["start_state"][()], g["targets"][: frame + 1], cfg.gym.max_speed)
            nq, nv = humanoid.nq, humanoid.nv
            sim = fk(states[-1:, 1 : 1 + nq].copy(), states[-1:, 1 + nq : 1 + nq + nv].copy())
            ref = reference_frames(library, 0, frame + 1)[np.array([frame + 1])]
            err = np.linalg.norm(sim.body_pos[0] - ref.body_pos[0], axis=-1)
            worst = np.argsort(err)[::-1][:4]
            head = humanoid.head_index
            dz = 100 * (sim.body_pos[0, head, 2] - ref.body_pos[0, head, 2])
            bodies = ", ".join(f"{humanoid.body_names[b]} {100 * err[b]:.0f} cm" for b in worst)
            print(f"frame {frame + 1}: farthest bodies {bodies}; head height {dz:+.0f} cm")
    fk.close()


if __name__ == "__main__":
    main()
