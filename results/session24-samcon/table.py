"""The stages of session 24's continuation runs (``samcon.assist --then-search``), one line each: the caps, the
searched and the polished MPJPE-g (mm, open loop from the clip's start; "fell N": the evaluator's failure step;
"polish dropped": no polish pass made the path cheaper, the searched one stays).

    python results/session24-samcon/table.py results/session24-samcon/cont-*.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def fig(j: dict | None) -> str:
    if j is None:
        return "-"
    out = f"{j['mpjpe_g']:.1f}" + ("" if j["fell_at"] is None else f" (fell {j['fell_at']})")
    return out + (" (polish dropped)" if j.get("kept") is False else "")


def search_rows(file: str, law: dict, name: str, row: dict) -> list[str]:
    """A clip's first stage and its ``--then-search`` stages, one table line each."""
    first = "given" if "given" in row else "search + polish"
    lines = [f"| `{Path(file).name}` | {name} | {first} | {law['cap']:g} | {law['torque_cap']:g} | "
             f"{fig(row.get('searched', row.get('given')))} | {fig(row.get('polished'))} |"]
    return lines + [f"| | | around it, {i + 1} | {t['force_cap']:g} | {t['torque_cap']:g} | {fig(t['searched'])} | "
                    f"{fig(t.get('polished'))} |" for i, t in enumerate(row.get("then_search", []))]


def main(files: list[str]) -> None:
    print("| file | clip | stage | force cap | torque cap | searched | polished |")
    print("|---|---|---|---|---|---|---|")
    for file in files:
        data = json.loads(Path(file).read_text())
        for name, row in data["clips"].items():
            print("\n".join(search_rows(file, data["assist"], name, row)))


if __name__ == "__main__":
    main(sys.argv[1:])
