#!/bin/bash
# Issue 58 item 1, probe: SuperTrack iteration time at 3x256, 5x512, 5x1024 (fp32 and bf16), one core, all 20 clips,
# beside a one-core PPO run on the other core (the capacity runs' conditions: two one-core runs side by side).
cd "$(dirname "$0")/../.."  # the project root
common=(--set gym.threads=1 --set train.torch_threads=1 --set "train.motions=[all]" --bf16-too)
for w in 256 512 1024; do
  case $w in 256) h='[256,256,256]'; n=20;; 512) h='[512,512,512,512,512]'; n=10;; 1024) h='[1024,1024,1024,1024,1024]'; n=6;; esac
  .venv/bin/python benchmarks/supertrack_iteration_time.py --configs configs/supertrack/default.yaml -n $n "${common[@]}" \
    --set "world_model.hidden=$h" --set "policy.hidden=$h" > "${OUT:-runs/capacity-bench}"-$w.txt 2>&1
done
