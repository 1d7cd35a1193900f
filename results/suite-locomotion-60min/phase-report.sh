#!/bin/bash
# Session 33, phase 2: the locomotion suite's report (every final checkpoint re-evaluated, pushes, pictures, the five
# SAMCON oracle runs), after phase 1's training; the same command as the training without --train-only (all six
# runs reused).
set -u
R=/work/runs/s32
PY=/work/main/.venv/bin/python
while pgrep -f phase1.sh > /dev/null; do sleep 10; done
cd /work/wt-s31
export PYTHONPATH=/work/wt-s31
date; echo "locomotion report starts"
$PY benchmarks/compare_trackers.py --suite locomotion --seeds 3 --minutes 60 --parallel 2 --out $R/suite-locomotion \
  --oracle /work/runs/s30/samcon-walk --oracle /work/runs/s30/samcon-jog --oracle /work/runs/s30/samcon-run \
  --oracle /work/runs/s30/samcon-stealthy_walk --oracle /work/runs/s31/samcon-zombie_walk > /work/runs/s33/suite-locomotion-report.log 2>&1
date; echo "locomotion report done"
