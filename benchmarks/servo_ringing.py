"""Do the PD servos ring at the physics rate? Substep angular velocities under open-loop playback, per setting.

For each setting (hinge armature, substeps, integrator) and clip, the character starts from reference state
initialisation at 12 evenly spaced times and plays the clip open loop (PD targets = the next reference frame) for up
to 60 control steps, until the head leaves its reference height by 25 cm. Printed per setting:
- ``ringing``: mean second difference of every body's world angular velocity from one physics substep to the next,
  |w[k+1] - 2 w[k] + w[k-1]| / 4 (rad/s). A servo oscillating at the physics rate (the sign flipping every
  substep) shows up here; smooth motion gives a small value.
- ``end-vs-mean``: |w at the end of a control step - w averaged over its substeps| (rad/s): how far the state a
  60 Hz learner sees is from the rate at which the body actually turned during the step. A world model that
  integrates the end velocity (semi-implicit Euler) cannot match both.
- open-loop frames up and mean body-position error over the first 30 frames: what the setting costs in tracking.

    .venv/bin/python benchmarks/servo_ringing.py --motions run walk
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common.character.humanoid import Humanoid, PhysicsConfig  # noqa: E402
from common.motion.dataset import load_motions  # noqa: E402

HEAD_RULE_M = 0.25
SETTINGS = {  # name -> (armature kg m^2, substeps, integrator or None for the MJCF's)
    "armature 0.002": (0.002, 8, None),
    "armature 0.005": (0.005, 8, None),
    "armature 0.01 (default)": (0.01, 8, None),
    "armature 0.002, 16 substeps": (0.002, 16, None),
    "armature 0.005, implicit": (0.005, 8, mujoco.mjtIntegrator.mjINT_IMPLICIT),
}


def measure(clip: str, armature: float, substeps: int, integrator: int | None, starts: int,
            frames: int) -> tuple[float, float, float, float]:  # fmt: skip
    """(ringing, end-vs-mean, open-loop frames up, body error over the first 30 frames in m) of one setting."""
    h = Humanoid(PhysicsConfig(substeps=substeps, armature=armature))
    library = load_motions([clip], h)
    m = h.model
    if integrator is not None:
        m.opt.integrator = integrator
    d = mujoco.MjData(m)
    ringing, mismatch, up, err30 = [], [], [], []
    duration = library.num_frames[0] * library.dt
    for t0 in np.linspace(0.0, 0.9 * duration, starts):
        ref = library.query(np.array([0]), np.array([t0]))
        d.qpos[:], d.qvel[:] = ref.qpos[0], ref.qvel[0]
        mujoco.mj_forward(m, d)
        errors = []
        for k in range(frames):
            nxt = library.query(np.array([0]), np.array([t0 + (k + 1) * library.dt]))
            d.ctrl[:] = nxt.qpos[0, h.hinge_qpos]
            w = []
            for _ in range(substeps):
                mujoco.mj_step(m, d)
                mujoco.mj_forward(m, d)  # cvel of the state just reached
                w.append(d.cvel[1:, :3].copy())  # world angular velocity of every body
            w = np.asarray(w)
            ringing.append(np.linalg.norm(w[2:] - 2 * w[1:-1] + w[:-2], axis=-1).mean() / 4)
            mismatch.append(np.linalg.norm(w[-1] - w.mean(0), axis=-1).mean())
            errors.append(np.linalg.norm(d.xpos[1:] - nxt.body_pos[0], axis=-1).mean())
            if abs(d.xpos[h.head_index + 1, 2] - nxt.body_pos[0, h.head_index, 2]) > HEAD_RULE_M:
                break
        up.append(k + 1)
        err30.append(np.mean(errors[:30]))
    return float(np.mean(ringing)), float(np.mean(mismatch)), float(np.mean(up)), float(np.mean(err30))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--motions", nargs="+", default=["run", "walk"], help="bundled clip names")
    parser.add_argument("--starts", type=int, default=12, help="evenly spaced start times per clip")
    parser.add_argument("--frames", type=int, default=60, help="control steps per start at most")
    args = parser.parse_args()
    print(f"{'clip':<8}{'setting':<30}{'ringing':>9}{'end-vs-mean':>13}{'frames up':>11}{'err 30 (mm)':>13}")
    for clip in args.motions:
        for name, (armature, substeps, integrator) in SETTINGS.items():
            r, e, up, err = measure(clip, armature, substeps, integrator, args.starts, args.frames)
            print(f"{clip:<8}{name:<30}{r:>9.2f}{e:>13.2f}{up:>11.1f}{1000 * err:>13.0f}", flush=True)


if __name__ == "__main__":
    main()
