#!/bin/bash
# Issue 57: one PPO arm on the locomotion set, one core (the suite's one-core settings: benchmarks/compare_trackers.py
# --parallel 2, eval every minutes/8). Usage: ppo-arm.sh ARM SEED MINUTES OUT
#   ARM: large (1024 characters x 8 steps, minibatch 2048, fixed rates) | adaptive (the same + rsl_rl's KL schedule)
#        | rsl (rsl_rl's PPO, configs/rsl_rl/default.yaml, at the same 1024 x 8 per update, 4 minibatches of 2048)
set -euo pipefail
cd "$(dirname "$0")/../.."  # the project root
arm=$1; seed=$2; minutes=$3; out=$4
sets=(--set gym.threads=1 --set train.torch_threads=1 --set train.eval.threads=1
      --set "train.eval_every_minutes=$(python3 -c "print($minutes/8)")"
      --set gym.num_envs=1024)
command=.venv/bin/train-ppo
case $arm in
  large) sets+=(--set ppo.minibatch_size=2048 --set ppo.schedule=fixed) ;;
  adaptive) sets+=(--set ppo.minibatch_size=2048 --set ppo.schedule=adaptive) ;;
  rsl) command=.venv/bin/train-rsl-rl ;;  # num_mini_batches 4 (its config): 8192 / 4 = 2048 per minibatch
  *) echo "unknown arm $arm"; exit 2 ;;
esac
resume=(); [ -e "$out/checkpoints/latest.json" ] && resume=(--resume)
exec $command --config default --seed "$seed" --max-minutes "$minutes" \
  --motions walk jog run stealthy_walk zombie_walk --out "$out" "${sets[@]}" "${resume[@]}"
