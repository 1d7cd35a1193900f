#!/bin/bash
# Session 31, phase 2: after phase 1 (the SAMCON searches), the full test suite on main's HEAD (both cores), then the
# jump suite's seed 0 (both learners side by side, one core each, 30 min) if it can end inside the session; the next
# session trains seeds 1 and 2 (the suite reuses finished runs).
set -u
R=/work/runs/s31
PY=/work/main/.venv/bin/python
while pgrep -f phase1.sh >/dev/null; do sleep 15; done
date; echo "tests start"
(cd /work/main && .venv/bin/pytest -q > $R/pytest.log 2>&1); tail -2 $R/pytest.log
date
if [ $(date +%H%M) -gt 1420 ]; then echo "too late for the jump pair; skipped"; exit 0; fi
cd /work/wt-s31
export PYTHONPATH=/work/wt-s31
echo "jump suite seed 0 starts"
$PY benchmarks/compare_trackers.py --suite jump --seeds 1 --minutes 30 --parallel 2 --train-only --out $R/suite-jump > $R/suite-jump.log 2>&1
date; echo "jump seed 0 done"
