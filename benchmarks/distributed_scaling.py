"""Data-parallel scaling on this machine, and a model of it on a cluster, from figures measured in one run.

For each learner the real training command trains for ``--minutes`` of training clock (evaluation off, compile warm-up
off the clock) in three ways, one after the other on an otherwise idle machine:

- ``whole``: one process with the whole machine (SuperTrack ``policy.concurrent`` with 2 gym threads; PPO 2 gym
  threads), today's fastest single run;
- ``1x1``: one process, one gym thread, one torch thread (a rank's share of a one-core-per-rank layout);
- ``2x1``: ``torchrun --nproc_per_node=2``, each rank one gym thread and one torch thread and the single process's
  sizes (characters, batches): twice the samples and the batch per update (weak scaling, as rsl_rl and ProtoMotions
  size a rank);
- ``2x1-split``: the same with each rank half the single process's sizes, so that an update averages the gradient of
  the same global batch as one process (strong scaling: SuperTrack 2 x 32 characters of which 2 x 2 held back, W
  batch 2 x 128 and policy batch 2 x 64 windows against 64, 4, 256, 128; PPO 2 x 128 characters and minibatches of
  2 x 256).

Rates are taken over the second half of each run's clock (steady state; SuperTrack's policy steps from the first
iteration here, ``policy.start_iteration=0``): learner updates (iterations) per second and samples per second of the
whole run (every rank's). The 2-rank runs also log the gradient all-reduces (``perf/allreduce_*``: calls, seconds and
bytes per iteration; the seconds include waiting for the slower rank). A probe then times bare all-reduces of those
sizes between two ranks of this machine (gloo over loopback, a barrier before each).

The model: a rank per core (or GPU) computes one iteration in t_c (the ``1x1`` run's seconds per iteration), then
makes c all-reduces of S bytes; a ring all-reduce over N ranks takes 2 (N - 1) alpha + 2 (N - 1) / N x S / B on a
network of bandwidth B and per-message latency alpha. Updates/s(N) = 1 / (t_c + c T(N)); samples/s(N) = N x samples
per rank-iteration x updates/s(N). alpha is an assumption, printed with the table (``--latency-us``).

Usage: python benchmarks/distributed_scaling.py [--learners supertrack ppo] [--minutes 2] [--out DIR]
Last line: ``ratios against whole: <learner> <mode> samples <r> updates <r>; ...`` (target >= 1.0 for each).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common.strict_json import parse_json  # noqa: E402

LOCOMOTION = ("walk", "jog", "run", "stealthy_walk", "zombie_walk")
# Training settings of every mode: no evaluation until the end (then a short one), a log line every 10 iterations.
COMMON = ("--set", "train.eval_every_minutes=100000", "--set", "train.eval.starts_per_clip=1",
          "--set", "train.eval.max_frames=30", "--set", "train.log_every=10", "--set", "train.torch_threads=1",
          "--set", "train.checkpoint_every_minutes=100000")  # fmt: skip
ONE_THREAD = ("--set", "gym.threads=1")
MODES = {
    "supertrack": {"whole": (None, ("--set", "policy.concurrent=true", "--set", "gym.threads=2")),
                   "1x1": (None, ONE_THREAD),
                   "2x1": (2, ONE_THREAD),
                   "2x1-split": (2, (*ONE_THREAD, "--set", "gym.num_envs=32", "--set", "buffer.val_envs=2",
                                     "--set", "world_model.batch=128", "--set", "policy.batch=64"))},
    "ppo": {"whole": (None, ("--set", "gym.threads=2")),
            "1x1": (None, ONE_THREAD),
            "2x1": (2, ONE_THREAD),
            "2x1-split": (2, (*ONE_THREAD, "--set", "gym.num_envs=128", "--set", "ppo.minibatch_size=256"))},
}  # fmt: skip
LEARNER_SETTINGS = {"supertrack": ("--set", "policy.start_iteration=0"), "ppo": ()}
NETWORKS_GBIT = (10.0, 100.0)
RANKS = (8, 64, 512)


def train(learner: str, mode: str, minutes: float, motions: list[str], out: Path) -> dict[str, float]:
    """Runs one mode; returns its steady-state rates (second half of the clock) and all-reduce figures."""
    ranks, extra = MODES[learner][mode]
    args = ["-m", f"{learner}.train", "--out", str(out), "--max-minutes", str(minutes), "--motions", *motions,
            *COMMON, *LEARNER_SETTINGS[learner], *extra]  # fmt: skip
    launcher = [] if ranks is None else ["-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={ranks}"]
    env = {k: v for k, v in os.environ.items() if k not in ("WORLD_SIZE", "RANK", "LOCAL_RANK")}
    env.update(OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    start = time.perf_counter()
    done = subprocess.run([sys.executable, *launcher, *args], cwd=ROOT, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{learner} {mode} failed:\n{done.stderr[-3000:]}")
    records = [parse_json(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    logs = [r for r in records if "perf/samples_per_s" in r]
    if len(logs) < 2:
        raise SystemExit(f"{learner} {mode}: {len(logs)} log line(s) in {minutes} min: too short, raise --minutes")
    end = logs[-1]
    mid = next(r for r in logs[:-1] if r["wall_clock_s"] >= 0.5 * end["wall_clock_s"]) \
        if logs[-2]["wall_clock_s"] >= 0.5 * end["wall_clock_s"] else logs[-2]
    seconds = end["wall_clock_s"] - mid["wall_clock_s"]
    half = [r for r in logs if r["iteration"] > mid["iteration"]]
    result = {"updates_per_s": (end["iteration"] - mid["iteration"]) / seconds,
              "samples_per_s": (end["samples"] - mid["samples"]) / seconds,
              "samples_per_iteration": (end["samples"] - mid["samples"]) / (end["iteration"] - mid["iteration"]),
              "iterations": end["iteration"], "wall_s": time.perf_counter() - start}  # fmt: skip
    for key in ("allreduce_calls", "allreduce_s", "allreduce_mb"):
        if half and f"perf/{key}" in half[0]:
            result[key] = sum(r[f"perf/{key}"] for r in half) / len(half)
    return result


def probe(sizes: list[int], repeats: int) -> dict[int, float]:
    """Median seconds of a bare all-reduce of each size (bytes, float32) between two ranks of this machine."""
    env = {k: v for k, v in os.environ.items() if k not in ("WORLD_SIZE", "RANK", "LOCAL_RANK")}
    env.update(OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    with tempfile.TemporaryDirectory() as tmp:
        result = Path(tmp) / "probe.json"
        cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2", __file__,
               "--probe", str(result), "--repeats", str(repeats), "--sizes", *map(str, sizes)]  # fmt: skip
        done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
        if done.returncode != 0:
            raise SystemExit(f"all-reduce probe failed:\n{done.stderr[-3000:]}")
        return {int(k): v for k, v in parse_json(result.read_text()).items()}


def _probe_rank(path: str, sizes: list[int], repeats: int) -> None:
    """One rank of :func:`probe` (run by torchrun)."""
    import numpy as np
    import torch
    import torch.distributed as dist

    dist.init_process_group("gloo")
    out = {}
    for size in sizes:
        buffer = torch.ones(max(1, size // 4))
        times = []
        for _ in range(repeats):
            dist.barrier()
            start = time.perf_counter()
            dist.all_reduce(buffer)
            times.append(time.perf_counter() - start)
        out[size] = float(np.median(times))
    if dist.get_rank() == 0:
        Path(path).write_text(json.dumps(out))
    dist.destroy_process_group()


def ring_seconds(ranks: int, size_bytes: float, gbit: float, latency_s: float) -> float:
    """A ring all-reduce of ``size_bytes`` over ``ranks`` on a ``gbit`` network: 2 (N - 1) latencies plus
    2 (N - 1) / N of the buffer through each link."""
    if ranks < 2:
        return 0.0
    return 2 * (ranks - 1) * latency_s + 2 * (ranks - 1) / ranks * size_bytes * 8 / (gbit * 1e9)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--learners", nargs="+", default=["supertrack", "ppo"], choices=sorted(MODES),
                        help="learners to measure")  # fmt: skip
    parser.add_argument("--minutes", type=float, default=2.0, help="training clock of each mode (min)")
    parser.add_argument("--motions", nargs="+", default=list(LOCOMOTION), help="clips (default: the locomotion set)")
    parser.add_argument("--latency-us", type=float, default=25.0,
                        help="assumed per-message latency of the cluster network in the model (us)")  # fmt: skip
    parser.add_argument("--repeats", type=int, default=50, help="all-reduces per size in the probe")
    parser.add_argument("--out", default=None, help="keep the runs in this folder (default: a temporary one)")
    parser.add_argument("--probe", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--sizes", type=int, nargs="*", default=[], help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.probe is not None:
        _probe_rank(args.probe, args.sizes, args.repeats)
        return

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.out) if args.out else Path(tmp)
        results: dict[str, dict[str, dict[str, float]]] = {}
        for learner in args.learners:
            results[learner] = {}
            for mode in MODES[learner]:
                r = train(learner, mode, args.minutes, args.motions, root / f"{learner}-{mode}")
                results[learner][mode] = r
                print(f"{learner:10s} {mode:5s}: {r['updates_per_s']:7.2f} updates/s  {r['samples_per_s']:9.0f} "
                      f"samples/s  ({r['iterations']} iterations, {r['wall_s']:.0f} s wall)", flush=True)  # fmt: skip
    sizes = {ln: int(round(r["2x1"]["allreduce_mb"] / r["2x1"]["allreduce_calls"] * 1e6))
             for ln, r in results.items()}  # fmt: skip
    probed = probe(sorted(set(sizes.values())), args.repeats)

    print("\nall-reduce per iteration (2 ranks of this machine)")
    print("learner     calls  MB/call  s in training (incl. waiting)  bare s/call (probe)")
    for ln, r in results.items():
        two = r["2x1"]
        print(f"{ln:10s} {two['allreduce_calls']:6.1f} {sizes[ln] / 1e6:8.3f} {two['allreduce_s']:30.4f} "
              f"{probed[sizes[ln]]:20.6f}")  # fmt: skip

    latency = args.latency_us * 1e-6
    print(f"\nmodel: a rank per core, t_c from 1x1, ring all-reduce, latency {args.latency_us:g} us per message")
    header = "learner     network   " + "  ".join(f"{n:>5d} ranks: updates/s  samples/s" for n in RANKS)
    print(header)
    for ln, r in results.items():
        one = r["1x1"]
        t_c, calls = 1.0 / one["updates_per_s"], r["2x1"]["allreduce_calls"]
        per_rank = one["samples_per_iteration"]
        for gbit in NETWORKS_GBIT:
            cells = []
            for n in RANKS:
                ups = 1.0 / (t_c + calls * ring_seconds(n, sizes[ln], gbit, latency))
                cells.append(f"{ups:16.2f} {n * per_rank * ups:10.0f}")
            print(f"{ln:10s} {gbit:5.0f} Gb/s " + "  ".join(cells))

    ratios = []
    for ln, r in results.items():
        whole = r["whole"]
        for mode in ("2x1", "2x1-split"):
            ratios.append(f"{ln} {mode} samples {r[mode]['samples_per_s'] / whole['samples_per_s']:.2f} "
                          f"updates {r[mode]['updates_per_s'] / whole['updates_per_s']:.2f}")  # fmt: skip
    print("\nratios against whole: " + "; ".join(ratios))


if __name__ == "__main__":
    main()
