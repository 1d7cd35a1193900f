# After the whole-machine run: the data-rate A/B on the locomotion set, one core each, started together, seed 5,
# 50 minutes: A the default (1 gym step x 64 characters per iteration; W reads each frame ~137 times), B 16 gym steps
# per iteration (1,024 frames; W ~8 reads, the paper ~5), both in-process. Beside them, once, W's per-clip error of the
# split run on its held-out clips and some training clips (nice 5; both arms share the perturbation).
while pgrep -f "train-supertrack" > /dev/null; do sleep 5; done
cd /work/wt-s29
run() { OMP_NUM_THREADS=1 PYTHONPATH=/work/wt-s29 /work/main/.venv/bin/train-supertrack \
  --motions walk jog run stealthy_walk zombie_walk --max-minutes 50 --seed 5 \
  --set gym.threads=1 --set train.torch_threads=1 --set train.eval.threads=1 \
  --set train.eval.starts_per_clip=4 --set train.eval_every_minutes=10 "$@"; }
run --out /work/runs/s29/st-loco-rate-default > /work/runs/s29/st-loco-rate-default.log 2>&1 &
run --out /work/runs/s29/st-loco-rate-16 --set collect.steps_per_iteration=16 > /work/runs/s29/st-loco-rate-16.log 2>&1 &
sleep 240
cd /work/main && nice -n 5 env OMP_NUM_THREADS=1 .venv/bin/python benchmarks/world_model_bodies.py /work/runs/s28/st-split-train \
  --motions walk jog sideflip kick dance_b run zombie_walk backflip --frames 120 > /work/runs/s29/w-bodies-split-heldout.txt 2>&1
wait
