#!/bin/bash
# Session 35, phase 2: after phase 1 (the all20 suite's seed 1), the all20 report, then the split suite's training
# (2 seeds x 120 min, one core per run, both learners of a seed side by side, from the worktree of every suite).
set -u
while kill -0 10812 2>/dev/null; do sleep 20; done  # phase1.sh (pid 10812)
date; echo "all20 report"
cd /work/main
.venv/bin/compare-trackers /work/runs/s33/suite-all20/runs/supertrack-s0 /work/runs/s33/suite-all20/runs/ppo-s0 \
    /work/runs/s33/suite-all20/runs/supertrack-s1 /work/runs/s33/suite-all20/runs/ppo-s1 \
    --out /work/runs/s33/suite-all20/report --motions all --video-clips 1 > /work/runs/s35/suite-all20-report.log 2>&1
rc=$?; date; echo "all20 report done ($rc)"
cd /work/wt-s31
export PYTHONPATH=/work/wt-s31
/work/main/.venv/bin/python benchmarks/compare_trackers.py --suite split --seeds 2 --minutes 120 --parallel 2 --train-only --out /work/runs/s35/suite-split > /work/runs/s35/suite-split.log 2>&1
date; echo "split done"
