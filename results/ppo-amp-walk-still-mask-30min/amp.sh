# PPO against PPO + AMP (amp.weight 0.3, rsl_rl form, still_std 1e-3 mask), 2 seeds, all four arms started together
# (four one-thread processes on the 2-core machine: about half a core each). Usage: amp.sh MOTIONS_NAME MINUTES MOTIONS...
NAME=$1; MIN=$2; shift 2
cd /work/wt-s29
run() { OMP_NUM_THREADS=1 PYTHONPATH=/work/wt-s29 /work/main/.venv/bin/train-ppo --motions "$@" --max-minutes $MIN \
  --set gym.threads=1 --set train.torch_threads=1 --set train.eval.threads=1; }
for S in 0 1; do
  run "$@" --seed $S --out /work/runs/s29/ppo-$NAME-s$S > /work/runs/s29/ppo-$NAME-s$S.log 2>&1 &
  run "$@" --seed $S --set amp.weight=0.3 --out /work/runs/s29/ppoamp-$NAME-s$S > /work/runs/s29/ppoamp-$NAME-s$S.log 2>&1 &
done
wait
