"""Session 16's scratch diagnosis: how a stored SAMCON walk feedback plan fails, from 32 evenly spread reference starts
(the feature deviations from the reference before each failure, and their growth over time).

    .venv/bin/python results/session16-samcon/scratch/faildiag.py RUN/samcon.h5
"""

import sys

import numpy as np

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from common.sim.gym import GymConfig, TrackingGym
from common.train.evaluate import EvalConfig
from samcon import store
from samcon.cost import FEATURE_NAMES, feedback_features
from samcon.feedback import FeedbackPolicy


def main() -> None:
    humanoid = Humanoid()
    library = load_motions(["walk"], humanoid)
    plans = store.load_plans(sys.argv[1], humanoid.physics.control_hz)[0]
    n, frames = 32, 400
    times = np.floor((np.arange(n) + 0.5) * 76 / n) * library.dt
    config = GymConfig(num_envs=n, threads=1, seed=0, physics=humanoid.physics, termination=EvalConfig().termination)
    gym = TrackingGym(config, library, humanoid)
    policy = FeedbackPolicy(plans, library, humanoid)
    result = gym.reset(clips=np.zeros(n, dtype=np.int64), times=times)
    history, alive, fail = [], np.ones(n, dtype=bool), np.full(n, frames)
    for t in range(frames):
        result = gym.step(policy(result), autoreset=False)
        history.append(feedback_features(humanoid, result.final_sim, result.final_ref))
        fail[alive & result.terminated] = t
        alive &= ~result.terminated
    history = np.stack(history)
    print("fail frames", sorted(fail.tolist()))
    fell = np.flatnonzero(fail < frames)
    for name in ("root_tilt_x", "root_tilt_y", "root_vel_x", "root_vel_y", "root_height"):
        j = FEATURE_NAMES.index(name)
        at30 = history[np.maximum(0, fail[fell] - 30), fell, j]
        at10 = history[np.maximum(0, fail[fell] - 10), fell, j]
        print(f"{name}: 30 frames before the fall mean {at30.mean():.3f} mean|.| {np.abs(at30).mean():.3f}; "
              f"10 before {at10.mean():.3f} {np.abs(at10).mean():.3f}")  # fmt: skip
    for t in (10, 30, 60, 90, 120, 150):
        up = fail > t
        med = np.median(np.abs(history[t, up]), axis=0)
        print(f"frame {t}: {up.sum()} up; median |deviation| roll {med[1]:.3f} pitch {med[2]:.3f} "
              f"forward vel {med[4]:.3f} lateral vel {med[5]:.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
