"""Gym throughput against raw MuJoCo on the same model, substeps and threads.

Raw: ``mujoco.rollout`` of N characters for ``substeps`` physics steps with fixed controls and no Python work.
Gym: ``TrackingGym.step`` with PD targets = reference + noise (kinematics, reference queries, rewards, termination,
resets). Blocks of both alternate within one run, so that a busy machine slows both alike; the ratio of their
median rates is the figure (target >= 0.9 at N = 256; about 0.83 now: docs/gym-and-judge.md, "Speed", has what
the gym's share costs and why it stays below 0.9 on 2 cores).

Usage: python benchmarks/gym_throughput.py [--envs 64 256] [--steps 60] [--repeats 5] [--threads 2]
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np
from mujoco import rollout

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from common.sim.gym import GymConfig, TrackingGym
from common.sim.rewards import TerminationConfig


def raw_block(humanoid: Humanoid, state0: np.ndarray, ctrl: np.ndarray, steps: int, pool: rollout.Rollout,
              datas: list[mujoco.MjData]) -> float:  # fmt: skip
    """Control steps per second of bare rollouts (state carried over from step to step)."""
    n, substeps = ctrl.shape[0], ctrl.shape[1]
    state = state0.copy()
    out = np.zeros((n, substeps, state.shape[1]))
    sensor = np.zeros((n, substeps, 0))
    models = [humanoid.model] * n
    start = time.perf_counter()
    for _ in range(steps):
        pool.rollout(models, datas, state, ctrl, state=out, sensordata=sensor, nstep=substeps, skip_checks=True)
        state[:] = out[:, -1]
    return steps / (time.perf_counter() - start)


def gym_block(gym: TrackingGym, steps: int, rng: np.random.Generator) -> float:
    noise = rng.normal(scale=0.1, size=(steps, gym.num_envs, gym.nu))
    start = time.perf_counter()
    for k in range(steps):
        gym.step(gym.reference_targets() + noise[k])
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", type=int, nargs="+", default=[64, 256], help="numbers of characters N")
    parser.add_argument("--steps", type=int, default=60, help="control steps per timed block")
    parser.add_argument("--repeats", type=int, default=5, help="alternating raw/gym block pairs per N")
    parser.add_argument("--threads", type=int, default=2, help="rollout threads for both")
    parser.add_argument("--motions", nargs="+", default=["all"], help="clips the characters track")
    args = parser.parse_args()

    humanoid = Humanoid()
    library = load_motions(args.motions, humanoid)
    print(f"model: {humanoid.num_bodies} bodies, nq {humanoid.nq}, control {humanoid.physics.control_hz:g} Hz, "
          f"{humanoid.physics.substeps} substeps, threads {args.threads}, clips {library.num_clips}")  # fmt: skip
    ratio = float("nan")
    for n in args.envs:
        gym = TrackingGym(GymConfig(num_envs=n, threads=args.threads, termination=TerminationConfig()), library,
                          humanoid)  # fmt: skip
        res = gym.reset()
        state0 = gym.sim.state.copy()
        ctrl = np.repeat(res.ref_next.qpos[:, None, humanoid.hinge_qpos], humanoid.physics.substeps, axis=1)
        ctrl = np.ascontiguousarray(ctrl)
        datas = [mujoco.MjData(humanoid.model) for _ in range(max(1, args.threads))]
        pool = rollout.Rollout(nthread=args.threads if args.threads > 1 else 0)
        rng = np.random.default_rng(0)
        gym_block(gym, 5, rng)
        raw_block(humanoid, state0, ctrl, 5, pool, datas)
        raw_rates, gym_rates = [], []
        for _ in range(args.repeats):
            raw_rates.append(raw_block(humanoid, state0, ctrl, args.steps, pool, datas))
            gym_rates.append(gym_block(gym, args.steps, rng))
        pool.close()
        gym.close()
        raw, g = float(np.median(raw_rates)), float(np.median(gym_rates))
        ratio = g / raw
        print(f"N = {n:4d}: raw {raw:7.1f} steps/s ({raw * n:8.0f} character-steps/s) | gym {g:7.1f} steps/s "
              f"({g * n:8.0f} character-steps/s) | gym/raw {ratio:.3f}")  # fmt: skip
    print(f"ratio: {ratio:.3f}")


if __name__ == "__main__":
    main()
