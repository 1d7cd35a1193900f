"""The session's assisted-tracking table from `python -m samcon.assist` JSON files: one row per clip and file.

    python results/session20-samcon/table.py results/session20-samcon/*.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def cell(judged: dict) -> str:
    fell = "" if judged["fell_at"] is None else f", fell at {judged['fell_at']}"
    return f"{judged['mpjpe_g']:.1f} / {judged['mpjpe_l']:.1f}{fell}"


def main(paths: list[str]) -> None:
    print("| clip | file | cap (body weights) | searched g / l (mm) | polished g / l (mm) | kept | force mean / p95 "
          "(body weights) | one-core min per s |")
    print("|---|---|---|---|---|---|---|---|")
    for path in paths:
        out = json.loads(Path(path).read_text())
        a = out["assist"]
        for name, row in out["clips"].items():
            pol = row.get("polished")
            force = row["force_body_weights"]
            print(f"| {name} | {Path(path).name} | {a['cap']:g} (kp {a['kp']:g}, kd {a['kd']:g}, ff {a['scale']:g}) "
                  f"| {cell(row['searched'])} | {cell(pol) if pol else '-'} | {pol['kept'] if pol else '-'} "
                  f"| {force['mean']:.3f} / {force['p95']:.3f} | {row['minutes_per_motion_second']:.2f} |")


if __name__ == "__main__":
    main(sys.argv[1:])
