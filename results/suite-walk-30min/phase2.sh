#!/bin/bash
# Session 30, phase 2: after the walk suite's training, the SAMCON oracle per clip (oracle.yaml), two processes side
# by side (one core each); the walk suite's report (with its oracle) as soon as walk's search is done.
set -u
R=/work/runs/s30
PY=/work/main/.venv/bin/python
while pgrep -f "compare_trackers.py --suite walk" >/dev/null; do sleep 20; done
cd /work/wt-s30 && git checkout -q --detach e5f1839
export PYTHONPATH=/work/wt-s30
date; echo "phase 2 starts"
samcon() { $PY -m samcon.track --config oracle --motions $1 --out $R/samcon-$1 > $R/samcon-$1.log 2>&1; date; echo "samcon $1 done"; }
( samcon walk
  $PY benchmarks/compare_trackers.py --suite walk --seeds 3 --minutes 30 --parallel 2 --oracle $R/samcon-walk --out $R/suite-walk > $R/suite-walk-report.log 2>&1
  date; echo "walk report done"
  samcon run; samcon jump ) &
( samcon jog; samcon stealthy_walk; samcon zombie_walk ) &
wait
date; echo "phase 2 done"
