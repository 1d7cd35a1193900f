"""A run's learning curve from its ``metrics.jsonl``: per evaluation, the training minutes and samples, the shared
evaluator's figures, and what the training episodes did since the previous evaluation (how long they were, the
share that failed, which termination rule ended them, the mean reward and each reward term).

Reads the file only (no simulation): fast, and the same numbers the run logged. Works for PPO and SuperTrack runs,
which log these under the same keys (:func:`common.sim.collect.chart_metrics`), and for PPO runs from before that
(``charts/mean_reward``, ``charts/episode_fail_rate``); columns a run did not log are left out.

Example::

    python benchmarks/run_curve.py runs/s14/ppo-run
    python benchmarks/run_curve.py runs/s14/ppo-all20 --clips   # plus each clip's failure-rate EMA at the end
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.strict_json import parse_json  # noqa: E402

EVAL = (("eval/mpjpe_g", "MPJPE-g", 1), ("eval/mpjpe_l", "MPJPE-l", 1), ("eval/survival", "surv", 2),
        ("eval/success", "succ", 2))  # fmt: skip
TRAIN = (("charts/episode_length", "ep len", 1), ("charts/terminated_share", "failed", 2),
         ("charts/reward", "reward", 3))  # fmt: skip
# Keys of PPO runs logged before both learners shared one scheme -> today's.
OLD_KEYS = {"charts/mean_reward": "charts/reward", "charts/episode_fail_rate": "charts/terminated_share"}


def read_metrics(path: Path) -> list[dict[str, Any]]:
    """The records of a metrics file, in order. Raises ValueError naming the file and line of a broken record."""
    records = []
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if line.strip():
            try:
                records.append(parse_json(line))
            except json.JSONDecodeError as e:
                raise ValueError(f"{path}:{n}: not a JSON record ({e.msg})") from None
    return records


def curve_rows(records: list[dict[str, Any]]) -> tuple[list[str], list[list[str]]]:
    """One row per evaluation record: its minute and samples, the evaluation's figures, and the mean of every
    training-record key of ``TRAIN``, ``charts/term/*`` and ``reward/*`` over the records since the previous one
    (old key names read as today's)."""
    records = [{OLD_KEYS.get(k, k): v for k, v in r.items()} for r in records]
    train_keys = sorted({k for r in records if "eval/mpjpe_g" not in r for k in r
                         if k.startswith(("charts/term/", "reward/"))})  # fmt: skip
    columns = [(k, name, d) for k, name, d in TRAIN if any(k in r for r in records)]
    columns += [(k, k.removeprefix("charts/term/").removesuffix("_per_1k") + "/1k", 1) for k in train_keys
                if k.startswith("charts/term/")]  # fmt: skip
    columns += [(k, k, 3) for k in train_keys if k.startswith("reward/")]
    header = ["min", "samples", *(name for _, name, _ in EVAL), *(name for _, name, _ in columns)]
    rows, since = [], []
    for r in records:
        if "eval/mpjpe_g" not in r:
            since.append(r)
            continue
        row = [f"{r['wall_clock_s'] / 60:.1f}", f"{r['samples'] / 1e6:.2f}M"]
        row += [f"{r[k]:.{d}f}" if k in r else "-" for k, _, d in EVAL]
        for k, _, d in columns:
            values = [s[k] for s in since if k in s]
            row.append(f"{sum(values) / len(values):.{d}f}" if values else "-")
        rows.append(row)
        since = []
    return header, rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a training run directory (with metrics.jsonl)")
    parser.add_argument("--clips", action="store_true", help="also each clip's failure-rate EMA in the last record")
    args = parser.parse_args(argv)
    path = args.run / "metrics.jsonl"
    if not path.is_file():
        sys.exit(f"error: {path}: no such file (is {args.run} a training run directory?)")
    try:
        records = read_metrics(path)
    except ValueError as e:
        sys.exit(f"error: {e}")
    header, rows = curve_rows(records)
    if not rows:
        sys.exit(f"error: {path}: no evaluation record yet")
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]
    print("  ".join(h.rjust(w) for h, w in zip(header, widths, strict=True)))
    for row in rows:
        print("  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)))
    if args.clips:
        last = {}
        for r in records:
            last.update({k.removeprefix("charts/failure_rate/"): v for k, v in r.items()
                         if k.startswith("charts/failure_rate/")})  # fmt: skip
        print("failure-rate EMA at the end: " + ", ".join(f"{k} {v:.2f}" for k, v in sorted(last.items())))


if __name__ == "__main__":
    main()
