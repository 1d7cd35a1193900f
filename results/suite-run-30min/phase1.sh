#!/bin/bash
# Session 31, phase 1: the run suite's training (3 seeds x 30 min, two runs at a time on one core each, nothing else
# on the machine), then its report with the SAMCON oracle of session 30 (run), beside the SAMCON jump search; then the
# zombie_walk search.
set -u
R=/work/runs/s31
PY=/work/main/.venv/bin/python
cd /work/wt-s31
export PYTHONPATH=/work/wt-s31
date; echo "run suite training starts"
$PY benchmarks/compare_trackers.py --suite run --seeds 3 --minutes 30 --parallel 2 --train-only --out $R/suite-run > $R/suite-run.log 2>&1
date; echo "run suite training done"
samcon() { $PY -m samcon.track --config oracle --motions $1 --out $R/samcon-$1 > $R/samcon-$1.log 2>&1; date; echo "samcon $1 done"; }
( $PY benchmarks/compare_trackers.py --suite run --seeds 3 --minutes 30 --parallel 2 --oracle /work/runs/s30/samcon-run --out $R/suite-run > $R/suite-run-report.log 2>&1
  date; echo "run report done"
  samcon zombie_walk ) &
( samcon jump ) &
wait
date; echo "phase 1 done"
