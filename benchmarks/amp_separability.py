"""Which of the AMP discriminator's features tell a trained policy's motion from the reference's, feature by feature.

A run's deterministic policy plays its clip in the gym (RSI, the gym's rules) and every simulated state is paired
with the reference at the same clip time. Per feature group it prints the mean absolute paired difference over the
reference's own standard deviation across time (about 1 or more: the group alone tells them apart), and it names the
dimensions the reference holds still (std < 1e-3) while the simulation moves them: a discriminator separates those
perfectly, whatever the policy learns.

    python benchmarks/amp_separability.py runs/ppo-walk --motions walk --steps 300
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.character.humanoid import Humanoid  # noqa: E402
from common.motion.dataset import load_motions  # noqa: E402
from common.sim.gym import GymConfig, TrackingGym  # noqa: E402
from ppo.amp_data import AMPFeatures  # noqa: E402
from report.runs import export_module, load_run  # noqa: E402

STILL_STD = 1e-3


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", help="a SuperTrack or PPO run directory")
    parser.add_argument("--motions", nargs="+", default=["walk"], help="clips to play (default: walk)")
    parser.add_argument("--steps", type=int, default=300, help="control steps played (default: 300)")
    parser.add_argument("--envs", type=int, default=16, help="characters (default: 16)")
    args = parser.parse_args(argv)
    run = load_run(args.run)
    humanoid = Humanoid(run.physics())
    library = load_motions(args.motions, humanoid)
    policy = export_module(run.learner).load_eval_policy(run.path, run.checkpoint, humanoid, library)
    gym = TrackingGym(GymConfig(num_envs=args.envs, threads=1, seed=3), library, humanoid)
    features = AMPFeatures(humanoid)
    res = gym.reset()
    sim: dict[str, list[np.ndarray]] = {}
    ref: dict[str, list[np.ndarray]] = {}
    for _ in range(args.steps):
        res = gym.step(policy(res))
        for store, state in ((sim, res.sim), (ref, res.ref)):
            for name, value in features.named(state).items():
                store.setdefault(name, []).append(value.reshape(len(value), -1))
    actuators = [mujoco.mj_id2name(humanoid.model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(humanoid.nu)]
    print(f"{run.label} on {', '.join(args.motions)}: {args.steps} steps x {args.envs} characters")
    print(f"{'group':14s} {'dims':>4s} {'|sim - ref| / ref std (mean, max)':>34s} {'still in ref':>13s}")
    for name in sim:
        s, r = np.concatenate(sim[name]), np.concatenate(ref[name])
        ref_std = r.std(0)
        still = np.flatnonzero((ref_std < STILL_STD) & (s.std(0) >= STILL_STD))
        ratio = np.abs(s - r).mean(0) / np.maximum(ref_std, STILL_STD)
        print(f"{name:14s} {s.shape[1]:4d} {ratio.mean():17.2f} {ratio.max():16.2f} {len(still):13d}")
        if name == "joint_vel" and len(still):
            print("    hinges the reference holds still: " + ", ".join(
                f"{actuators[i]} (sim std {s[:, i].std():.2f} rad/s)" for i in still))  # fmt: skip


if __name__ == "__main__":
    main()
