#!/bin/bash
# Session 36: the split suite (2 seeds x 120 min, one core per run, both learners of a seed side by side), the same
# command that started it (../suite-all20-120min/phase-report.sh). Seed 0 of both learners resumes from its 100-minute
# checkpoints (session 35 stopped both right after writing them); seed 1 follows from nothing.
cd /work/wt-s31
PYTHONPATH=/work/wt-s31 nohup /work/main/.venv/bin/python benchmarks/compare_trackers.py --suite split --seeds 2 \
    --minutes 120 --parallel 2 --train-only --out /work/runs/s35/suite-split > /work/runs/s36/suite-split.log 2>&1 &
