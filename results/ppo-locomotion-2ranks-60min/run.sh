#!/bin/bash
# Issue 56: PPO on the locomotion set, 2 data-parallel ranks x 1 core, 60 min, seed 0 (whole machine)
cd "$(dirname "$0")/../.."  # the project root
.venv/bin/torchrun --standalone --nproc_per_node=2 -m ppo.train --motions walk jog run stealthy_walk zombie_walk \
  --out runs/s39/ppo-loco-2ranks --max-minutes 60 --seed 0 --set gym.threads=1 --set train.eval.threads=2 \
  --set train.eval.starts_per_clip=4 --set train.eval_every_minutes=10
# then, with the machine free (after issue 57's arms of runs/s39/arms-seed0.sh):
.venv/bin/compare-trackers runs/s39/ppo-loco-2ranks --starts 4 --no-render --threads 2 --out runs/s39/report-ppo-loco-2ranks
.venv/bin/python benchmarks/run_curve.py runs/s39/ppo-loco-2ranks
