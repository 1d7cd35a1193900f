#!/bin/bash
# Issue 57, seed 0: our PPO at 1024 x 8 / minibatch 2048, fixed rates and rsl_rl's adaptive schedule, side by side,
# one core each, 60 min, locomotion set.
cd "$(dirname "$0")/../.."  # the project root
results/ppo-locomotion-arms-60min/ppo-arm.sh large 0 60 runs/s39/ppo-large-s0 > runs/s39/ppo-large-s0.log 2>&1 &
results/ppo-locomotion-arms-60min/ppo-arm.sh adaptive 0 60 runs/s39/ppo-adaptive-s0 > runs/s39/ppo-adaptive-s0.log 2>&1 &
wait
