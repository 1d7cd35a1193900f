#!/bin/bash
# Session 36: after the split suite's training (pid 17367: seed 0 resumed from its 100-minute checkpoints, seed 1 from
# nothing), its two reports side by side, one core each: the held-out clips (one MP4 per method) and the training
# clips (no MP4: the held-out report has the suite's videos).
set -u
while kill -0 17367 2>/dev/null; do sleep 10; done
date; echo "split reports"
cd /work/main
R=/work/runs/s35/suite-split/runs
RUNS="$R/supertrack-s0 $R/ppo-s0 $R/supertrack-s1 $R/ppo-s1"
.venv/bin/compare-trackers $RUNS --out /work/runs/s35/suite-split/report --motions walk jog sideflip kick dance_b \
    --video-clips 1 --threads 1 > /work/runs/s36/report-heldout.log 2>&1 &
p1=$!
.venv/bin/compare-trackers $RUNS --out /work/runs/s35/suite-split/report-train --motions backflip cartwheel crawl \
    dance_a dance_spin getup_facedown getup_faceup jump punch roll run spin spinkick stealthy_walk zombie_walk long \
    --video-clips 0 --threads 1 > /work/runs/s36/report-train.log 2>&1 &
p2=$!
wait $p1; echo "held-out report done ($?)"; date
wait $p2; echo "training-clip report done ($?)"; date
