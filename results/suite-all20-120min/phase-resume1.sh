#!/bin/bash
# Session 34, phase 1: resume the all20 suite (2 seeds x 120 min, one core per run, both learners of a seed side by
# side). Seed 0 resumes from its 10-minute checkpoints (session 33's end stopped it after ~18 training minutes); seed 1
# follows from nothing; the session's end stops it, and the next session's identical command resumes it.
set -u
R=/work/runs/s33
PY=/work/main/.venv/bin/python
cd /work/wt-s31
export PYTHONPATH=/work/wt-s31
date; echo "all20 resumes"
$PY benchmarks/compare_trackers.py --suite all20 --seeds 2 --minutes 120 --parallel 2 --train-only --out $R/suite-all20 > /work/runs/s34/suite-all20.log 2>&1
date; echo "all20 done"
