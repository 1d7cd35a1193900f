"""The README's session 22 table: per clip and draw, the searched and polished body rms and the open-loop MPJPE-g /
-l of the polished path (``track-samcon`` results files), and the one-core minutes per second of motion.

    python table.py bridge-a.json bridge-b.json seed1.json seed2.json
"""

import json
import sys
from collections import defaultdict

rows = defaultdict(list)
for path in sys.argv[1:]:
    data = json.load(open(path))
    for clip, r in data["clips"].items():
        p, o = r["polish"], r["open_loop"]
        rows[clip].append((path, p["body_rms_mm_before"], p["body_rms_mm_after"], o["mpjpe_g"], o["mpjpe_l"],
                           r["minutes_per_motion_second"]))  # fmt: skip
for clip, rs in rows.items():
    cells = [f"{g:.1f} / {loc:.1f}" for _, _, _, g, loc, _ in rs]
    best = min(r[3] for r in rs)
    rms = ", ".join(f"{b:.0f} -> {a:.0f}" for _, b, a, *_ in rs)
    mins = ", ".join(f"{m:.2f}" for *_, m in rs)
    print(f"| {clip} | {' | '.join(cells)} | {best:.1f} | {rms} | {mins} |")
