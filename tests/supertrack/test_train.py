"""End-to-end tests of ``train-supertrack`` on the debug preset: checkpoint, exact resume, evaluation, bad input."""

from __future__ import annotations

import json
import math
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from common.character.humanoid import Humanoid
from common.config import load_config
from common.motion.dataset import load_motions
from common.run.directory import read_checkpoint
from common.run.logs import read_metrics
from supertrack.config import SuperTrackConfig
from supertrack.export import load_eval_policy
from supertrack.learner import SuperTrackLearner
from supertrack.train import build_parser, run

DEBUG = str(Path(__file__).resolve().parents[2] / "configs" / "supertrack" / "debug.yaml")
COMPARED = ("losses/", "charts/", "eval/", "world_model/")


def _train(out: Path, *extra: str) -> None:
    run(["--config", DEBUG, "--out", str(out), *extra])


def _compared(record: dict) -> dict:
    return {k: v for k, v in record.items() if k.startswith(COMPARED)}


def _line(records: list[dict], iteration: int, key: str) -> dict:
    return next(r for r in records if r["iteration"] == iteration and key in r)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Run a: 6 iterations straight. Run b: 3 iterations, then resumed to 6 with only --out and --resume (no
    --config: the run's own config.yaml, not the command's default)."""
    root = tmp_path_factory.mktemp("supertrack")
    _train(root / "a")
    _train(root / "b", "--max-iterations", "3")
    run(["--out", str(root / "b"), "--resume", "--max-iterations", "6"])
    return {"a": root / "a", "b": root / "b"}


def test_debug_run_writes_config_metrics_checkpoint_and_evaluates(runs: dict[str, Path]) -> None:
    a = runs["a"]
    assert (a / "config.yaml").is_file() and (a / "checkpoints" / "latest.json").is_file()
    records = read_metrics(a / "metrics.jsonl")
    final = records[-1]
    assert final["iteration"] == 6
    assert 0.0 <= final["eval/survival"] <= 1.0 and final["eval/mpjpe_g"] > 0.0
    for h in (1, 8, 32):
        assert final[f"world_model/val_pos_err_h{h}"] > 0.0
    losses = _line(records, 6, "losses/policy")
    assert math.isfinite(losses["losses/world_model"]) and math.isfinite(losses["losses/policy"])
    assert losses["perf/samples_per_s"] > 0.0 and "perf/world_model_step_s" in losses
    state = read_checkpoint(a)[1]
    learner = state["learner"]
    for key in ("world_model", "policy", "world_optimizer", "policy_optimizer", "collector", "train_buffer",
                "val_buffer"):
        assert key in learner
    assert "local_norm.mean" in learner["world_model"] and state["iteration"] == 6


def test_same_seed_gives_identical_runs(runs: dict[str, Path]) -> None:
    a, b = (read_metrics(runs[k] / "metrics.jsonl") for k in ("a", "b"))
    assert _compared(_line(a, 2, "losses/policy")) == _compared(_line(b, 2, "losses/policy"))


def test_resume_continues_exactly(runs: dict[str, Path]) -> None:
    a, b = (read_checkpoint(runs[k])[1] for k in ("a", "b"))
    assert a["iteration"] == b["iteration"] == 6 and a["samples"] == b["samples"]
    for net in ("world_model", "policy"):
        for name, value in a["learner"][net].items():
            assert torch.equal(value, b["learner"][net][name]), f"{net}.{name} differs after resume"
    ma, mb = (read_metrics(runs[k] / "metrics.jsonl") for k in ("a", "b"))
    assert _compared(_line(ma, 6, "losses/policy")) == _compared(_line(mb, 6, "losses/policy"))
    assert _compared(ma[-1]) == _compared(mb[-1])
    # Evaluations stay on the straight run's grid (every 4 iterations): the resumed run (from 3, whose end evaluated
    # too) is evaluated at 4 as well, not first at 3 + 4.
    evaluated = [[r["iteration"] for r in m if "eval/mpjpe_g" in r] for m in (ma, mb)]
    assert evaluated == [[4, 6], [3, 4, 6]]


def test_resume_with_another_config_fails_clearly(runs: dict[str, Path]) -> None:
    with pytest.raises(SystemExit, match=r"(?s)incompatible.*policy\.lr: saved 0.0001, current 0.5"):
        _train(runs["b"], "--resume", "--set", "policy.lr=0.5")


def test_resume_from_a_damaged_checkpoint_names_it_and_keeps_it(runs: dict[str, Path], tmp_path: Path) -> None:
    run = tmp_path / "damaged"
    shutil.copytree(runs["b"], run)
    path, state = read_checkpoint(run)  # the newest numbered one is read first
    rows = state["learner"]["train_buffer"]["rows"]
    rows["sim"] = rows["sim"][:, :, :3]
    torch.save(state, path)
    # Without latest.json's digests the edited file reads (with them it would be passed over as damaged).
    (run / "checkpoints" / "latest.json").unlink()
    before = path.read_bytes()
    with pytest.raises(SystemExit, match=rf"(?s)checkpoint .*{path.name}: cannot restore the learner: .*field 'sim'"):
        _train(run, "--resume")
    assert path.read_bytes() == before


def test_unknown_config_key_fails_with_its_name(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="unknown key 'policy.lrr'"):
        _train(tmp_path / "x", "--set", "policy.lrr=1")


@pytest.mark.parametrize(("value", "message"), [
    ("-1", r"collect\.steps_per_iteration must be >= 1, warmup_steps >= 0 and processes >= 0"),
    ("7", r"collect\.processes \(7\) exceeds gym\.num_envs \(6\)"),
])  # fmt: skip
def test_a_bad_collector_count_fails_with_its_name(tmp_path: Path, value: str, message: str) -> None:
    with pytest.raises(SystemExit, match=message):
        _train(tmp_path / "x", "--set", f"collect.processes={value}")
    assert not (tmp_path / "x" / "checkpoints").exists()


@pytest.mark.parametrize(("key", "value", "message"), [
    ("policy.step_decay", "1.5", r"policy\.step_decay must be in \(0, 1\], got 1\.5"),
    ("policy.average_decay", "1.0", r"policy\.average_decay must be in \[0, 1\), got 1\.0"),
])  # fmt: skip
def test_an_out_of_range_decay_fails_with_its_name(tmp_path: Path, key: str, value: str, message: str) -> None:
    with pytest.raises(SystemExit, match=message):
        _train(tmp_path / "x", "--set", f"{key}={value}")
    assert not (tmp_path / "x" / "checkpoints").exists()


def test_clip_weights_reach_the_gym_and_a_wrong_clip_name_fails_with_the_file_and_key(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match=r"debug\.yaml: collect\.clip_weights: clip weight for 'wlak': no such clip"):
        _train(tmp_path / "x", "--motions", "walk", "run", "--set", "collect.clip_weights={wlak: 10}")
    assert not (tmp_path / "x").exists()  # refused before the run directory is made: a corrected retry can use it
    weights = "collect.clip_weights={walk: 10}"
    _train(tmp_path / "y", "--motions", "walk", "run", "--max-iterations", "1", "--set", weights)
    gym = read_checkpoint(tmp_path / "y")[1]["learner"]["collector"]["sources"][0]["gym"]
    np.testing.assert_array_equal(gym["clip_weights"], [10.0, 1.0])


def test_init_from_starts_a_new_run_from_another_runs_networks(runs: dict[str, Path], tmp_path: Path) -> None:
    source = read_checkpoint(runs["a"])[1]
    _train(tmp_path / "ft", "--motions", "run", "--init-from", str(runs["a"]), "--max-iterations", "2",
           "--set", "world_model.lr=0", "--set", "policy.lr=0")  # fmt: skip
    info = json.loads((tmp_path / "ft" / "run_info.json").read_text())
    assert info["init_from"].endswith("ckpt_00000006.pt") and info["init_iteration"] == 6
    tuned = read_checkpoint(tmp_path / "ft")[1]
    assert tuned["iteration"] == 2  # a new run: its own counters
    for net in ("world_model", "policy"):  # learning rate 0: the weights and normalisers are the source's, unchanged
        for k, v in source["learner"][net].items():
            torch.testing.assert_close(tuned["learner"][net][k], v)
    assert tuned["learner"]["policy_average"]["updates"] == 1  # restarted from the loaded policy (1 policy step)
    for k, v in source["learner"]["policy"].items():
        torch.testing.assert_close(tuned["learner"]["policy_average"]["module"][k], v)


@pytest.mark.parametrize(("extra", "message"), [
    (("--set", "policy.hidden=[16]"), r"policy\.hidden is \[32, 32\] there and \[16\] here"),
    (("--resume",), r"use one or the other"),
])  # fmt: skip
def test_init_from_a_checkpoint_that_does_not_fit_is_refused_before_anything_is_written(
    runs: dict[str, Path], tmp_path: Path, extra: tuple[str, ...], message: str
) -> None:
    with pytest.raises(SystemExit, match=message):
        _train(tmp_path / "ft", "--init-from", str(runs["a"] / "checkpoints" / "ckpt_00000006.pt"), *extra)
    assert not (tmp_path / "ft").exists()


def test_init_from_something_that_is_not_a_supertrack_checkpoint_names_it(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match=r"--init-from .*nowhere: no such checkpoint file or run directory"):
        _train(tmp_path / "ft", "--init-from", str(tmp_path / "nowhere"))
    torch.save({"meta": {"learner": "ppo"}, "learner": {}}, tmp_path / "ppo.pt")
    with pytest.raises(SystemExit, match=r"ppo\.pt: not a SuperTrack checkpoint \(learner: 'ppo'\)"):
        _train(tmp_path / "ft", "--init-from", str(tmp_path / "ppo.pt"))
    assert not (tmp_path / "ft").exists()


def test_export_loads_the_averaged_policy_that_the_trainer_evaluated(runs: dict[str, Path]) -> None:
    checkpoint, state = read_checkpoint(runs["a"])
    saved = state["learner"]
    humanoid = Humanoid(load_config(SuperTrackConfig, runs["a"] / "config.yaml").gym.physics)
    for average, weights in ((None, saved["policy_average"]["module"]), (True, saved["policy_average"]["module"]),
                             (False, saved["policy"])):  # fmt: skip
        net = load_eval_policy(runs["a"], checkpoint, humanoid, None, average=average).__self__.policy
        for k, v in net.state_dict().items():
            torch.testing.assert_close(v, weights[k])
    live, averaged = saved["policy"], saved["policy_average"]["module"]
    assert any(not torch.equal(live[k], averaged[k]) for k in live)  # the two choices are different weights
    del saved["policy_average"]
    stripped = runs["a"] / "no_average.pt"
    torch.save({"learner": saved}, stripped)
    with pytest.raises(ValueError, match=r"no_average\.pt: no averaged policy in this checkpoint"):
        load_eval_policy(runs["a"], stripped, humanoid, None, average=True)


def test_help_explains_every_option() -> None:
    text = build_parser().format_help()
    for option in ("--config", "--motions", "--device", "--out", "--resume", "--max-minutes", "--seed", "--set"):
        assert option in text


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
def test_debug_run_on_cuda(tmp_path: Path) -> None:
    _train(tmp_path / "gpu", "--device", "cuda", "--max-iterations", "3")
    assert (tmp_path / "gpu" / "checkpoints" / "latest.json").is_file()


@pytest.fixture(scope="module")
def collector_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """With a collector process: runs c and d 4 iterations straight, run e 2 iterations, then resumed to 4."""
    root = tmp_path_factory.mktemp("collector")
    on = ("--set", "collect.processes=1", "--max-iterations", "4")
    _train(root / "c", *on)
    _train(root / "d", *on)
    _train(root / "e", *on[:2], "--max-iterations", "2")
    _train(root / "e", "--resume", *on)
    return {k: root / k for k in "cde"}


def _assert_same_tensors(a: object, b: object, where: str = "") -> None:
    """Every tensor and array of two nested checkpoint states equal, exactly."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            _assert_same_tensors(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, torch.Tensor):
        assert torch.equal(a, b), where
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=where)


@pytest.mark.parametrize("other", ["d", "e"])
def test_collector_runs_of_one_seed_and_a_resumed_one_give_identical_checkpoints(collector_runs: dict[str, Path],
                                                                                 other: str) -> None:  # fmt: skip
    c, o = (read_checkpoint(collector_runs[k])[1] for k in ("c", other))
    assert c["iteration"] == o["iteration"] == 4 and c["samples"] == o["samples"]
    _assert_same_tensors(c["learner"], o["learner"])  # networks, optimisers, buffers, gym states, the block in flight
    assert c["learner"]["collector"]["pending"] is not None
    mc, mo = (read_metrics(collector_runs[k] / "metrics.jsonl") for k in ("c", other))
    # Evaluations fall on other iterations after a resume (every 4 iterations from the start of each part), and with
    # them the per-clip failure rates (charts/failure_rate/<clip>).
    logged = [{k: v for k, v in _line(m, 4, "losses/policy").items()
               if k.startswith(("losses/", "charts/")) and not k.startswith("charts/failure_rate/")}
              for m in (mc, mo)]  # fmt: skip
    assert logged[0] == logged[1] and "charts/buffer_age" in logged[0]
    assert mc[-1]["eval/mpjpe_g"] == mo[-1]["eval/mpjpe_g"]


def test_the_collector_collects_with_the_weights_one_update_behind(
    runs: dict[str, Path], collector_runs: dict[str, Path]
) -> None:
    """Same frames as the in-process loop until the policy's weights first change (update 2: update 1 is W-only)."""
    a, c = (read_checkpoint(r)[1]["learner"] for r in (
        runs["a"], collector_runs["c"]))  # fmt: skip
    rows_a, rows_c = a["train_buffer"]["rows"], c["train_buffer"]["rows"]
    # Rows 0-33: the warm-up; row 34: iteration 2's block; row 35: iteration 3's, collected with update 2's policy in
    # process and with update 1's (= the initial one) by the worker.
    np.testing.assert_array_equal(rows_a["target_rot"][:35], rows_c["target_rot"][:35])
    np.testing.assert_array_equal(rows_a["sim"][:36], rows_c["sim"][:36])  # S_35 is still reached by equal targets
    assert not np.array_equal(rows_a["target_rot"][35], rows_c["target_rot"][35])
    np.testing.assert_array_equal(rows_a["collected_at"][33:37, 0], [0, 1, 2, 3])
    np.testing.assert_array_equal(rows_c["collected_at"][33:37, 0], [0, 0, 1, 2])


def test_replay_ratio_and_buffer_age_by_hand(runs: dict[str, Path], collector_runs: dict[str, Path]) -> None:
    """Debug preset: 4 training characters, warm-up 34 steps, then 1 step per iteration; W reads 16 x 8 frames per
    update, the policy 8 x 8 from update 2 on; lines every 2 iterations."""
    for path in (runs["a"], collector_runs["c"]):
        first, second = (_line(read_metrics(path / "metrics.jsonl"), i, "charts/replay_ratio_w") for i in (2, 4))
        assert first["charts/replay_ratio_w"] == pytest.approx(2 * 128 / (34 * 4 + 4))  # 1.829
        assert first["charts/replay_ratio_policy"] == pytest.approx(64 / (34 * 4 + 4))
        assert second["charts/replay_ratio_w"] == pytest.approx(2 * 128 / 8)
        assert second["charts/replay_ratio_policy"] == pytest.approx(2 * 64 / 8)
    # With the worker every frame read in iterations 1-2 was collected with the initial weights: W's 128 reads in
    # update 1 are 0 updates old, its 128 and the policy's 64 in update 2 are 1 update old.
    line = _line(read_metrics(collector_runs["c"] / "metrics.jsonl"), 2, "charts/buffer_age")
    assert line["charts/buffer_age"] == pytest.approx((0 * 128 + 1 * 192) / 320)


def test_the_compile_warm_up_stays_off_the_training_clock_and_budget(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A 5 s warm-up against a 3 s budget: counted, the run would stop after its first iteration."""
    monkeypatch.setattr(SuperTrackLearner, "warm_up", lambda self: time.sleep(5.0))
    _train(tmp_path / "w", "--max-minutes", "0.05", "--set", "train.max_iterations=null")
    records = read_metrics(tmp_path / "w" / "metrics.jsonl")
    assert records[0]["perf/compile_s"] >= 5.0
    state = read_checkpoint(tmp_path / "w")[1]
    assert state["iteration"] >= 2 and 3.0 <= state["train_seconds"] < 5.0
    assert records[-1]["wall_clock_s"] == state["train_seconds"]


def test_a_checkpoint_from_before_the_collector_still_loads(runs: dict[str, Path]) -> None:
    """benchmarks/world_model_bodies.py reads old runs: a 'gym' entry and frames without collected_at."""
    state = read_checkpoint(runs["a"])[1]["learner"]
    old = {k: v for k, v in state.items() if k != "collector"}
    old["gym"] = state["collector"]["sources"][0]["gym"]
    for name in ("train_buffer", "val_buffer"):
        old[name] = {**state[name], "rows": {k: v for k, v in state[name]["rows"].items() if k != "collected_at"}}
    cfg = load_config(SuperTrackConfig, runs["a"] / "config.yaml")
    humanoid = Humanoid(cfg.gym.physics)
    learner = SuperTrackLearner(cfg, humanoid, load_motions(["walk"], humanoid), np.random.default_rng(0))
    try:
        learner.load_state_dict(old)
        reloaded = learner.state_dict()
    finally:
        learner.close()
    _assert_same_tensors(reloaded["collector"]["sources"][0]["gym"], old["gym"])
    np.testing.assert_array_equal(reloaded["val_buffer"]["rows"]["sim"], state["val_buffer"]["rows"]["sim"])
    assert not reloaded["train_buffer"]["rows"]["collected_at"].any()


def test_world_model_bodies_per_clip_errors(runs: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    """benchmarks/world_model_bodies.py --motions: the constant-velocity columns are |v_t - v_t+1| per body, read
    from the packed layout by hand (vel at columns 7:10, angvel at 10:13), and the per-clip table names every body."""
    from tests.benchmark_module import benchmark_module

    bench = benchmark_module("world_model_bodies")
    eager = ["world_model.compile=false", "policy.compile=false"]
    cfg = load_config(SuperTrackConfig, runs["a"] / "config.yaml", eager)
    humanoid = Humanoid(cfg.gym.physics)
    library = load_motions(["walk"], humanoid)
    learner = SuperTrackLearner(cfg, humanoid, library, np.random.default_rng(0))
    try:
        learner.load_state_dict(read_checkpoint(runs["a"])[1]["learner"])
        rng = np.random.default_rng(3)
        n = humanoid.num_bodies
        sim, nxt = rng.normal(size=(2, 5, n, 13)).astype(np.float32)
        sim[..., 3:7] /= np.linalg.norm(sim[..., 3:7], axis=-1, keepdims=True)
        targets = np.zeros((5, len(humanoid.joint_groups), 4), np.float32)
        targets[..., 0] = 1.0
        w_vel, base_vel, w_ang, base_ang = bench.one_frame_errors(learner, sim, targets, nxt)
        np.testing.assert_allclose(base_vel, np.linalg.norm(sim[..., 7:10] - nxt[..., 7:10], axis=-1).mean(0), 1e-6)
        np.testing.assert_allclose(base_ang, np.linalg.norm(sim[..., 10:13] - nxt[..., 10:13], axis=-1).mean(0), 1e-6)
        assert w_vel.shape == w_ang.shape == (n,) and np.all(w_ang > 0)
        bench.per_clip(cfg, learner, humanoid, library, ["walk", "jog"], frames=3)
        with pytest.raises(SystemExit, match="no_such_clip"):
            bench.per_clip(cfg, learner, humanoid, library, ["walk", "no_such_clip"], frames=3)
    finally:
        learner.close()
    out = capsys.readouterr().out
    assert all(name in out for name in humanoid.body_names)
    header = next(line for line in out.splitlines() if line.startswith("body"))
    assert header.split()[1:] == ["walk", "jog*"]  # jog is not among the run's clips: measured, and marked
    assert "* not among the run's training clips" in out
