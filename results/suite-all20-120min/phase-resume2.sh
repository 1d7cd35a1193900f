#!/bin/bash
# Seed 0 is done (reused); seed 1 resumes from its 60-minute checkpoints (session 34 set aside the 70-minute ones,
# trained beside CI), 60 training minutes left for each learner, one core each, side by side.
set -u
R=/work/runs/s33
PY=/work/main/.venv/bin/python
cd /work/wt-s31
export PYTHONPATH=/work/wt-s31
date; echo "all20 resumes"
$PY benchmarks/compare_trackers.py --suite all20 --seeds 2 --minutes 120 --parallel 2 --train-only --out $R/suite-all20 > /work/runs/s35/suite-all20.log 2>&1
date; echo "all20 done"
