#!/bin/bash
# Session 33, phase 1: the locomotion suite's seeds 1 and 2 (both learners side by side, one core each, 60 min each),
# reusing seed 0's finished runs (same command and config path, from the worktree /work/wt-s31). Session 32's seed-1
# start was stopped by that session's end after 5 minutes, before its first checkpoint; it was moved to
# /work/runs/s33/aborted-loco-s1 and seed 1 starts again from nothing.
set -u
R=/work/runs/s32
PY=/work/main/.venv/bin/python
cd /work/wt-s31
export PYTHONPATH=/work/wt-s31
date; echo "locomotion seeds 1 and 2 start"
$PY benchmarks/compare_trackers.py --suite locomotion --seeds 3 --minutes 60 --parallel 2 --train-only --out $R/suite-locomotion > /work/runs/s33/suite-locomotion-s12.log 2>&1
date; echo "locomotion seeds 1 and 2 done"
