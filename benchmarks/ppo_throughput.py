"""PPO's samples/s against raw MuJoCo physics on the same characters and threads, measured in one run.

Raw: ``mujoco.rollout`` of the config's ``gym.num_envs`` characters for the config's substeps, with fixed controls and
no Python work (as ``benchmarks/gym_throughput.py``): the ceiling of any learner on this machine. PPO: whole iterations
of the configured learner, ``collect()`` (a rollout of ``ppo.rollout_length`` gym steps with the policy, observation,
reward and termination) plus ``update()`` (GAE and the epochs of minibatch steps). Blocks of the two alternate, so
that a busy machine slows both alike; the figure is the ratio of their median rates (issue 14's aim: >= 0.7 with
the machine to itself). Also prints the gym's and the update's shares of a PPO iteration.

    .venv/bin/python benchmarks/ppo_throughput.py                                  # configs/ppo/default.yaml
    .venv/bin/python benchmarks/ppo_throughput.py --set train.torch_threads=2 --repeats 7
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np
import torch
from gym_throughput import raw_block  # this folder: the script's own
from mujoco import rollout

from common.character.humanoid import Humanoid
from common.config import load_config
from common.motion.dataset import load_motions
from common.sim.gym import TrackingGym
from common.train.training import gym_config
from ppo.config import PPOTrackerConfig
from ppo.learner import PPOLearner


def ppo_rate(learner: PPOLearner, iterations: int) -> tuple[float, float, float]:
    """Samples per second of whole PPO iterations, and the seconds spent collecting and updating."""
    samples, collect_s, update_s = 0, 0.0, 0.0
    for _ in range(iterations):
        t0 = time.perf_counter()
        samples += learner.collect()
        t1 = time.perf_counter()
        learner.update()
        collect_s += t1 - t0
        update_s += time.perf_counter() - t1
    return samples / (collect_s + update_s), collect_s, update_s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default="configs/ppo/default.yaml", help="PPO config file")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="config override (repeatable)")  # fmt: skip
    parser.add_argument("--motions", nargs="+", default=None, help="clips (default: the config's)")
    parser.add_argument("--iterations", type=int, default=4, help="PPO iterations per timed block")
    parser.add_argument("--repeats", type=int, default=5, help="alternating raw / PPO block pairs")
    args = parser.parse_args()
    overrides = list(args.overrides) + ([f"train.motions=[{', '.join(args.motions)}]"] if args.motions else [])
    cfg = load_config(PPOTrackerConfig, args.config, overrides)
    torch.manual_seed(cfg.train.seed)
    torch.set_num_threads(max(1, cfg.train.torch_threads))
    humanoid = Humanoid(cfg.gym.physics)
    library = load_motions(list(cfg.train.motions), humanoid)
    learner = PPOLearner(cfg, library, humanoid, np.random.default_rng(cfg.train.seed))
    n, threads = cfg.gym.num_envs, cfg.gym.threads
    # The raw blocks' start: the learner's first state (its gym is the collector's, so a twin with the same seed).
    gym = TrackingGym(gym_config(cfg), library, humanoid)
    res = gym.reset()
    state0 = gym.sim.state.copy()
    gym.close()
    ctrl = np.ascontiguousarray(np.repeat(res.ref_next.qpos[:, None, humanoid.hinge_qpos], humanoid.physics.substeps,
                                          axis=1))  # fmt: skip
    datas = [mujoco.MjData(humanoid.model) for _ in range(max(1, threads))]
    pool = rollout.Rollout(nthread=threads if threads > 1 else 0)
    steps = cfg.ppo.rollout_length * args.iterations
    print(f"{args.config}: {n} characters, {threads} rollout thread(s), {cfg.train.torch_threads} torch thread(s), "
          f"{cfg.ppo.rollout_length}-step rollouts, {args.iterations} iterations per block", flush=True)  # fmt: skip
    try:
        ppo_rate(learner, 2)  # warm-up: first allocations, first update
        raw_block(humanoid, state0, ctrl, 5, pool, datas)
        raws, ppos, collect, update = [], [], 0.0, 0.0
        for k in range(args.repeats):
            raws.append(n * raw_block(humanoid, state0, ctrl, steps, pool, datas))  # character-steps/s
            rate, c, u = ppo_rate(learner, args.iterations)
            ppos.append(rate)
            collect, update = collect + c, update + u
            print(f"block {k + 1}: raw {raws[-1]:8.0f} character-steps/s | PPO {ppos[-1]:8.0f} samples/s", flush=True)
    finally:
        pool.close()
        learner.close()
    raw, ppo = float(np.median(raws)), float(np.median(ppos))
    print(f"median: raw {raw:.0f} character-steps/s, PPO {ppo:.0f} samples/s; PPO/raw {ppo / raw:.3f}; "
          f"of a PPO iteration: gym {collect / (collect + update):.0%}, update {update / (collect + update):.0%}")


if __name__ == "__main__":
    main()
