#!/bin/bash
# tuning grid on 19 starts (not the evaluator's 16)
cd /work/main
for u in 5 10 20; do for h in 3 10 30; do for rr in 10 50; do
s="{\"u\":$u,\"h\":$h,\"rr\":$rr,\"starts\":19}"
r=$(nice .venv/bin/python results/session18-samcon/scratch/lqr.py runs/s18/walk-s01 walk "$s" 2>&1 | grep -E "^\{" | python3 -c "import sys,ast; d=ast.literal_eval(sys.stdin.read()); print(d['survival'], d['episode_len_ratio'], d['mpjpe_g_succ'])")
echo "$s $r"
done; done; done
