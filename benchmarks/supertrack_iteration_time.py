"""Iteration time of SuperTrack on this machine: gym vs world-model step vs policy step, with and without collectors.

For each config the learner is built, compiled before timing (``warm_up``, as the Trainer does it off the clock), the
buffer warmed up, one untimed iteration run, then ``--iterations`` timed iterations (collect + update, as the Trainer
runs them). Prints seconds per iteration, samples/s and the share of each part. With ``--processes K`` the config is
also measured with ``collect.processes=K`` (the gym in K worker processes beside the learner) and with no collection
at all (updates only, on the warmed buffer: the learner's own pace), and the run prints

- the learner's iterations/s with the collector against updates only (the issue's target: >= 0.9x), and
- the fresh frames/s the workers delivered, and what they could deliver (frames / the seconds they spent stepping:
  their capacity, which lockstep caps at one block per learner iteration).

    .venv/bin/python benchmarks/supertrack_iteration_time.py                      # default and paper configs
    .venv/bin/python benchmarks/supertrack_iteration_time.py --configs configs/supertrack/default.yaml -n 20
    .venv/bin/python benchmarks/supertrack_iteration_time.py --configs configs/supertrack/default.yaml --processes 1 \\
        --set collect.steps_per_iteration=16                 # the data-rate target: 1,024 fresh frames per iteration
    .venv/bin/python benchmarks/supertrack_iteration_time.py --configs configs/supertrack/default.yaml --eager-too

``--eager-too`` also measures each config with ``world_model.compile`` and ``policy.compile`` off, ``--bf16-too``
with ``world_model.bf16`` and ``policy.bf16`` on, ``--concurrent-too`` with ``policy.concurrent`` on (the policy
step in a second thread beside W's steps: one run on both cores), and prints the ratios.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from common.character.humanoid import Humanoid
from common.config import load_config
from common.motion.dataset import load_motions
from supertrack.config import SuperTrackConfig
from supertrack.learner import SuperTrackLearner

DEFAULT_CONFIGS = ("configs/supertrack/default.yaml", "configs/supertrack/paper.yaml")


def measure(config: str, iterations: int, device: str | None, overrides: list[str],
            updates_only: bool = False) -> dict[str, float]:  # fmt: skip
    """Mean seconds per iteration of each part after warm-up; with ``updates_only`` also the pace of updates alone."""
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
        learner.warm_up()
        learner.collect()
        learner.update()
        totals = {"gym": 0.0, "world_model": 0.0, "policy": 0.0, "collect": 0.0}
        samples = 0
        start = time.perf_counter()
        for _ in range(iterations):
            t0 = time.perf_counter()
            samples += learner.collect()
            totals["gym"] += time.perf_counter() - t0
            metrics = learner.update()
            totals["world_model"] += metrics["perf/world_model_step_s"]
            totals["policy"] += metrics["perf/policy_step_s"]
            totals["collect"] += metrics["perf/collect_s"]
        wall = time.perf_counter() - start
        if updates_only:
            t0 = time.perf_counter()
            for _ in range(iterations):
                learner.update()
            update_s = (time.perf_counter() - t0) / iterations
    finally:
        learner.close()
    out = {f"{k}_s": v / iterations for k, v in totals.items()}
    out["iteration_s"] = wall / iterations
    out["samples_per_s"] = samples / wall
    out["capacity_per_s"] = samples / max(totals["collect"], 1e-9)  # what the collectors' stepping time allows
    if updates_only:
        out["update_only_s"] = update_s
    return out


def _row(label: str, r: dict[str, float]) -> str:
    parts = r["gym_s"] + r["world_model_s"] + r["policy_s"]
    shares = [r[k] / parts for k in ("gym_s", "world_model_s", "policy_s")]
    return f"{label:<48}{r['iteration_s']:>12.3f}{r['samples_per_s']:>11.0f}" + "".join(f"{s:>8.0%}" for s in shares)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--configs", nargs="+", default=list(DEFAULT_CONFIGS), help="config files to measure")
    parser.add_argument("-n", "--iterations", type=int, default=5, help="timed iterations per config")
    parser.add_argument("--device", default=None, help="torch device (default: the config's)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="config override applied to every config (repeatable)")  # fmt: skip
    parser.add_argument("--eager-too", action="store_true", help="also measure each config uncompiled; print the ratio")
    parser.add_argument("--bf16-too", action="store_true", help="also measure each config in bf16; print the ratio")
    parser.add_argument("--concurrent-too", action="store_true",
                        help="also measure each config with policy.concurrent (policy beside W); print the ratio")
    parser.add_argument("--processes", type=int, default=0, metavar="K",
                        help="also measure with K collector processes, against updates only (0: not)")  # fmt: skip
    args = parser.parse_args()
    print(f"{'config':<48}{'iteration s':>12}{'samples/s':>11}{'gym':>8}{'W step':>8}{'Pi step':>8}   (shares)")
    eager = ["world_model.compile=false", "policy.compile=false"]
    bf16 = ["world_model.bf16=true", "policy.bf16=true"]
    for config in args.configs:
        variants = [("", args.overrides)]
        variants += [(" eager", [*args.overrides, *eager])] if args.eager_too else []
        variants += [(" bf16", [*args.overrides, *bf16])] if args.bf16_too else []
        variants += [(" concurrent", [*args.overrides, "policy.concurrent=true"])] if args.concurrent_too else []
        first = 0.0
        for label, overrides in variants:
            base = measure(config, args.iterations, args.device, ["collect.processes=0", *overrides],
                           updates_only=args.processes > 0)  # fmt: skip
            print(_row(config + label, base), flush=True)
            first = first or base["iteration_s"]  # the first variant is the config as given
            if label:
                print(f"{'':<48}{label.strip()} / as configured: {base['iteration_s'] / first:.2f}x", flush=True)
            if args.processes > 0:
                k = args.processes
                r = measure(config, args.iterations, args.device, [f"collect.processes={k}", *overrides])
                print(_row(f"{config}{label} processes={k}", r), flush=True)
                print(f"{'':<48}learner: {1 / r['iteration_s']:.2f} iterations/s with {k} collector(s), "
                      f"{1 / base['update_only_s']:.2f} updating only "
                      f"({base['update_only_s'] / r['iteration_s']:.2f}x), {1 / base['iteration_s']:.2f} collecting "
                      f"in process; fresh frames {r['samples_per_s']:.0f}/s, collector capacity "
                      f"{r['capacity_per_s']:.0f}/s", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
