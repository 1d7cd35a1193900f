"""report/tables.py's clip-per-row summary, on numbers set by hand."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from report.tables import clip_summary_table, metric_tables


def _result(survival: list[float], mpjpe_g: list[float], mpjpe_l: list[float]) -> SimpleNamespace:
    per_clip = {"survival": np.array(survival), "mpjpe_g": np.array(mpjpe_g), "mpjpe_l": np.array(mpjpe_l)}
    return SimpleNamespace(clips=["walk", "run"], per_clip=per_clip,
                           overall={k: float(np.mean(v)) for k, v in per_clip.items()})  # fmt: skip


def test_summary_has_a_row_per_clip_and_the_mean_last() -> None:
    a, b = _result([1.0, 0.5], [40.0, 900.0], [20.0, 60.0]), _result([0.25, 0.0], [3000.0, 5000.0], [300.0, 400.0])
    md = clip_summary_table(["st", "ppo"], [a, b], ("survival", "mpjpe_g", "mpjpe_l"))
    lines = md.splitlines()
    names = "survival / MPJPE-g (mm) / MPJPE-l (mm)"
    assert lines[0] == f"| clip | st: {names} | ppo: {names} |"
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in lines[2:]]
    assert [r[0] for r in rows] == ["`walk`", "`run`", "mean"]
    assert [float(x) for x in rows[1][1].split("/")] == [0.5, 900.0, 60.0]
    assert [float(x) for x in rows[2][2].split("/")] == [0.125, 4000.0, 350.0]


def test_metric_tables_put_the_summary_only_where_there_are_several_clips() -> None:
    from common.evaluation import metrics as M

    full = {k: np.array([1.0, 2.0]) for k in M.METRIC_NAMES}
    two = SimpleNamespace(clips=["walk", "run"], per_clip=full, overall={k: 1.5 for k in M.METRIC_NAMES})
    one = SimpleNamespace(clips=["walk"], per_clip={k: v[:1] for k, v in full.items()},
                          overall={k: 1.0 for k in M.METRIC_NAMES})  # fmt: skip
    assert "#### Per clip at a glance" in metric_tables(["a"], [two])
    assert "#### Per clip at a glance" not in metric_tables(["a"], [one])


def test_oracle_table_takes_each_clips_oracle_and_marks_clips_a_samcon_run_did_not_track() -> None:
    from report.tables import oracle_table

    learner = _result([1.0, 0.0], [61.4, 2873.6], [18.1, 164.1])
    on_walk = _result([0.25, 0.0], [2481.4, 8959.5], [337.0, 462.1])  # a SAMCON run that tracked walk only
    open_loop = _result([1.0, 1.0], [44.69, 3000.0], [30.47, 200.0])
    md = oracle_table({"samcon:w": (open_loop, {"walk": 5.0083})}, ["st", "samcon:w"], [learner, on_walk])
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in md.splitlines()[2:]]
    assert rows[0] == ["walk", "samcon:w", "45 / 30", "no", "5.0", "61 / 18", "2481 / 337"]
    assert rows[1] == ["run", "not tracked", "", "", "", "2874 / 164", "not tracked"]
