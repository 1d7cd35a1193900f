"""The stages of ``python -m samcon.assist`` runs, one table line each: the first search and polish at the run's caps
(or the path it was given, ``--start-path``), then its ``--then-caps``, ``--then-search``, ``--then-couple`` and
``--polish-again`` stages. Each line gives the caps (or the couple's weight and its mean in body-weight metres), the
searched and the polished MPJPE-g (mm, open loop from the clip's start; "fell N": the evaluator's failure step;
"polish dropped": no polish pass made the path cheaper, the one it started from stays). Files that are not
``samcon.assist`` output (``track-samcon`` results) are skipped.

    python studies/results_tools/assist_table.py results/samcon-study-root-assist/*/*.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def fig(judged: dict | None) -> str:
    """One judged path as a table cell.

    Args:
        judged: an open-loop judgement (``mpjpe_g``, ``fell_at``, optional ``kept``), or None.

    Returns:
        The MPJPE-g in mm with the failure step and a dropped polish noted; "-" for None.
    """
    if judged is None:
        return "-"
    out = f"{judged['mpjpe_g']:.1f}" + ("" if judged["fell_at"] is None else f" (fell {judged['fell_at']})")
    return out + (" (polish dropped)" if judged.get("kept") is False else "")


def law_note(law: dict) -> str:
    """The root law's gains when they are not the default PD pull (kp 100, kd 20, nothing fed forward)."""
    if law["kp"] == 100.0 and law["kd"] == 20.0 and law["scale"] == 0.0:
        return ""
    return f" (kp {law['kp']:g}, kd {law['kd']:g}, ff {law['scale']:g})"


def clip_rows(file: str, law: dict, name: str, row: dict) -> list[str]:
    """A clip's stages in one ``samcon.assist`` file, one table line each.

    Args:
        file: the file's path (its name goes in the first column).
        law: the file's ``assist`` entry (the root law: cap, torque_cap, kp, kd, scale).
        name: the clip's name.
        row: the clip's entry in the file's ``clips``.

    Returns:
        The table lines, the first stage first.
    """
    first = ("given" if "given" in row else "search + polish") + law_note(law)
    torque = law.get("torque_cap", 0.0)  # runs made before the root torque existed have none
    lines = [
        f"| `{Path(file).name}` | {name} | {first} | {law['cap']:g} | {torque:g} | "
        f"{fig(row.get('searched', row.get('given')))} | {fig(row.get('polished'))} |"
    ]
    lines += [f"| | | polish at a lower cap, {i + 1} | {t['cap']:g} | {torque:g} | - | {fig(t)} |"
              for i, t in enumerate(row.get("then", []))]  # fmt: skip
    lines += [f"| | | around it, {i + 1} | {t['force_cap']:g} | {t['torque_cap']:g} | {fig(t['searched'])} | "
              f"{fig(t.get('polished'))} |" for i, t in enumerate(row.get("then_search", []))]  # fmt: skip
    lines += [f"| | | couple as a control | 0 | {t['weight']:g} ({t['torque_body_weight_metres']['mean']:.3f}) | - | "
              f"{fig(t)} |" for t in row.get("then_couple", [])]  # fmt: skip
    lines += [f"| | | without help, polish {j + 1} | 0 | 0 | - | {fig(t)} |"
              for j, t in enumerate(row.get("unassisted_rounds", []))]  # fmt: skip
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+", metavar="FILE.json", help="samcon.assist output files")
    args = parser.parse_args(argv)
    print("| file | clip | stage | force cap | torque cap / couple weight (mean couple) | searched | polished |")
    print("|---|---|---|---|---|---|---|")
    for file in args.files:
        data = json.loads(Path(file).read_text())
        if "assist" not in data:
            continue
        for name, row in data["clips"].items():
            print("\n".join(clip_rows(file, data["assist"], name, row)))


if __name__ == "__main__":
    main()
