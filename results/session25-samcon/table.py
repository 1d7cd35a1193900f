"""The stages of session 25's runs (``samcon.assist`` with ``--then-search``, ``--then-couple`` or
``--polish-again``), one line each: the caps (or the couple's weight and its mean in body-weight metres), the searched
and the polished MPJPE-g (mm, open loop from the clip's start; "fell N": the evaluator's failure step; "polish
dropped": no polish pass made the path cheaper, the one it started from stays).

    python results/session25-samcon/table.py results/session25-samcon/*.json
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

# fig() and the first lines of a clip's rows are session 24's (results/session24-samcon/table.py).
_spec = importlib.util.spec_from_file_location("table24", Path(__file__).parents[1] / "session24-samcon" / "table.py")
_table24 = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_table24)
fig, search_rows = _table24.fig, _table24.search_rows


def main(files: list[str]) -> None:
    print("| file | clip | stage | force cap | torque cap / couple weight (mean couple) | searched | polished |")
    print("|---|---|---|---|---|---|---|")
    for file in files:
        data = json.loads(Path(file).read_text())
        if "assist" not in data:
            continue
        for name, row in data["clips"].items():
            print("\n".join(search_rows(file, data["assist"], name, row)))
            for t in row.get("then_couple", []):
                print(f"| | | couple as a control | 0 | {t['weight']:g} "
                      f"({t['torque_body_weight_metres']['mean']:.3f}) | - | {fig(t)} |")
            for j, t in enumerate(row.get("unassisted_rounds", [])):
                print(f"| | | without help, polish {j + 1} | 0 | 0 | - | {fig(t)} |")


if __name__ == "__main__":
    main(sys.argv[1:])
