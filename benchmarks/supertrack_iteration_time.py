"""Iteration time of SuperTrack on this machine: gym vs world-model step vs policy step.

For each config the learner is built, the buffer is warmed up, one untimed iteration runs, then ``--iterations``
timed iterations (collect + update, as the Trainer runs them). Prints seconds per iteration, samples/s and the
share of each part.

    .venv/bin/python benchmarks/supertrack_iteration_time.py                      # default and paper configs
    .venv/bin/python benchmarks/supertrack_iteration_time.py --configs configs/supertrack/default.yaml -n 20
    .venv/bin/python benchmarks/supertrack_iteration_time.py --configs configs/supertrack/default.yaml --eager-too

With ``--eager-too`` each config is also measured with ``world_model.compile`` and ``policy.compile`` off, in the same
run, and the ratio printed (the first compiled step of a run compiles: it is the untimed warm-up iteration here).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from common.config import load_config
from common.humanoid import Humanoid
from common.motion_dataset import load_motions
from supertrack.config import SuperTrackConfig
from supertrack.learner import SuperTrackLearner

DEFAULT_CONFIGS = ("configs/supertrack/default.yaml", "configs/supertrack/paper.yaml")


def measure(config: str, iterations: int, device: str | None, overrides: list[str]) -> dict[str, float]:
    """Mean seconds per iteration of each part, after warm-up."""
    # The policy steps from the first iteration, so that the steady state is timed.
    overrides = ["policy.start_iteration=0", *overrides] + ([f"train.device={device}"] if device else [])
    cfg = load_config(SuperTrackConfig, config, overrides)
    torch.manual_seed(cfg.train.seed)
    torch.set_num_threads(cfg.train.torch_threads)
    humanoid = Humanoid(cfg.gym.physics)
    learner = SuperTrackLearner(
        cfg, humanoid, load_motions(list(cfg.train.motions), humanoid), np.random.default_rng(0)
    )
    try:
        learner.collect()
        learner.update()
        totals = {"gym": 0.0, "world_model": 0.0, "policy": 0.0}
        samples = 0
        start = time.perf_counter()
        for _ in range(iterations):
            t0 = time.perf_counter()
            samples += learner.collect()
            totals["gym"] += time.perf_counter() - t0
            metrics = learner.update()
            totals["world_model"] += metrics["perf/world_model_step_s"]
            totals["policy"] += metrics["perf/policy_step_s"]
        wall = time.perf_counter() - start
    finally:
        learner.close()
    out = {f"{k}_s": v / iterations for k, v in totals.items()}
    out["iteration_s"] = wall / iterations
    out["samples_per_s"] = samples / wall
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--configs", nargs="+", default=list(DEFAULT_CONFIGS), help="config files to measure")
    parser.add_argument("-n", "--iterations", type=int, default=5, help="timed iterations per config")
    parser.add_argument("--device", default=None, help="torch device (default: the config's)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="config override applied to every config (repeatable)")  # fmt: skip
    parser.add_argument("--eager-too", action="store_true", help="also measure each config uncompiled; print the ratio")
    args = parser.parse_args()
    print(f"{'config':<40}{'iteration s':>12}{'samples/s':>11}{'gym':>8}{'W step':>8}{'Pi step':>8}   (shares)")
    eager = ["world_model.compile=false", "policy.compile=false"]
    for config in args.configs:
        variants = [("", args.overrides)] + ([(" eager", [*args.overrides, *eager])] if args.eager_too else [])
        seconds = []
        for label, overrides in variants:
            r = measure(config, args.iterations, args.device, overrides)
            seconds.append(r["iteration_s"])
            parts = r["gym_s"] + r["world_model_s"] + r["policy_s"]
            shares = [r[k] / parts for k in ("gym_s", "world_model_s", "policy_s")]
            row = f"{config + label:<40}{r['iteration_s']:>12.3f}{r['samples_per_s']:>11.0f}"
            print(row + "".join(f"{s:>8.0%}" for s in shares), flush=True)
        if len(seconds) == 2:
            print(f"{'':<40}eager / as configured: {seconds[1] / seconds[0]:.2f}x", flush=True)


if __name__ == "__main__":
    main()
