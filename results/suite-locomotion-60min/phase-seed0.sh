#!/bin/bash
# Session 32, phase 1: the jump suite's seeds 1 and 2 (seed 0 trained in session 31 by the same command; two runs at a
# time on one core each, nothing else on the machine), its report with the SAMCON jump oracle, then the locomotion
# suite's seed 0 (60 min, one core each) if it can end inside the session.
set -u
R=/work/runs/s32
R31=/work/runs/s31
PY=/work/main/.venv/bin/python
cd /work/wt-s31
export PYTHONPATH=/work/wt-s31
date; echo "jump suite training (seeds 1, 2) starts"
$PY benchmarks/compare_trackers.py --suite jump --seeds 3 --minutes 30 --parallel 2 --train-only --out $R31/suite-jump > $R/suite-jump.log 2>&1
date; echo "jump suite training done"
$PY benchmarks/compare_trackers.py --suite jump --seeds 3 --minutes 30 --parallel 2 --oracle $R31/samcon-jump --out $R31/suite-jump > $R/suite-jump-report.log 2>&1
date; echo "jump report done"
if [ $(date +%H%M) -gt 1745 ]; then echo "too late for locomotion seed 0; skipped"; exit 0; fi
$PY benchmarks/compare_trackers.py --suite locomotion --seeds 1 --minutes 60 --parallel 2 --train-only --out $R/suite-locomotion > $R/suite-locomotion.log 2>&1
date; echo "locomotion seed 0 done"
