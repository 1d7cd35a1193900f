"""The comparison report built from two tiny debug runs (SuperTrack and PPO, a few seconds each)."""

from __future__ import annotations

import importlib
import json
import re
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from common.character.humanoid import Humanoid
from common.evaluation import metrics as M
from common.evaluation.evaluate import evaluate
from common.motion.dataset import bundled_motion_dir, load_motions
from common.motion.terrain import write_sidecar
from common.motion.terrain_generator import stairs
from common.run.logs import read_metrics
from ppo.train import main as train_ppo
from report.compare import PUSHES, Report, build_report, main
from report.runs import ReportError, export_module, load_run
from supertrack.train import run as train_supertrack

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    torch.set_num_threads(1)
    base = tmp_path_factory.mktemp("runs")
    train_supertrack(["--config", str(ROOT / "configs/supertrack/debug.yaml"), "--out", str(base / "st")])
    train_ppo(["--config", str(ROOT / "configs/ppo/debug.yaml"), "--out", str(base / "ppo")])
    return {"supertrack": base / "st", "ppo": base / "ppo"}


@pytest.fixture(scope="module")
def report(runs: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Report:
    out = tmp_path_factory.mktemp("report")
    return build_report([runs["supertrack"], runs["ppo"]], out, do_render=False)


def _markdown_table(md: str, heading: str) -> dict[str, list[float]]:
    """{metric: [value per run]} of the table under ``heading``."""
    block = md.split(heading, 1)[1].split("\n\n", 2)[1]
    rows = {}
    for line in block.splitlines()[2:]:
        cells = [c.strip().strip("*") for c in line.strip("|").split("|")]
        rows[cells[0].split(" ")[0].rstrip(",")] = [float(c) for c in cells[1:]]
    return rows


def test_tables_hold_the_evaluators_numbers(runs: dict[str, Path], report: Report) -> None:
    md = (report.files["markdown"]).read_text()
    overall = _markdown_table(md, "#### Mean over clips")
    per_clip = _markdown_table(md, "#### Clip `walk`")
    assert list(overall) == list(M.METRIC_NAMES)
    for col, name in enumerate(("supertrack", "ppo")):
        run = load_run(runs[name])
        humanoid = Humanoid(run.physics())
        library = load_motions(["walk"], humanoid)
        policy = export_module(name).load_eval_policy(run.path, run.checkpoint, humanoid, library)
        fresh = evaluate(policy, library, humanoid, run.eval_config())
        # The trainer evaluated the live learner at the end of training: the exported policy must act identically.
        logged = read_metrics(run.path)[-1]
        assert fresh.overall["mpjpe_g"] == pytest.approx(logged["eval/mpjpe_g"], rel=1e-9)
        for key in M.METRIC_NAMES:  # the success-only figures are NaN where no episode succeeded
            assert overall[key][col] == pytest.approx(fresh.overall[key], rel=1e-5, abs=1e-12, nan_ok=True)
            assert per_clip[key][col] == pytest.approx(fresh.per_clip[key][0], rel=1e-5, abs=1e-12, nan_ok=True)
            assert fresh.overall[key] == pytest.approx(logged[f"eval/{key}"], rel=1e-9, abs=1e-12, nan_ok=True)
        pushed = evaluate(policy, library, humanoid, replace(run.eval_config(), pushes=PUSHES))
        section = md.split("## Robustness: pushes on the pelvis", 1)[1]
        walk_row = next(line for line in section.splitlines() if line.startswith("| `walk`"))
        survival, mpjpe = (float(x) for x in walk_row.strip("|").split("|")[1 + col].split("/"))
        assert survival == pytest.approx(pushed.per_clip["survival"][0], rel=1e-5)
        assert mpjpe == pytest.approx(pushed.per_clip["mpjpe_g"][0], rel=1e-5)
        assert 0 < fresh.overall["mpjpe_g"] < 1000


def test_best_per_row_is_marked(report: Report) -> None:
    md = report.files["markdown"].read_text()
    row = next(line for line in md.splitlines() if line.startswith("| mpjpe_g"))
    values = [float(c.strip().strip("*")) for c in row.strip("|").split("|")[1:]]
    bold = [c.strip().startswith("**") for c in row.strip("|").split("|")[1:]]
    assert bold == [v == min(values) for v in values] or values[0] == values[1]


def test_report_files_and_sections(report: Report) -> None:
    md = report.files["markdown"].read_text()
    for section in ("Learning curves", "Samples and wall-clock to reach thresholds", "World-model diagnostics",
                    "Filmstrips", "Runs: machine, versions, seeds", "Configs",
                    "Samples and wall-clock to reach the other method's final MPJPE-g"):  # fmt: skip
        assert section in md
    assert "switched off with --no-render" in md
    # World-model errors come from SuperTrack's log, at every horizon it logged.
    wm = {int(h) for h in re.findall(r"\| supertrack:st \| (\d+) \|", md)}
    assert wm == {1, 8, 32}
    page = report.files["html"].read_text()
    assert page.count("data:image/png;base64,") == 2  # curves + world model, embedded
    assert 'src="learning_curves.png"' not in page
    results = json.loads(report.files["results"].read_text())
    assert [r["learner"] for r in results["runs"]] == ["supertrack", "ppo"]
    assert report.files["curves"].stat().st_size > 1000


def test_thresholds_come_from_the_logged_curve(runs: dict[str, Path], report: Report) -> None:
    md = report.files["markdown"].read_text()
    rows = [line for line in md.splitlines() if line.startswith("| ppo:ppo |") and "samples" in line]
    first = next(m for m in read_metrics(runs["ppo"]) if "eval/survival" in m and m["eval/survival"] >= 0.9)
    assert rows and f"{first['samples']:,} samples" in rows[0].split("|")[2]


def test_bad_directories_are_named(runs: dict[str, Path], tmp_path: Path) -> None:
    with pytest.raises(ReportError, match="not a run directory"):
        load_run(tmp_path)
    unfinished = tmp_path / "unfinished"
    shutil.copytree(runs["ppo"], unfinished)
    shutil.rmtree(unfinished / "checkpoints")
    with pytest.raises(ReportError, match="unfinished run"):
        load_run(unfinished)
    with pytest.raises(ReportError, match="no checkpoint of iteration 999"):
        load_run(runs["ppo"], iteration=999)
    with pytest.raises(SystemExit, match="unfinished"):
        main([str(runs["ppo"]), str(unfinished), "--out", str(tmp_path / "r"), "--no-render"])


def test_a_run_naming_an_unknown_learner_is_refused_in_one_line_without_any_import(
        runs: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    foreign = tmp_path / "foreign"
    shutil.copytree(runs["ppo"], foreign)
    info = json.loads((foreign / "run_info.json").read_text())
    (foreign / "run_info.json").write_text(json.dumps({**info, "learner": "os"}))  # an importable module's name
    imported: list[str] = []
    real_import = importlib.import_module
    monkeypatch.setattr(importlib, "import_module", lambda name, *a: imported.append(name) or real_import(name, *a))
    with pytest.raises(ReportError, match="unknown learner 'os'"):
        load_run(foreign)
    with pytest.raises(ReportError, match="unknown learner 'os'"):
        export_module("os")
    with pytest.raises(SystemExit) as stop:
        main([str(foreign), "--out", str(tmp_path / "r"), "--no-render"])
    assert "unknown learner 'os'" in str(stop.value) and "\n" not in str(stop.value)
    assert imported == [] and not (tmp_path / "r").exists()


def test_mixed_training_motion_sets_are_reported(runs: dict[str, Path], tmp_path: Path) -> None:
    other = tmp_path / "other"
    shutil.copytree(runs["ppo"], other)
    info = json.loads((other / "run_info.json").read_text())
    info["motions"] = ["run"]
    (other / "run_info.json").write_text(json.dumps(info))
    report = build_report([runs["ppo"], other], tmp_path / "r", do_render=False)
    md = report.files["markdown"].read_text()
    assert "TRAINED on different motion sets" in md
    # Same checkpoint, same protocol: identical numbers under two labels.
    a, b = report.results
    assert np.array_equal(a.per_clip["mpjpe_g"], b.per_clip["mpjpe_g"])
    assert [r.label for r in report.runs] == ["ppo:ppo", "ppo:other"]


def test_a_report_on_a_terrain_clip(runs: dict[str, Path], tmp_path: Path) -> None:
    """Runs trained on the flat floor, re-evaluated on a clip on stairs from the terrain generator (a DeepMimic
    ``.txt`` and its sidecar) beside the flat clip, pushes included: the report runs as it does on flat clips, and
    the flat clip's figures are those of a report without the terrain clip (to the policies' rounding: a network's
    matrix products round differently over a batch of 8 episodes than of 4, 1e-9 of MPJPE-g here)."""
    clip = tmp_path / "walk_up.txt"
    shutil.copy(bundled_motion_dir() / "humanoid3d_walk.txt", clip)
    write_sidecar(clip, stairs("up", steps=4, step_height=0.08, seed=0))
    both = build_report([runs["supertrack"], runs["ppo"]], tmp_path / "r", motions=["walk", str(clip)],
                        max_frames=40, do_render=False)  # fmt: skip
    alone = build_report([runs["supertrack"], runs["ppo"]], tmp_path / "flat", motions=["walk"], max_frames=40,
                         do_render=False, pushes=False)  # fmt: skip
    assert len(both.pushed) == 2 and both.results[0].clips == ["walk", "walk_up"]
    for result in both.results + both.pushed:
        assert np.isfinite(result.per_clip["mpjpe_g"]).all() and np.isfinite(result.per_clip["survival"]).all()
    for a, b in zip(both.results, alone.results, strict=True):
        for key in M.METRIC_NAMES:
            assert a.per_clip[key][0] == pytest.approx(b.per_clip[key][0], rel=1e-6, abs=1e-9, nan_ok=True), key
    assert "walk_up" in both.files["markdown"].read_text()


def test_filmstrip_or_reason(runs: dict[str, Path], tmp_path: Path) -> None:
    report = build_report([runs["supertrack"]], tmp_path / "r", max_frames=12)
    md = report.files["markdown"].read_text()
    strips = list((tmp_path / "r").glob("filmstrip_*.png"))
    if strips:
        assert "![supertrack:st walk](filmstrip_supertrack_st_walk.png)" in md
        assert strips[0].stat().st_size > 1000
    else:
        assert "Filmstrips were not rendered" in md


def test_video_per_method_and_clip_or_reason(runs: dict[str, Path], tmp_path: Path) -> None:
    report = build_report([runs["supertrack"], runs["ppo"]], tmp_path / "r", max_frames=12, render_clips=0,
                          pushes=False, video_clips=1)  # fmt: skip
    md = report.files["markdown"].read_text()
    videos = sorted(p.name for p in (tmp_path / "r").glob("video_*.mp4"))
    if videos:
        assert videos == ["video_ppo_ppo_walk.mp4", "video_supertrack_st_walk.mp4"]
        assert "- [supertrack:st on walk](video_supertrack_st_walk.mp4)" in md
        assert (tmp_path / "r" / videos[0]).read_bytes()[4:8] == b"ftyp"  # an MP4 container
        assert '<a href="video_ppo_ppo_walk.mp4">' in report.files["html"].read_text()
    else:
        assert "Videos were not rendered" in md


def test_film_order_spreads_over_the_first_runs_errors() -> None:
    from report.compare import film_order

    mpjpe = np.array([300.0, 50.0, 900.0, 120.0, 60.0])  # ranked: 1 (50), 4, 3, 0, 2 (900)
    assert film_order(mpjpe, 1) == [1]
    assert film_order(mpjpe, 2) == [1, 2]
    assert film_order(mpjpe, 3) == [1, 2, 3]  # best, worst, median
    assert film_order(mpjpe, 5) == [1, 2, 4, 3, 0]
    assert film_order(mpjpe, 9) == [1, 2, 4, 3, 0] and film_order(mpjpe, 0) == []


def test_motion_union_loads_a_clip_once_when_a_run_trained_on_all() -> None:
    from report.compare import motion_union

    assert motion_union([["walk"], ["run", "walk"]]) == ["walk", "run"]
    # A run on every clip beside runs on a few: "all" holds walk and run already.
    assert motion_union([["all"], ["walk", "run"], ["my_take.txt"]]) == ["all", "my_take.txt"]
    assert motion_union([["walk"], ["all"]]) == ["all"]
    # "terrain" holds the terrain suite's clips: a run on walk_stairs beside one on the suite, and flat walk kept.
    assert motion_union([["walk_stairs", "walk"], ["terrain"]]) == ["walk", "terrain"]
