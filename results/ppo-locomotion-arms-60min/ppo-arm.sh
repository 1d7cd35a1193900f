#!/bin/bash
# Issue 57: one PPO arm on the locomotion set, one core (the suite's one-core settings: benchmarks/compare_trackers.py
# --parallel 2, eval every minutes/8). Usage: ppo-arm.sh ARM SEED MINUTES OUT
#   ARM: large (1024 characters x 8 steps, minibatch 2048, fixed rates) | adaptive (the same + rsl_rl's KL schedule)
set -euo pipefail
cd "$(dirname "$0")/../.."  # the project root
arm=$1; seed=$2; minutes=$3; out=$4
sets=(--set gym.threads=1 --set train.torch_threads=1 --set train.eval.threads=1
      --set "train.eval_every_minutes=$(python3 -c "print($minutes/8)")"
      --set gym.num_envs=1024 --set ppo.minibatch_size=2048)
case $arm in
  large) ;;
  adaptive) sets+=(--set ppo.schedule=adaptive) ;;
  *) echo "unknown arm $arm"; exit 2 ;;
esac
resume=(); [ -e "$out/checkpoints/latest.json" ] && resume=(--resume)
exec .venv/bin/train-ppo --config default --seed "$seed" --max-minutes "$minutes" \
  --motions walk jog run stealthy_walk zombie_walk --out "$out" "${sets[@]}" "${resume[@]}"
