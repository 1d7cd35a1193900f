"""The motion-quality rows and table of the report (report/tables.py), on numbers set by hand."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from common.evaluation import metrics as M
from report.tables import metric_tables


def _rows(md: str, section: str) -> list[list[str]]:
    """The body rows of the table under the heading ``section``."""
    block = md.split(f"#### {section}\n", 1)[1].split("\n\n", 1)[0].strip().splitlines()
    return [[c.strip() for c in line.strip("|").split("|")] for line in block[2:]]


def test_motion_quality_rows_beside_mpjpe_and_the_references_sliding_unranked() -> None:
    def result(scale: float) -> SimpleNamespace:
        per_clip = {k: np.array([1.0, 3.0]) * scale for k in M.METRIC_NAMES}
        per_clip["foot_slide_ref"] = np.array([4.0, 6.0])  # the clips' own: the same for both runs
        return SimpleNamespace(clips=["walk", "run"], per_clip=per_clip,
                               overall={k: float(np.mean(v)) for k, v in per_clip.items()})  # fmt: skip

    md = metric_tables(["a", "b"], [result(1.0), result(2.0)])
    rows = {r[0]: r[1:] for r in _rows(md, "Mean over clips")}
    assert rows["accel_err (mm/frame^2), lower better"] == ["**2**", "4"]
    assert rows["foot_slide (mm/frame), lower better"] == ["**2**", "4"]
    assert rows["target_jitter (rad/frame^2), lower better"] == ["**2**", "4"]
    assert rows["foot_slide_ref (mm/frame), the reference's, not ranked"] == ["5", "5"]
    glance = _rows(md, "Motion quality per clip")
    assert [r[0] for r in glance] == ["`walk`", "`run`", "mean"]
    # accel / vel / foot slide / reference's / jitter of run b, then the means of run a.
    assert [float(x) for x in glance[1][2].split("/")] == [6.0, 6.0, 6.0, 6.0, 6.0]
    assert [float(x) for x in glance[2][1].split("/")] == [2.0, 2.0, 2.0, 5.0, 2.0]
