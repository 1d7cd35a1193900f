"""report/tables.py's clip-per-row summary, on numbers set by hand."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from report.runs import Run
from report.tables import clip_summary_table, metric_tables, parity, parity_table


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


def _run(learner: str, seed: int, curve: list[tuple[int, float, float]]) -> Run:
    """A run whose log holds evaluations (samples, wall-clock s, MPJPE-g) and nothing else."""
    metrics = [{"samples": n, "wall_clock_s": t, "eval/mpjpe_g": v} for n, t, v in curve]
    return Run(path=Path(f"/runs/{learner}-{seed}"), label=f"{learner}:{learner}-{seed}", learner=learner,
               config={"train": {"seed": seed}}, info={"seed": seed}, metrics=metrics, checkpoint=Path("c.pt"),
               iteration=1, samples=curve[-1][0], train_seconds=curve[-1][1])  # fmt: skip


def test_parity_table_by_hand() -> None:
    """B ends at 60 and 80 mm (mean 70) with 1,000 / 3,000 samples (mean 2,000) at 100 / 300 s (mean 200): A's seed 0
    first reaches <= 70 at its second evaluation (400 samples, 40 s: 0.20x, 0.20x), seed 1 never; B reaches A's
    final mean (50 and 500: 275) at its first evaluation in both seeds."""
    runs = [_run("supertrack", 0, [(100, 10.0, 900.0), (400, 40.0, 70.0), (800, 80.0, 50.0)]),
            _run("supertrack", 1, [(100, 10.0, 900.0), (800, 80.0, 500.0)]),
            _run("ppo", 0, [(500, 50.0, 120.0), (1000, 100.0, 60.0)]),
            _run("ppo", 1, [(1500, 150.0, 200.0), (3000, 300.0, 80.0)])]  # fmt: skip
    md = parity_table(runs)
    rows = {line.split(" | ")[0].strip("| "): line for line in md.splitlines()[2:]}
    assert "ppo: 70.0" in rows["supertrack"]
    assert "seed 0: 400 samples (0.20x), 40.0 s (0.20x)" in rows["supertrack"] and "seed 1: never" in rows["supertrack"]
    assert "supertrack: 275.0" in rows["ppo"]
    # ppo's first evaluations (120, 200 mm) are at or below 275: 500 samples of supertrack's mean 800 (0.62x)
    assert "seed 0: 500 samples (0.62x), 50.0 s (0.62x)" in rows["ppo"]
    assert "seed 1: 1,500 samples (1.88x), 2.5 min (1.88x)" in rows["ppo"]  # 150 s
    assert parity_table(runs[:2]) is None  # one method: nothing to compare
    oracle = _run("samcon", 0, [(0, 0.0, 40.0)])
    oracle.metrics = []  # a SAMCON run logs no evaluations: it neither reaches nor is reached
    assert parity_table([*runs, oracle]) == md
    # the same figures as data, as results.json keeps them
    data = {(p["method"], p["target_method"]): p for p in parity(runs)}
    st = data["supertrack", "ppo"]
    assert st["target"] == 70.0 and st["target_samples"] == 2000.0 and st["target_seconds"] == 200.0
    assert st["runs"][0] == {"label": "supertrack:supertrack-0", "seed": 0, "samples": 400, "seconds": 40.0,
                             "sample_ratio": 0.2, "time_ratio": 0.2}  # fmt: skip
    assert st["runs"][1]["samples"] is None and st["runs"][1]["sample_ratio"] is None
    assert parity(runs[:2]) == []


def test_update_statistics_table_takes_the_median_of_the_last_half() -> None:
    from report.tables import update_statistics_table

    # Iterations logged at 10..100 s: the last half (>= 50 s) holds the values at 50..100 s.
    metrics = [{"samples": 100 * t, "wall_clock_s": float(t), "losses/approx_kl": t / 1000.0,
                "losses/clip_frac": 0.5 if t < 50 else 0.1} for t in range(10, 101, 10)]  # fmt: skip
    ppo = Run(path=Path("/runs/ppo-0"), label="ppo:ppo-0", learner="ppo", config={}, info={}, metrics=metrics,
              checkpoint=Path("c.pt"), iteration=1, samples=10_000, train_seconds=100.0)  # fmt: skip
    supertrack = _run("supertrack", 0, [(100, 10.0, 500.0)])
    md = update_statistics_table([ppo, supertrack])
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in md.splitlines()[2:]]
    assert len(rows) == 1 and rows[0][0] == "ppo:ppo-0"  # SuperTrack logs no PPO statistics
    assert rows[0][1] == "0.075 (0.01 -> 0.1)"  # median of 0.05 ... 0.1
    assert rows[0][3] == "0.1 (0.5 -> 0.1)"
    assert rows[0][2] == "-"
    assert update_statistics_table([supertrack]) is None
