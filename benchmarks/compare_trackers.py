"""One-command comparison: train SuperTrack and PPO on the same clip(s) for the same wall-clock, then report.

Each (seed, learner) run trains in its own process, one after the other, so that every method gets the whole machine
for the same training wall-clock (``--minutes``; evaluation time excluded, as in ``common.training``). Then
``compare-trackers`` re-evaluates every final checkpoint on one protocol and writes the report; with ``--seeds N``
the report also shows mean ± std over seeds.

The default (``--minutes 12``, one seed) finishes in about 30 minutes on a 2-core CPU: 2 x 12 minutes of training plus
the periodic and final evaluations and the report.

Run: ``.venv/bin/python benchmarks/compare_trackers.py --motions walk --minutes 12 --out runs/compare-walk``
Smoke test: ``.venv/bin/python benchmarks/compare_trackers.py --debug --minutes 0.2 --out /tmp/compare-smoke``
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from report.compare import main as compare_main  # noqa: E402

LEARNERS = {"supertrack": "supertrack.train", "ppo": "ppo.train"}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="compare_trackers.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, help="output directory (runs/ and report/ inside)")
    parser.add_argument("--motions", nargs="+", default=["walk"], help="clip(s) both methods train and are judged on")
    parser.add_argument("--minutes", type=float, default=12.0, help="training wall-clock per run, minutes")
    parser.add_argument("--seeds", type=int, default=1, help="seeds per method (0 .. N-1), for the spread")
    parser.add_argument("--evals", type=int, default=8, help="evaluations logged per run (learning-curve points)")
    parser.add_argument("--debug", action="store_true", help="the tiny debug configs (tests and smoke runs)")
    parser.add_argument("--starts", type=int, default=None, help="start frames per clip of the final evaluation")
    parser.add_argument("--no-render", action="store_true", help="skip the filmstrips")
    return parser


def train(learner: str, seed: int, args: argparse.Namespace, out: Path) -> None:
    """Trains one run in a child process (a fresh interpreter: no state shared between methods)."""
    preset = "debug" if args.debug else "default"
    config = ROOT / "configs" / learner / f"{preset}.yaml"
    cmd = [sys.executable, "-m", LEARNERS[learner], "--config", str(config), "--out", str(out), "--seed", str(seed),
           "--max-minutes", str(args.minutes), "--motions", *args.motions]  # fmt: skip
    if args.debug:
        # The debug presets stop after a few iterations; the wall-clock budget must rule instead.
        cmd += ["--set", "train.max_iterations=null"]
    else:
        # Evaluate at fixed shares of the budget so both methods get the same number of curve points.
        cmd += ["--set", f"train.eval_every_minutes={args.minutes / max(args.evals, 1)}"]
    print(f"[{time.strftime('%H:%M:%S')}] {learner} seed {seed}: {' '.join(cmd)}", flush=True)
    subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    out = Path(args.out)
    run_dirs = []
    for seed in range(args.seeds):
        for learner in LEARNERS:
            run_dir = out / "runs" / f"{learner}-s{seed}"
            train(learner, seed, args, run_dir)
            run_dirs.append(str(run_dir))
    report_args = [*run_dirs, "--out", str(out / "report"), "--motions", *args.motions]
    if args.starts is not None:
        report_args += ["--starts", str(args.starts)]
    if args.no_render:
        report_args.append("--no-render")
    compare_main(report_args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
