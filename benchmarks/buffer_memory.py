"""Memory and throughput of CyclicBuffer at training scale (150,000 frames, N = 256).

Prints the stored-array bytes, the process RSS growth from creating and completely filling the buffer,
the push rate and the sample_windows rates; the last line is ``ratio: <rss growth / array bytes>``
(target <= 1.2). Run: ``.venv/bin/python benchmarks/buffer_memory.py``.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.sim.buffer import CyclicBuffer  # noqa: E402

CAPACITY = 150_000
NUM_ENVS = 256
MEAN_EPISODE_STEPS = 120
BODY_STATE = {"pos": (15, 3), "rot": (15, 4), "lin_vel": (15, 3), "ang_vel": (15, 3)}
FIELDS: dict[str, tuple[tuple[int, ...], str]] = {
    **{f"{prefix}_{name}": (shape, "float32") for prefix in ("sim", "kin") for name, shape in BODY_STATE.items()},
    "pd_targets": ((28,), "float32"),
    "policy_output": ((42,), "float32"),
    "reward": ((), "float32"),
}


def rss_bytes() -> int:
    """Resident set size of this process; statm's second column counts resident pages."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def main() -> None:
    """Build, fill and sample the buffer, printing memory and rates."""
    rng = np.random.default_rng(0)
    batch = {name: rng.standard_normal((NUM_ENVS, *shape)).astype(dtype) for name, (shape, dtype) in FIELDS.items()}
    episode_id = np.arange(NUM_ENVS, dtype=np.int64)
    next_id = NUM_ENVS
    rows = CAPACITY // NUM_ENVS
    # Done flags drawn up front: each step ends an episode with probability 1 / MEAN_EPISODE_STEPS.
    done_all = rng.random((rows, NUM_ENVS)) < 1.0 / MEAN_EPISODE_STEPS
    no_done = np.zeros(NUM_ENVS, dtype=bool)

    before = rss_bytes()
    buf = CyclicBuffer(CAPACITY, NUM_ENVS, FIELDS)
    start = time.perf_counter()
    for step in range(rows):
        done = done_all[step]
        buf.push(**batch, episode_id=episode_id, terminated=done, truncated=no_done)
        # Characters whose episode ended start a new one with a fresh, globally unique id.
        num_done = int(done.sum())
        episode_id = episode_id.copy()
        episode_id[done] = np.arange(next_id, next_id + num_done)
        next_id += num_done
    push_seconds = time.perf_counter() - start
    growth = rss_bytes() - before

    print(f"rows x envs: {buf.rows} x {buf.num_envs} = {len(buf)} frames, {len(FIELDS) + 3} fields")
    print(f"stored-array bytes: {buf.nbytes:,} ({buf.nbytes / 2**20:.1f} MiB)")
    print(f"rss growth: {growth:,} ({growth / 2**20:.1f} MiB)")
    print(f"push rate: {len(buf) / push_seconds:,.0f} frames/s ({rows / push_seconds:,.0f} steps/s)")
    for batch_size, length in ((2048, 8), (1024, 32)):
        repeats = 20
        start = time.perf_counter()
        for _ in range(repeats):
            buf.sample_windows(batch_size, length, rng)
        seconds = (time.perf_counter() - start) / repeats
        print(
            f"sample_windows {batch_size} x {length}: {1.0 / seconds:,.1f} batches/s, "
            f"{batch_size * length / seconds:,.0f} frames/s"
        )
    print(f"ratio: {growth / buf.nbytes:.3f}")


if __name__ == "__main__":
    main()
