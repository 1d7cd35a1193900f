"""``track-samcon`` end to end on the debug config: its run directory, the report reading it, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from report.compare import build_report
from report.runs import ReportError, load_run
from samcon.track import main

ROOT = Path(__file__).resolve().parents[2]
DEBUG = str(ROOT / "configs/samcon/debug.yaml")


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("samcon") / "run"
    main(["--config", DEBUG, "--out", str(out)])
    return out


def test_debug_run_writes_its_run_directory(run: Path) -> None:
    for name in ("config.yaml", "run_info.json", "results.json", "samcon.h5", "progress.log", "optimise.png"):
        assert (run / name).is_file(), name
    info = json.loads((run / "run_info.json").read_text())
    results = json.loads((run / "results.json").read_text())
    assert info["learner"] == "samcon" and info["policy_file"] == "samcon.h5" and info["motions"] == ["walk"]
    walk = results["clips"]["walk"]
    # Two segments of 3 frames, 8 samples x 2 rounds each, plus one refinement search of the same size, plus the
    # polish's search of the second segment.
    assert walk["frames"] == 6 and walk["samples"] == 2 * 2 * 8 * 2 + 2 * 8 == info["samples"]
    # The feedback's extra search from frame 3 (the only other segment start): one segment, counted apart.
    assert walk["feedback_search_samples"] == 1 * 2 * 8 and walk["feedback_search_minutes"] > 0
    log = (run / "progress.log").read_text()
    assert "walk: a search from frame 3 to 6 for the feedback regression" in log
    assert "walk segment 1/2" in log and "walk segment 2/2" in log
    assert "walk: visit round 1/1: 0% of 2 episodes fell; searches from 0 of their states" in log
    assert walk["visits"] == [{"round": 1, "fell": 0.0, "searches": 0}]
    # The closed-loop gain search of the debug config: 2 generations, 2 groups of 6 features x 10 actuators, and the
    # offsets of 2 actuators in each of the 2 segments.
    opt = walk["optimise"]
    assert opt["generation"] == [1, 2] and opt["parameters"] == 2 * 6 * 10 + 2 * 2 and opt["seconds"] > 0
    assert "walk: generation 2/2: cost best" in log
    import h5py

    with h5py.File(run / "samcon.h5") as f:
        assert f["clips/walk/ref_gain"].shape == (2, 28, 16) and float(f["clips/walk/ref_limit"][()]) == 0.5
        ref_offset = f["clips/walk/ref_offset"][()]
    assert ref_offset.shape == (2, 28) and np.count_nonzero(ref_offset[:, [14, 21]]) == 4  # right_hip_x, left_hip_x
    assert np.count_nonzero(ref_offset) == 4
    # The iLQR polish of the debug config: windows at frames 0 and 3, the second's searched anew from where the
    # first left the character (one segment, counted in the samples above); the stored targets are the polished
    # path's and replay to its stored segment-end states.
    polish = walk["polish"]
    assert [(w["first"], w["end"], w["searched"]) for w in polish["windows"]] == [(0, 3, False), (3, 6, True)]
    assert "walk: polished, cost" in log and polish["seconds"] > 0
    assert len(polish["passes"]) == 1 and polish["passes"][0]["kept"] == polish["kept"]
    from samcon.search import replay, start_state

    humanoid = Humanoid()
    with h5py.File(run / "samcon.h5") as f:
        targets, end_states = f["clips/walk/targets"][()], f["clips/walk/end_states"][()]
        start = f["clips/walk/start_state"][()]
    np.testing.assert_array_equal(start, start_state(load_motions(["walk"], humanoid), humanoid, 0))
    np.testing.assert_array_equal(replay(humanoid, start, targets)[[2, 5]], end_states)


def test_compare_trackers_reads_a_samcon_run(run: Path, tmp_path: Path) -> None:
    report = build_report([run], tmp_path / "report", max_frames=6, do_render=False)
    results = json.loads((run / "results.json").read_text())["clips"]["walk"]
    oracle, minutes = report.oracles[f"samcon:{run.name}"]
    # The report re-plays the stored open-loop trajectory: the same numbers the run measured.
    assert oracle.per_clip["mpjpe_g"][0] == pytest.approx(results["open_loop"]["mpjpe_g"], rel=1e-12)
    assert minutes["walk"] == pytest.approx(results["minutes"], rel=1e-9)
    assert report.results[0].per_clip["mpjpe_g"][0] == pytest.approx(results["feedback"]["mpjpe_g"], rel=1e-12)
    md = (tmp_path / "report" / "report.md").read_text()
    oracle_rows = md.split("## Oracle", 1)[1].split("\n\n")[1].splitlines()[2:]
    cells = [c.strip() for c in oracle_rows[0].strip("|").split("|")]
    assert cells[:2] == ["walk", f"samcon:{run.name}"] and cells[3] == "no"


def test_a_clips_search_does_not_depend_on_the_clips_before_it(run: Path, tmp_path: Path) -> None:
    """walk run second, after jump, gets the same trajectory and gains as walk alone (the module's run)."""
    import h5py

    main(["--config", DEBUG, "--out", str(tmp_path / "two"), "--motions", "jump", "walk"])
    with h5py.File(run / "samcon.h5") as alone, h5py.File(tmp_path / "two" / "samcon.h5") as two:
        assert list(two["clips"]) == ["jump", "walk"]
        for name in ("targets", "offsets", "gain", "bias"):
            np.testing.assert_array_equal(two["clips/walk"][name][()], alone["clips/walk"][name][()])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--set", "search.sampels=3"], "unknown key 'search.sampels'"),
        (["--motions", "nosuchclip"], "nosuchclip: no such motion file"),
        (["--set", "feedback.visit_lead=-1"], "visit_lead >= 0"),
        (["--set", "optimise.offsets=[knee]"], "optimise.offsets: no actuator 'knee'"),
        (["--set", "optimise.offset_sigma=0"], "offset_sigma > 0"),
        (["--set", "polish.follow=true"], "polish.search plays new frames from searches"),  # debug.yaml searches
        (["--set", "polish.follow=[true, false]"], "polish.follow: one value per pass (1)"),
    ],
)
def test_bad_input_is_refused_in_one_line(args: list[str], message: str, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    with pytest.raises(SystemExit) as exit_info:
        main(["--config", DEBUG, "--out", str(tmp_path / "run"), *args])
    text = str(exit_info.value)
    assert text.startswith("error: ") and message in text and "\n" not in text and exit_info.value.code == 2
    assert not (tmp_path / "run").exists()


def test_a_run_without_its_policy_file_is_refused(run: Path, tmp_path: Path) -> None:
    copy = tmp_path / "copy"
    copy.mkdir()
    for name in ("config.yaml", "run_info.json"):
        (copy / name).write_bytes((run / name).read_bytes())
    with pytest.raises(ReportError, match="unfinished run: no samcon.h5"):
        load_run(copy)


def test_nearest_anchor_run_stores_every_searched_path(tmp_path: Path) -> None:
    """``feedback.anchor=nearest`` searches and fits exactly as ``path`` (no refinement, whose guide differs) and
    adds the anchors of both searches (from frame 0 and from frame 3) to the file; the report evaluates the policy
    they make."""
    import h5py

    plain = ["--set", "feedback.refine_iterations=0", "--set", "lqr.enabled=false"]  # the regressed policy judged
    path_run, out = tmp_path / "path", tmp_path / "nearest"
    main(["--config", DEBUG, "--out", str(path_run), *plain])
    main(["--config", DEBUG, "--out", str(out), *plain, "--set", "feedback.anchor=nearest"])
    with h5py.File(path_run / "samcon.h5") as path, h5py.File(out / "samcon.h5") as nearest:
        for name in ("targets", "gain", "bias"):
            np.testing.assert_array_equal(nearest["clips/walk"][name][()], path["clips/walk"][name][()])
        assert "anchor_features" not in path["clips/walk"]
        feats, offs = nearest["clips/walk/anchor_features"][()], nearest["clips/walk/anchor_offsets"][()]
        assert feats.shape[:2] == (2, 2) and offs.shape[:2] == (2, 2)
        # Path 0 is the search from the clip's start; path 1 starts at frame 3, segment 1, on the reference.
        np.testing.assert_array_equal(offs[:, 0], nearest["clips/walk/offsets"][()])
        assert np.isnan(feats[0, 1]).all() and not np.isnan(feats[1, 1]).any()
    results = json.loads((out / "results.json").read_text())["clips"]["walk"]
    report = build_report([out], tmp_path / "report", max_frames=6, do_render=False)
    assert report.results[0].per_clip["mpjpe_g"][0] == pytest.approx(results["feedback"]["mpjpe_g"], rel=1e-12)
    # The same gains on the first path alone are the path-anchored run, figure for figure.
    path_results = json.loads((path_run / "results.json").read_text())["clips"]["walk"]["feedback"]
    for key in ("mpjpe_g", "mpjpe_l", "survival"):
        assert results["feedback_path_anchor"][key] == pytest.approx(path_results[key], rel=1e-12)


def test_nearest_refinement_adds_each_guided_search_as_an_anchor_path(tmp_path: Path) -> None:
    import h5py

    out = tmp_path / "refined"
    main(["--config", DEBUG, "--out", str(out), "--set", "feedback.anchor=nearest", "--set",
          "feedback.refine_iterations=2"])  # fmt: skip
    with h5py.File(out / "samcon.h5") as f:
        # The search from frame 0, the one from frame 3 and the 2 guided searches from frame 0.
        feats = f["clips/walk/anchor_features"][()]
        assert feats.shape[:2] == (2, 4)
        assert not np.isnan(feats[:, [0, 2, 3]]).any() and np.isnan(feats[0, 1]).all()


def test_phase_indexed_feedback_run_fits_and_stores_a_policy_per_segment_of_the_cycle(tmp_path: Path) -> None:
    """Walk's 76-frame cycle in 2 segments of 38 frames (``search.align_cycle``), tracked over 160 frames (grid 0, 38,
    76, 114, 152, 160): one policy per phase, anchored on every cycle of both searches; the report evaluates it."""
    import h5py

    out = tmp_path / "phase"
    sets = ["train.max_frames=160", "train.eval.max_frames=160", "search.segment_frames=38", "search.align_cycle=true",
            "feedback.index=phase", "feedback.anchor=nearest", "feedback.refine_iterations=0",
            "feedback.start_segments=1"]  # fmt: skip
    main(["--config", DEBUG, "--out", str(out), *(a for s in sets for a in ("--set", s))])
    with h5py.File(out / "samcon.h5") as f:
        g = f["clips/walk"]
        np.testing.assert_array_equal(g["bounds"][()], [0, 38, 76, 114, 152, 160])
        np.testing.assert_array_equal(g["plan_bounds"][()], [0, 38, 76])
        assert g["gain"].shape[0] == 2 and g["bias"].shape[0] == 2
        # Columns p Q + q: Q = 3 cycles; the search from the start in cycles 0-2, the later one (frame 38, one
        # segment) in cycle 0 at phase 1 alone.
        feats, offs = g["anchor_features"][()], g["anchor_offsets"][()]
        assert feats.shape[:2] == (2, 6)
        np.testing.assert_array_equal(offs[:, 0], g["offsets"][:2])
        np.testing.assert_array_equal(offs[:, 1], g["offsets"][2:4])
        np.testing.assert_array_equal(offs[0, 2], g["offsets"][4])
        assert np.isnan(feats[1, 2]).all() and not np.isnan(feats[1, 3]).any() and np.isnan(feats[0, 3]).all()
    log = (out / "progress.log").read_text()
    assert "a search from frame 38 to 76 for the feedback regression" in log
    results = json.loads((out / "results.json").read_text())["clips"]["walk"]
    report = build_report([out], tmp_path / "report", max_frames=160, do_render=False)
    assert report.results[0].per_clip["mpjpe_g"][0] == pytest.approx(results["feedback"]["mpjpe_g"], rel=1e-12)


def test_phase_index_without_aligned_segments_is_refused(tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--config", DEBUG, "--out", str(tmp_path / "run"), "--set", "feedback.index=phase"])
    assert "needs search.align_cycle: true" in str(exit_info.value) and exit_info.value.code == 2
    assert not (tmp_path / "run").exists()


def test_sigma_choices_keep_the_cheaper_search(tmp_path: Path) -> None:
    out = tmp_path / "choices"
    main(["--config", DEBUG, "--out", str(out), "--set", "search.sigma_choices=[0.02, 0.5]", "--set",
          "feedback.refine_iterations=0", "--set", "feedback.starts=0", "--set", "polish.iterations=0"])  # fmt: skip
    log = (out / "progress.log").read_text()
    line = next(x for x in log.splitlines() if "kept the search at sigma" in x)
    entries = dict(pair.split(": ", 1) for pair in line.split("by sigma: ")[1][:-1].split(", "))
    assert set(map(float, entries)) == {0.02, 0.5}
    row = json.loads((out / "results.json").read_text())["clips"]["walk"]
    first = float(entries["0.02"])
    if entries["0.5"].startswith("abandoned"):  # stopped once dearer than the first: the first is kept
        kept, total = 0.02, first
    else:
        kept, total = min((first, 0.02), (float(entries["0.5"]), 0.5))[::-1]
    assert row["sigma_init"] == kept and f"kept the search at sigma {kept:g}" in line
    assert row["cost_total"] == pytest.approx(total, rel=1e-12)


@pytest.mark.parametrize("path", sorted((ROOT / "configs/samcon").glob("*.yaml")), ids=lambda p: p.name)
def test_every_samcon_config_loads_and_names_real_features_and_actuators(path: Path) -> None:
    from common.character.humanoid import Humanoid
    from common.config import load_config
    from samcon.config import SamconConfig
    from samcon.optimise import reduced_indices

    cfg = load_config(SamconConfig, str(path), [])
    features, actuators, offsets = reduced_indices(Humanoid(cfg.gym.physics), cfg.optimise)
    assert len(features) == len(cfg.optimise.features) and len(actuators) == len(cfg.optimise.actuators)
    assert len(offsets) == len(cfg.optimise.offsets)


def test_feedback_walk_config_is_the_default_but_for_its_experiment() -> None:
    """feedback-walk.yaml names default.yaml as its base: it is the default but for its experiment's keys (a partial
    copy without a base took the dataclass defaults, ran without the look-ahead and fell 40 times)."""
    from dataclasses import asdict

    from common.config import load_config
    from samcon.config import SamconConfig

    default = asdict(load_config(SamconConfig, str(ROOT / "configs/samcon/default.yaml"), []))
    walk = asdict(load_config(SamconConfig, str(ROOT / "configs/samcon/feedback-walk.yaml"), []))
    sections = [sec for sec in default if sec != "optimise"]
    changed = {(sec, k) for sec in sections for k in default[sec] if default[sec][k] != walk[sec][k]}
    assert changed == {("train", "eval"), ("search", "sigma_init"), ("search", "align_cycle"), ("feedback", "anchor"),
                       ("feedback", "starts"), ("feedback", "start_segments"), ("feedback", "index"),
                       ("feedback", "refine_iterations"), ("lqr", "enabled")}  # fmt: skip
    assert walk["train"]["eval"] == {**default["train"]["eval"], "starts_per_clip": 16}


def test_visited_states_are_where_the_policy_was_before_it_fell() -> None:
    """The reference's own angles (a plan with no offsets) fall on walk within 120 frames: every episode's state at
    the last segment start at least visit_lead frames before its failure is returned, and it is the gym's state
    there (re-simulated step by step); a search started from it starts there and replays bit-exactly."""
    from common.character.humanoid import Humanoid
    from common.evaluation.evaluate import EvalConfig
    from common.motion.dataset import load_motions
    from common.sim.gym import GymConfig, TrackingGym
    from samcon.config import CostConfig, FeedbackConfig, SearchConfig
    from samcon.cost import FEATURE_NAMES
    from samcon.feedback import ClipPlan, FeedbackPolicy
    from samcon.search import replay, samcon
    from samcon.track import visited_states

    humanoid = Humanoid()
    library = load_motions(["walk"], humanoid)
    grid = np.arange(0, 181, 6)
    d = len(FEATURE_NAMES)
    plan = ClipPlan(np.zeros((180, humanoid.nu)), grid, np.zeros((30, humanoid.nu, d)), np.zeros((30, humanoid.nu)))
    fb = FeedbackConfig(visit_episodes=2, visit_frames=170, visit_lead=12)
    ev = EvalConfig(threads=1)
    # Two episodes over two start segments: one from frame 0, one from frame 6.
    visits, share = visited_states(plan, "walk", library, humanoid, grid, 12, 1, fb, ev, np.random.default_rng(0))
    assert share == 1.0 and len(visits) == 2
    # Re-simulated: each episode to its failure, and its states on the grid.
    gym = TrackingGym(GymConfig(num_envs=2, threads=1, seed=ev.seed, physics=humanoid.physics,
                                termination=ev.termination), library, humanoid)  # fmt: skip
    policy = FeedbackPolicy({"walk": plan}, library, humanoid)
    result = gym.reset(clips=np.zeros(2, dtype=np.int64), times=np.array([0.0, 6.0]) * library.dt)
    seen, fail = [{0: gym.sim.state[0].copy()}, {6: gym.sim.state[1].copy()}], [None, None]
    for step in range(1, 171):
        result = gym.step(policy(result), autoreset=False)
        for i, first in enumerate((0, 6)):
            if fail[i] is None:
                seen[i][first + step] = gym.sim.state[i].copy()
                fail[i] = first + step if result.terminated[i] else None
    gym.close()
    assert None not in fail
    owners = set()
    for frame, state in visits:
        # The episode whose state it is: the last segment start at least 12 frames before that episode's failure.
        match = [j for j in (0, 1) if frame % 6 == 0 and frame <= fail[j] - 12 < frame + 6
                 and frame in seen[j] and np.array_equal(state, seen[j][frame])]  # fmt: skip
        assert len(match) >= 1
        owners.update(match)
    assert owners == {0, 1}
    frame, state = visits[0]
    search = SearchConfig(segment_frames=6, samples=6, iterations=1, keep=2, elite=2)
    path = samcon(humanoid, library, 0, 180, search, CostConfig(), np.random.default_rng(1), start_frame=frame,
                  end_frame=frame + 6, start=state)  # fmt: skip
    np.testing.assert_array_equal(path.start_state, state)
    np.testing.assert_array_equal(replay(humanoid, state, path.targets)[-1], path.end_states[-1])
    assert np.abs(path.features[0]).max() > 0.05  # the policy's state, not the reference's (features 0 there)


def test_oracle_config_is_the_default_but_for_its_search_cost_and_polish() -> None:
    from dataclasses import asdict

    from common.config import load_config
    from samcon.config import SamconConfig

    default = asdict(load_config(SamconConfig, str(ROOT / "configs/samcon/default.yaml"), []))
    oracle = asdict(load_config(SamconConfig, str(ROOT / "configs/samcon/oracle.yaml"), []))
    changed = {(sec, k) for sec in default for k in default[sec] if default[sec][k] != oracle[sec][k]}
    assert changed == {("search", "iterations"), ("search", "sigma_choices"), ("cost", "body_pos"),
                       ("feedback", "refine_iterations")}  # fmt: skip
    assert oracle["search"]["iterations"] == 4 and oracle["cost"]["body_pos"] == 100.0


def test_polish_config_is_the_default_but_for_its_polish() -> None:
    from dataclasses import asdict

    from common.config import load_config
    from samcon.config import SamconConfig

    default = asdict(load_config(SamconConfig, str(ROOT / "configs/samcon/default.yaml"), []))
    polish = asdict(load_config(SamconConfig, str(ROOT / "configs/samcon/polish.yaml"), []))
    changed = {sec for sec in default for k in default[sec] if default[sec][k] != polish[sec][k]}
    assert changed == {"polish"} and default["polish"]["iterations"] == 0
    assert polish["polish"]["iterations"] == 10 and polish["polish"]["window"] == 60
