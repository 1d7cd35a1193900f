"""benchmarks/compare_trackers.py as a suite: two tiny debug runs per learner, two at a time, then the report."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from report.tables import fmt
from tests.benchmark_module import benchmark_module


def _suite_module():
    return benchmark_module("compare_trackers")


@pytest.fixture(scope="module")
def suite(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("suite")
    args = ["--debug", "--seeds", "2", "--minutes", "0.03", "--parallel", "2", "--no-render", "--out", str(out)]
    assert _suite_module().main(args) == 0
    return out


def _rows(md: str, heading: str) -> list[list[str]]:
    block = md.split(heading, 1)[1].split("\n\n", 2)[1]
    return [[c.strip() for c in line.strip("|").split("|")] for line in block.splitlines()[2:]]


def _mean_std(values: list[float]) -> str:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return "nan" if len(v) == 0 else f"{fmt(v.mean())} ± {fmt(v.std(ddof=1))} (n={len(v)})"


def test_suite_report_holds_the_evaluators_numbers_with_their_spread(suite: Path) -> None:
    results = json.loads((suite / "report" / "results.json").read_text())
    runs = {r["label"]: r for r in results["runs"]}
    assert sorted(runs) == ["ppo:ppo-s0", "ppo:ppo-s1", "supertrack:supertrack-s0", "supertrack:supertrack-s1"]
    # Two seeds of one learner are different runs.
    assert runs["ppo:ppo-s0"]["overall"]["mpjpe_g"] != runs["ppo:ppo-s1"]["overall"]["mpjpe_g"]
    md = (suite / "report" / "report.md").read_text()
    overall = {row[0]: row[1:] for row in _rows(md, "### Spread: mean over clips")}
    for col, learner in enumerate(("supertrack", "ppo")):
        seeds = [runs[f"{learner}:{learner}-s{s}"] for s in (0, 1)]
        for key in ("mpjpe_g", "mpjpe_l", "survival", "episode_len_ratio"):
            assert overall[key][col] == _mean_std([r["overall"][key] for r in seeds])
        for key in ("survival", "mpjpe_g"):
            assert overall[f"{key} under pushes"][col] == _mean_std([r["pushed"]["overall"][key] for r in seeds])
        per_clip = {(row[0], row[1]): row[2:] for row in _rows(md, "### Spread per clip")}
        for c, clip in enumerate(seeds[0]["clips"]):
            for key in ("mpjpe_g", "survival"):
                assert per_clip[(f"`{clip}`", key)][col] == _mean_std([r["per_clip"][key][c] for r in seeds])
    # The training logs' curves are kept beside the judge's figures (a later parity needs no run directory).
    for label, run in runs.items():
        log = suite / "runs" / label.split(":")[1] / "metrics.jsonl"
        logged = [json.loads(line) for line in log.read_text().splitlines()]
        logged = [m for m in logged if m.get("eval/mpjpe_g") is not None]
        assert logged, label
        assert run["curves"]["eval/mpjpe_g"] == {"samples": [m["samples"] for m in logged],
                                                 "seconds": [m["wall_clock_s"] for m in logged],
                                                 "values": [m["eval/mpjpe_g"] for m in logged]}  # fmt: skip
    assert (suite / "report" / "learning_curves.png").stat().st_size > 1000
    assert "## Robustness: pushes on the pelvis" in md


def test_finished_runs_are_reused_not_retrained(suite: Path, capsys: pytest.CaptureFixture[str]) -> None:
    logs = {p: p.read_text() for p in (suite / "runs").glob("*/metrics.jsonl")}
    assert len(logs) == 4
    module = _suite_module()
    args = ["--debug", "--seeds", "2", "--minutes", "0.03", "--parallel", "2", "--train-only", "--out", str(suite)]
    assert module.main(args) == 0
    assert capsys.readouterr().out.count("reused") == 4
    assert {p: p.read_text() for p in logs} == logs
    # Another budget is another command: the finished short runs are not taken for it (they resume instead).
    assert not module.finished(suite / "runs" / "ppo-s0", minutes=10.0)


def test_parallel_runs_get_one_core_each() -> None:
    module = _suite_module()
    args = module.build_parser().parse_args(["--suite", "locomotion", "--seeds", "2", "--parallel", "2", "--out", "x"])
    jobs = module.jobs(args, Path("x"))
    assert [(j.learner, j.seed) for j in jobs] == [("supertrack", 0), ("ppo", 0), ("supertrack", 1), ("ppo", 1)]
    for job in jobs:
        sets = [job.cmd[i + 1] for i, a in enumerate(job.cmd) if a == "--set"]
        assert {"gym.threads=1", "train.torch_threads=1", "train.eval.threads=1"} <= set(sets)
        motions = job.cmd[job.cmd.index("--motions") + 1 : job.cmd.index("--set")]
        assert motions == ["walk", "jog", "run", "stealthy_walk", "zombie_walk"]
    serial = module.jobs(module.build_parser().parse_args(["--suite", "walk", "--out", "x"]), Path("x"))
    assert not any("gym.threads=1" in a for a in serial[0].cmd)


def test_runs_on_other_clips_are_not_seeds_of_each_other() -> None:
    from report.runs import Run
    from report.runs import method_groups as _groups

    def run(learner: str, motions: list[str], name: str) -> Run:
        return Run(Path(name), f"{learner}:{name}", learner, {}, {"motions": motions}, [], Path("c"), 0, 0, 0.0)

    runs = [run("supertrack", ["walk"], "a"), run("samcon", ["walk"], "b"), run("samcon", ["run"], "c"),
            run("supertrack", ["walk"], "d")]  # fmt: skip
    assert _groups(runs) == {"supertrack": [0, 3], "samcon (walk)": [1], "samcon (run)": [2]}


def test_runs_of_other_configs_are_not_seeds_of_each_other() -> None:
    from report.runs import Run, method_groups

    def run(name: str, seed: int, lr: float, threads: int) -> Run:
        config = {"train": {"seed": seed, "torch_threads": threads}, "ppo": {"actor_lr": lr, "epochs": 5}}
        return Run(Path(name), f"ppo:{name}", "ppo", config, {"motions": ["walk"]}, [], Path("c"), 0, 0, 0.0)

    # seeds and thread counts do not make another method; the learning rate does, and names the group
    runs = [run("a", 0, 1e-4, 1), run("b", 0, 3e-5, 1), run("c", 1, 1e-4, 2), run("d", 1, 3e-5, 1)]
    assert method_groups(runs) == {"ppo [ppo.actor_lr=0.0001]": [0, 2], "ppo [ppo.actor_lr=3e-05]": [1, 3]}
    assert method_groups(runs[:1] + runs[2:3]) == {"ppo": [0, 1]}


def test_a_failed_run_stops_new_starts_but_lets_running_ones_finish(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    module = _suite_module()
    py = sys.executable
    fake = [module.Job("supertrack", 0, tmp_path / "a", [py, "-c", "import sys; sys.exit(3)"]),
            module.Job("ppo", 0, tmp_path / "b", [py, "-c", "import time; time.sleep(1.5)"]),
            module.Job("supertrack", 1, tmp_path / "c", [py, "-c", "pass"])]  # fmt: skip
    for job in fake:
        job.out.mkdir()
    monkeypatch.setattr(module, "jobs", lambda args, out: fake)
    args = module.build_parser().parse_args(["--debug", "--parallel", "2", "--out", str(tmp_path)])
    with pytest.raises(SystemExit, match="supertrack seed 0 exited with 3"):
        module.train_all(args, tmp_path)
    assert (tmp_path / "b" / module.COMMAND_FILE).exists()  # the run going at the failure finished
    assert not (tmp_path / "c" / module.COMMAND_FILE).exists()  # and nothing new started
    assert not (tmp_path / "logs" / "supertrack-s1.log").exists()


def test_the_generalisation_split_is_fixed_disjoint_and_covers_the_library() -> None:
    m = _suite_module()
    from common.motion.dataset import bundled_clip_names

    # Fixed: these lists are the protocol; changing them makes earlier split results incomparable.
    assert m.SPLIT_TEST == ["walk", "jog", "sideflip", "kick", "dance_b"]
    assert m.SUITES["split"] == m.SPLIT_TRAIN and "long" in m.SPLIT_TRAIN and len(m.SPLIT_TRAIN) == 16
    assert not set(m.SPLIT_TEST) & set(m.SPLIT_TRAIN)
    assert sorted(m.SPLIT_TEST + [c for c in m.SPLIT_TRAIN if c != "long"]) == bundled_clip_names()
    args = m.build_parser().parse_args(["--suite", "split", "--out", "x"])
    assert m.judged_motions(args) == [("report", m.SPLIT_TEST), ("report-train", m.SPLIT_TRAIN)]
    walk = m.build_parser().parse_args(["--suite", "walk", "--out", "x"])
    assert m.judged_motions(walk) == [("report", ["walk"])]


def test_an_oracle_is_checked_before_training_and_joins_every_report_with_the_options(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """--oracle: a missing or non-SAMCON run directory stops the suite before any run starts; a SAMCON one is handed
    to compare-trackers with the suite's runs, for each report of the split; the report options (--no-pushes,
    --video-clips) are handed on as given."""
    module = _suite_module()
    trained: list[bool] = []
    monkeypatch.setattr(module, "train_all", lambda args, out: trained.append(True) or [])
    with pytest.raises(SystemExit, match="--oracle .*nowhere"):
        module.main(["--out", str(tmp_path / "a"), "--oracle", str(tmp_path / "nowhere")])
    ppo_run = tmp_path / "ppo-run"
    ppo_run.mkdir()
    (ppo_run / "run_info.json").write_text(json.dumps({"learner": "ppo"}))
    import report.runs

    # A stand-in load_run that reads only the learner (a real run directory needs a trained run).
    monkeypatch.setattr(report.runs, "load_run", lambda d: type("R", (), {"learner": json.loads(
        (Path(d) / "run_info.json").read_text())["learner"]})())  # fmt: skip
    with pytest.raises(SystemExit, match="a ppo run, not a track-samcon run"):
        module.main(["--out", str(tmp_path / "a"), "--oracle", str(ppo_run)])
    assert not trained
    samcon_run = tmp_path / "samcon-run"
    samcon_run.mkdir()
    (samcon_run / "run_info.json").write_text(json.dumps({"learner": "samcon"}))
    calls: list[list[str]] = []
    monkeypatch.setattr(module, "compare_main", calls.append)
    assert module.main(["--suite", "split", "--out", str(tmp_path / "b"), "--oracle", str(samcon_run)]) == 0
    assert trained == [True] and len(calls) == 2  # report/ and report-train/
    assert all(call[0] == str(samcon_run) for call in calls)
    assert all("--video-clips" not in call for call in calls)  # compare-trackers' default: every clip
    calls.clear()
    assert module.main(["--suite", "all20", "--out", str(tmp_path / "c"), "--video-clips", "1", "--no-pushes"]) == 0
    assert calls == [["--out", str(tmp_path / "c" / "report"), "--motions", "all", "--no-pushes", "--video-clips", "1"]]
    trained.clear()
    with pytest.raises(SystemExit):  # refused by argparse, before anything trains
        module.main(["--suite", "all20", "--out", str(tmp_path / "d"), "--video-clips", "-1"])
    assert not trained


def _sets(cmd: list[str]) -> list[str]:
    return [cmd[i + 1] for i, a in enumerate(cmd) if a == "--set"]


def test_the_terrain_suite_trains_with_the_terrain_observation_and_the_flat_suites_as_before() -> None:
    m = _suite_module()
    parse = m.build_parser().parse_args
    args = parse(["--suite", "terrain", "--parallel", "2", "--minutes", "90", "--learners", "supertrack", "ppo",
                  "rsl_rl", "--set", "observation.contact_frames=[1]", "--out", "x"])  # fmt: skip
    jobs = {j.learner: j for j in m.jobs(args, Path("x"))}
    for job in jobs.values():
        assert job.cmd[job.cmd.index("--motions") + 1 : job.cmd.index("--set")] == ["terrain"]
    parc = ["observation.heightmap_extent=1.0", "observation.contact_frames=[1, 2, 4, 8, 16]"]
    assert _sets(jobs["ppo"].cmd)[:2] == parc and _sets(jobs["rsl_rl"].cmd)[:2] == parc
    assert _sets(jobs["supertrack"].cmd)[:3] == ["terrain.heightmap_extent=1.0", "terrain.contact_weight=1.0",
                                                 "terrain.contact_frames=[1, 2, 4, 8, 16]"]  # fmt: skip
    # The command's own --set comes after the suite's, so that it overrides them.
    assert _sets(jobs["ppo"].cmd)[2] == "observation.contact_frames=[1]"
    locomotion = ["walk", "jog", "run", "stealthy_walk", "zombie_walk"]
    assert m.judged_motions(args) == [("report", ["terrain"]), ("report-flat", locomotion)]
    # A flat suite's jobs are the commands they were before the terrain suite (written out by hand).
    flat = m.jobs(parse(["--suite", "locomotion", "--parallel", "2", "--minutes", "60", "--out", "x"]), Path("x"))
    config = str(m.ROOT / "configs" / "supertrack" / "default.yaml")
    assert flat[0].cmd == [sys.executable, "-m", "supertrack.train", "--config", config, "--out",
                           str(Path("x/runs/supertrack-s0")), "--seed", "0", "--max-minutes", "60.0", "--motions",
                           *locomotion, "--set", "train.eval_every_minutes=7.5", "--set", "gym.threads=1", "--set",
                           "train.torch_threads=1", "--set", "train.eval.threads=1"]  # fmt: skip
    everyone = ["--learners", "supertrack", "ppo", "rsl_rl", "--out", "x"]
    for suite in sorted(set(m.SUITES) - {"terrain"}):
        for job in m.jobs(parse(["--suite", suite, *everyone]), Path("x")):
            assert not any(s.startswith(("terrain.", "observation.")) for s in _sets(job.cmd)), (suite, job.cmd)


def test_other_suites_runs_are_judged_beside_the_suites(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """--also-judge: finished runs of another suite (the flat-trained locomotion runs) join every report of the suite;
    a SAMCON run is refused there (it is an --oracle), before anything trains."""
    module = _suite_module()
    import report.runs

    monkeypatch.setattr(module, "train_all", lambda args, out: [])
    monkeypatch.setattr(report.runs, "load_run", lambda d: type("R", (), {"learner": Path(d).name.split("-")[0]})())
    calls: list[list[str]] = []
    monkeypatch.setattr(module, "compare_main", calls.append)
    flat = [str(tmp_path / "supertrack-s0"), str(tmp_path / "ppo-s0")]
    assert module.main(["--suite", "terrain", "--out", str(tmp_path / "t"), "--also-judge", *flat, "--no-pushes"]) == 0
    assert [c[: c.index("--out")] for c in calls] == [flat, flat]
    locomotion = ["walk", "jog", "run", "stealthy_walk", "zombie_walk"]
    assert [c[c.index("--motions") + 1 :] for c in calls] == [["terrain", "--no-pushes"], [*locomotion, "--no-pushes"]]
    with pytest.raises(SystemExit, match="--also-judge .*samcon-run: a track-samcon run; give it with --oracle"):
        module.main(["--suite", "terrain", "--out", str(tmp_path / "u"), "--also-judge", str(tmp_path / "samcon-run")])
