#!/bin/bash
# Session 33, phase 3: the all20 suite (2 seeds x 120 min, one core per run, both learners of a seed side by side),
# started 37 minutes before the session ends (a first start at 20:38 was stopped after 3 minutes, before any checkpoint, to run CI on an idle machine, and moved to aborted-all20-first-start); the next session's identical command resumes both runs from their last
# checkpoints (every 10 training minutes; buffer, optimisers, normalisers and counters included).
set -u
R=/work/runs/s33
PY=/work/main/.venv/bin/python
cd /work/wt-s31
export PYTHONPATH=/work/wt-s31
date; echo "all20 starts"
$PY benchmarks/compare_trackers.py --suite all20 --seeds 2 --minutes 120 --parallel 2 --train-only --out $R/suite-all20 > $R/suite-all20.log 2>&1
date; echo "all20 done"
