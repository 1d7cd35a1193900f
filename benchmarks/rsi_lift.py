"""Clips that start inside the floor: does lifting the start state (``rsi_lift``) change what a tracker gets?

Some clips put a foot 3-13 cm below the ground at some frames. For every clip, from ``--starts`` evenly spaced
start frames, this prints how deep the reference's lowest point is at the start, and what open-loop playback (PD
targets = the next reference frame) does from there with and without the lift: the pelvis's change of angular
velocity over the first control step (the kick a start inside the floor gives), the frames until the head is 25 cm
off its reference height (no grace period), and MPJPE-g over the first 30 frames.

    .venv/bin/python benchmarks/rsi_lift.py --motions all --starts 8
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common.character.humanoid import BodyGeometry, Humanoid  # noqa: E402
from common.evaluation.evaluate import reference_policy  # noqa: E402
from common.evaluation.metrics import mpjpe_global_mm  # noqa: E402
from common.motion.dataset import load_motions  # noqa: E402
from common.sim.gym import GymConfig, TrackingGym  # noqa: E402
from common.sim.rewards import TerminationConfig  # noqa: E402

FRAMES = 120


def play(library, humanoid: Humanoid, clips: np.ndarray, times: np.ndarray, lift: bool,
         threads: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Per episode: pelvis |delta w| over the first step (rad/s), frames up, MPJPE-g over the first 30 frames."""
    rule = TerminationConfig(max_episode_frames=None, grace_frames=0, head_height_error=0.25)
    gym = TrackingGym(GymConfig(num_envs=len(clips), threads=threads, rsi_lift=lift, termination=rule,
                                physics=humanoid.physics), library, humanoid)  # fmt: skip
    try:
        res = gym.reset(clips=clips, times=times)
        w0 = res.sim.body_angvel[:, humanoid.root_index].copy()
        up = np.full(len(clips), FRAMES)
        alive = np.ones(len(clips), dtype=bool)
        err = []
        for t in range(FRAMES):
            res = gym.step(reference_policy(res, humanoid), autoreset=False)
            if t == 0:
                kick = np.linalg.norm(res.final_sim.body_angvel[:, humanoid.root_index] - w0, axis=-1)
            if t < 30:
                err.append(mpjpe_global_mm(res.final_sim.body_pos, res.final_ref.body_pos))
            up[alive & res.terminated] = t + 1
            alive &= ~res.terminated
    finally:
        gym.close()
    return kick, up, np.mean(err, axis=0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--motions", nargs="+", default=["all"], help="clips (default: the 20 short clips)")
    parser.add_argument("--starts", type=int, default=8, help="evenly spaced start frames per clip")
    parser.add_argument("--threads", type=int, default=2, help="rollout threads")
    args = parser.parse_args()
    humanoid = Humanoid()
    library = load_motions(args.motions, humanoid)
    k = args.starts
    clips = np.repeat(np.arange(library.num_clips), k)
    frac = np.tile(np.arange(k) / k, library.num_clips)
    times = np.floor(frac * (library.num_frames[clips] - FRAMES // 4)).clip(0) * library.dt
    ref = library.query(clips, times)
    depth = -BodyGeometry(humanoid).lowest_points(ref.body_pos, ref.body_rot).min(axis=-1)  # > 0: inside
    flat, lifted = (play(library, humanoid, clips, times, lift, args.threads) for lift in (False, True))
    print(f"{'clip':<18}{'inside (cm)':>12}{'starts in':>10}{'kick flat/lift':>16}{'frames up flat/lift':>21}"
          f"{'MPJPE-g 30 flat/lift':>22}")  # fmt: skip
    rows = []
    for c, name in enumerate(library.names):
        e = clips == c
        inside = depth[e] > 0.005
        row = (depth[e].max() * 100, inside.sum(), flat[0][e].mean(), lifted[0][e].mean(), flat[1][e].mean(),
               lifted[1][e].mean(), flat[2][e].mean(), lifted[2][e].mean())  # fmt: skip
        rows.append(row)
        print(f"{name:<18}{row[0]:>12.1f}{f'{row[1]}/{k}':>10}{row[2]:>9.2f}/{row[3]:<6.2f}{row[4]:>13.1f}/{row[5]:<7.1f}"
              f"{row[6]:>14.0f}/{row[7]:<7.0f}")  # fmt: skip
    m = np.mean(rows, axis=0)
    print(f"{'mean':<18}{m[0]:>12.1f}{'':>10}{m[2]:>9.2f}/{m[3]:<6.2f}{m[4]:>13.1f}/{m[5]:<7.1f}"
          f"{m[6]:>14.0f}/{m[7]:<7.0f}")  # fmt: skip
    print("kick: |pelvis angular velocity change| over the first control step (rad/s); frames up: until the head is "
          f"25 cm off (at most {FRAMES}); 'starts in': starts whose lowest point is more than 5 mm below the floor")


if __name__ == "__main__":
    main()
