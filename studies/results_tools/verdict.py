"""Per bundled clip, SAMCON's best open-loop tracking so far: without root forces, and with a root force of at most
0.5 body weights (``python -m samcon.assist``), from the stored result files of sessions 16-26 (the folders in
``FOLDERS``).

    python studies/results_tools/verdict.py [--feasibility results/samcon-study-feasibility/forces.json]

Counted: ``track-samcon`` ``results.json`` copies (the open-loop row) and ``samcon.assist`` JSON files (the searched,
polished, ``--then-caps``, ``--then-search`` and ``--then-couple`` rows, each at its own caps, of the default law: a
PD pull, no residual fed forward; a ``--then-search`` stage at caps 0:0 and the path ``--then-couple`` polishes last
are unassisted paths and count as such), on
the default references (session 16's reference fixes on; session 22's bridged references and the 64-frame probes
left out), over the evaluator's whole open-loop horizon (512 frames, or to a one-shot clip's end) and without a fall.
Force caps above 0.5, a root torque, stronger servos (``gym.physics.torque_scale``; all session 23) and floor contacts
with torsional friction (``gym.physics.torsional_friction``, session 26) go to the last column, one cell per setting.
Each cell is the lowest MPJPE-g of those, with its MPJPE-l, the one-core minutes per
second of motion of that run (all its stages, and the run whose path a ``--start-path`` run began from) and its
file. One draw each: the best of several draws and configs is a selection, so the figures are what SAMCON has
reached, not what one run reaches.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from common.character.humanoid import Humanoid  # noqa: E402
from common.motion.dataset import resolve_clips  # noqa: E402
from common.motion.library import MotionLibrary  # noqa: E402
from samcon.search import horizon  # noqa: E402

TARGET_MM = 60.0
CAP = 0.5
# The results measured on the fixed references (session 16 on); the folders before them are left out.
FOLDERS = (
    "samcon-study-search-settings/fixed-references",
    "samcon-study-search-settings/cost-probes",
    "samcon-study-feedback/cma",
    "samcon-study-feedback/visits",
    "samcon-study-lqr-walk",
    "samcon-study-polish",
    "samcon-study-root-assist",
    "samcon-study-loop-seams",
    "samcon-study-torsional-friction",
)
# On session 22's bridged references (commit 98bbe92 made the bridge the default for these runs), or not full length.
EXCLUDE = re.compile(r"samcon-study-loop-seams/(bridge-|seed\d|search-bridged|probes/)")
# ``--start-path`` values written before results/ was renamed (issue 41): the folders they point to now.
MOVED = {
    "results/session24-samcon/": "results/samcon-study-root-assist/search-anew/",
    "results/session25-samcon/": "results/samcon-study-root-assist/couple/",
}


def _physics(data: dict, key: str, default: float) -> float:
    """The run's last ``--set gym.physics.<key>=...`` override, or ``default``."""
    given = [float(o.split("=")[1]) for o in data.get("overrides", []) if f"physics.{key}=" in o]
    return given[-1] if given else default


def records(root: Path, full: dict[str, int]) -> dict[str, list[dict]]:
    """Every counted result per clip: mpjpe_g, mpjpe_l, cap (0: no root force), min_per_s, file."""
    out: dict[str, list[dict]] = {name: [] for name in full}
    paths = sorted(p for folder in FOLDERS for p in (root / "results" / folder).glob("**/*.json"))
    for path in paths:
        rel = path.relative_to(root).as_posix()
        if EXCLUDE.search(rel):
            continue
        data = json.loads(path.read_text())
        if not isinstance(data, dict) or not isinstance(data.get("clips"), dict):
            continue
        for name, row in data["clips"].items():
            if name not in full or not isinstance(row, dict) or row.get("frames") != full[name]:
                continue
            base = {"min_per_s": row.get("minutes_per_motion_second"), "file": rel, "torque": 0.0,
                    "strength": _physics(data, "torque_scale", 1.0),
                    "torsion": _physics(data, "torsional_friction", 0.0)}  # fmt: skip
            if "assist" in data:
                law = data["assist"]
                if law["scale"] > 0.0 or law["kp"] == 0.0:  # the residual fed forward: another law, left out
                    continue
                torque = law.get("torque_cap", 0.0)
                judged = [(row[k], law["cap"], torque, k) for k in ("searched", "polished") if k in row]
                judged += [(t, t["cap"], torque, "then") for t in row.get("then", [])]
                # --then-search stages (session 24), each at its own caps; a run started from another's saved path
                # (--start-path) counts that run's minutes too.
                judged += [(t[k], t["force_cap"], t["torque_cap"], "then_search") for t in row.get("then_search", [])
                           for k in ("searched", "polished") if k in t]  # fmt: skip
                # --then-couple stages (session 25): the couple held, counted at its largest value as a torque cap;
                # the path polished without it after them is unassisted.
                judged += [(t, 0.0, t["torque_body_weight_metres"]["max"], "then_couple")
                           for t in row.get("then_couple", [])]  # fmt: skip
                judged += [(row["unassisted"], 0.0, 0.0, "unassisted")] if "unassisted" in row else []
                if data.get("start_path") and base["min_per_s"] is not None:
                    start = data["start_path"].rpartition(":")[0]
                    for before, now in MOVED.items():
                        start = start.replace(before, now)
                    given = Path(start).with_suffix(".json")
                    given = ROOT / given if (ROOT / given).is_file() else path.with_name(given.name)
                    source = json.loads(given.read_text())["clips"][name]
                    base["min_per_s"] += source["minutes_per_motion_second"]
                for j, cap, torque, stage in judged:
                    if j["fell_at"] is None:
                        out[name].append(base | {"mpjpe_g": j["mpjpe_g"], "mpjpe_l": j["mpjpe_l"], "cap": cap,
                                                 "torque": torque, "stage": stage})  # fmt: skip
            elif "open_loop" in row and row["open_loop"].get("survival", 0.0) >= 1.0:
                j = row["open_loop"]
                out[name].append(base | {"mpjpe_g": j["mpjpe_g"], "mpjpe_l": j["mpjpe_l"], "cap": 0.0,
                                         "stage": "track"})  # fmt: skip
    return out


def best(rows: list[dict], max_cap: float) -> dict | None:
    """The lowest MPJPE-g with a force of at most ``max_cap`` body weights and no root torque."""
    within = [
        r for r in rows if r["cap"] <= max_cap and r["torque"] == 0.0 and r["strength"] == 1.0 and r["torsion"] == 0.0
    ]
    return min(within, key=lambda r: (r["mpjpe_g"], r["min_per_s"] or 0.0)) if within else None


def label(r: dict) -> str:
    """The setting of a "more" cell: force cap, torque cap, servo strength, torsional friction."""
    parts = [f"force cap {r['cap']:g}"] + ([f"torque cap {r['torque']:g}"] if r["torque"] else [])
    parts += [f"servo limits x {r['strength']:g}"] if r["strength"] != 1.0 else []
    return ", ".join(parts + ([f"torsional friction {r['torsion']:g} m"] if r["torsion"] else []))


def cell(r: dict | None) -> str:
    if r is None:
        return "-"
    mark = "**" if r["mpjpe_g"] <= TARGET_MM else ""
    speed = "?" if r["min_per_s"] is None else f"{r['min_per_s']:.2f}"
    return f"{mark}{r['mpjpe_g']:.1f}{mark} / {r['mpjpe_l']:.1f} ({speed}; `{r['file'].removeprefix('results/')}`)"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--feasibility",
        default=None,
        metavar="FILE.json",
        help="samcon.feasibility output: adds the reference's residual force and joint-range columns",
    )
    args = parser.parse_args(argv)
    humanoid = Humanoid()
    clips = resolve_clips(["all"])
    library = MotionLibrary.from_clips(clips, humanoid)
    full = {name: horizon(library, c, 512) for c, name in enumerate(library.names)}
    feas = json.loads(Path(args.feasibility).read_text())["clips"] if args.feasibility else {}
    rows = records(ROOT, full)
    head = (
        "| clip | frames | no root force: MPJPE-g / -l mm (one-core min per s; file) | root force <= 0.5 body "
        "weights | more: a larger force or a root torque |"
    )
    rule = "|---|---|---|---|---|"
    if feas:
        head += " residual force mean / share > 0.1 (body weights) | hinge out of range (share of frames) |"
        rule += "---|---|"
    print(head)
    print(rule)
    counts = [0, 0, 0]
    for name in library.names:
        plain, assisted = best(rows[name], 0.0), best(rows[name], CAP)
        counts[0] += plain is not None and plain["mpjpe_g"] <= TARGET_MM
        counts[1] += assisted is not None and assisted["mpjpe_g"] <= TARGET_MM
        setting = lambda r: (r["cap"], r["torque"], r["strength"], r["torsion"])  # noqa: E731
        more = [r for r in rows[name] if r["cap"] > CAP or r["torque"] > 0.0 or r["strength"] != 1.0 or r["torsion"]]
        more = [min([r for r in more if setting(r) == k], key=lambda r: (r["mpjpe_g"], r["min_per_s"] or 0.0))
                for k in sorted({setting(r) for r in more})]  # fmt: skip
        extra = "; ".join(f"{cell(r)} at {label(r)}" for r in more) or "-"
        counts[2] += any(r["mpjpe_g"] <= TARGET_MM for r in rows[name])
        line = f"| {name} | {full[name]} | {cell(plain)} | {cell(assisted)} | {extra} |"
        if feas:
            f = feas[name]
            beyond = f["out_of_range_joint"]
            by, share = f["out_of_range_max_rad"], f["out_of_range_share"]
            joint = "-" if not beyond else f"{beyond} by {by:.2f} rad ({share:.0%})"
            line += f" {f['residual_mean']:.2f} / {f['residual_share_over']:.0%} | {joint} |"
        print(line)
    print(f"\nwithin {TARGET_MM:g} mm: {counts[0]} of {len(full)} without root forces, {counts[1]} with a force of at "
          f"most {CAP:g} body weights, {counts[2]} with some setting in the table")  # fmt: skip


if __name__ == "__main__":
    main()
