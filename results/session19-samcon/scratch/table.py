"""Per clip: default.yaml's searched path (session 18's lqr-set1/2.json: the same search, seed 0) against the
polished one (polish.yaml runs of this session): open-loop MPJPE-g / -l from the clip's start, whether the polish was
kept, one-core minutes per second of motion, LQR survival.

    python table.py RESULTS.json ...
"""

import json
import sys
from pathlib import Path

here = Path(__file__).resolve().parents[2]
before = {}
for name in ("lqr-set1.json", "lqr-set2.json"):
    before.update(json.loads((here / "session18-samcon" / name).read_text())["clips"])
print("| clip | searched MPJPE-g / -l | polished MPJPE-g / -l | polish kept | one-core min per s | LQR survival "
      "(searched / polished path) |")
print("|---|---|---|---|---|---|")
for path in sys.argv[1:]:
    for clip, row in json.loads(Path(path).read_text())["clips"].items():
        b, ol = before[clip], row["open_loop"]
        kept = row.get("polish", {}).get("kept")
        print(f"| {clip} | {b['open_loop']['mpjpe_g']:.1f} / {b['open_loop']['mpjpe_l']:.1f} | "
              f"{ol['mpjpe_g']:.1f} / {ol['mpjpe_l']:.1f} | {'yes' if kept else 'no'} | "
              f"{row['minutes_per_motion_second']:.2f} | {b['feedback']['survival']:.2f} / "
              f"{row['feedback']['survival']:.2f} |")
