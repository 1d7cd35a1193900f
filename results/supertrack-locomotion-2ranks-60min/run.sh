#!/usr/bin/env bash
# SuperTrack on the locomotion set, 2 ranks x 1 core, 60 training minutes, seed 5: the whole-machine run of
# results/supertrack-locomotion-whole-machine-60min spread over two ranks with the same global sizes (2 x 32
# characters of which 2 x 2 held back, W batch 2 x 128, policy batch 2 x 64 windows), evaluated as that run was.
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-runs/s37/st-loco-2ranks}
.venv/bin/torchrun --standalone --nproc_per_node=2 -m supertrack.train \
    --motions walk jog run stealthy_walk zombie_walk --out "$OUT" --max-minutes 60 --seed 5 \
    --set gym.threads=1 --set gym.num_envs=32 --set buffer.val_envs=2 \
    --set world_model.batch=128 --set policy.batch=64 \
    --set train.eval.threads=2 --set train.eval.starts_per_clip=4 --set train.eval_every_minutes=10 "$@"
