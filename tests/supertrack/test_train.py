"""End-to-end tests of ``train-supertrack`` on the debug preset: checkpoint, exact resume, evaluation, bad input."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from common.config import load_config
from common.humanoid import Humanoid
from common.logs import read_metrics
from common.run import read_checkpoint
from supertrack.config import SuperTrackConfig
from supertrack.export import load_eval_policy
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
    """Run a: 6 iterations straight. Run b: 3 iterations, then resumed to 6."""
    root = tmp_path_factory.mktemp("supertrack")
    _train(root / "a")
    _train(root / "b", "--max-iterations", "3")
    _train(root / "b", "--resume")
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
    for key in ("world_model", "policy", "world_optimizer", "policy_optimizer", "gym", "train_buffer", "val_buffer"):
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
    gym = read_checkpoint(tmp_path / "y")[1]["learner"]["gym"]
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
