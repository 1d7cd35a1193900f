"""``train-ppo`` end to end on the debug config: train, checkpoint, exact resume, evaluation, determinism, errors, and
a collector process (the same numbers, an exact resume)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from common.character.humanoid import Humanoid
from common.config import load_config
from common.motion.dataset import load_motions
from common.run.directory import read_checkpoint
from common.sim.gym import GymConfig, TrackingGym
from ppo.config import PPOTrackerConfig
from ppo.export import load_eval_policy
from ppo.learner import PPOLearner
from ppo.train import main

DEBUG = str(Path(__file__).resolve().parents[2] / "configs" / "ppo" / "debug.yaml")


def _run(out: Path, *extra: str) -> None:
    assert main(["--config", DEBUG, "--out", str(out), *extra]) == 0


def _weights(out: Path) -> dict[str, torch.Tensor]:
    return read_checkpoint(out)[1]["learner"]["net"]


def _records(out: Path) -> list[dict]:
    lines = (out / "metrics.jsonl").read_text().splitlines()
    return [{k: v for k, v in json.loads(line).items() if not k.startswith("perf/") and k != "wall_clock_s"}
            for line in lines]  # fmt: skip


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Three debug runs: 6 iterations straight (twice, same seed), and 4 iterations resumed to 6."""
    root = tmp_path_factory.mktemp("ppo")
    out = {"straight": root / "straight", "again": root / "again", "resumed": root / "resumed"}
    _run(out["straight"], "--max-iterations", "6")
    _run(out["again"], "--max-iterations", "6")
    _run(out["resumed"], "--max-iterations", "4")
    _run(out["resumed"], "--resume", "--max-iterations", "6")
    return out


def test_debug_run_trains_checkpoints_and_evaluates(runs: dict[str, Path]) -> None:
    run = runs["straight"]
    assert (run / "config.yaml").is_file() and (run / "run_info.json").is_file()
    assert (run / "checkpoints" / "ckpt_00000006.pt").is_file() and (run / "checkpoints" / "latest.json").is_file()
    records = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    last = records[-1]
    assert last["iteration"] == 6 and last["samples"] == 6 * 64
    assert 0.0 <= last["eval/survival"] <= 1.0 and np.isfinite(last["eval/mpjpe_g"])
    logged = {k for r in records for k in r}
    for key in ("losses/policy", "losses/value", "losses/entropy", "losses/approx_kl", "losses/clip_frac",
                "reward/root_pos", "reward/body_pos", "charts/term/root_below_ref_per_1k", "charts/reward",
                "charts/episode_length", "charts/terminated_share", "charts/action_std", "charts/clip_weight_max",
                "perf/samples_per_s", "perf/gym_share", "perf/update_share"):  # fmt: skip
        assert key in logged, key
    assert not logged & {"charts/mean_reward", "charts/episode_fail_rate"}  # the names before SuperTrack's
    state = read_checkpoint(run)[1]["learner"]
    assert state["normalizer"]["count"] == 6 * 64  # the normaliser's statistics are saved with the checkpoint
    assert state["motion_weights"]["failure_rate"].shape == (1,)


def test_resume_continues_exactly(runs: dict[str, Path]) -> None:
    straight, resumed = _weights(runs["straight"]), _weights(runs["resumed"])
    for name, value in straight.items():
        torch.testing.assert_close(resumed[name], value, rtol=0, atol=0, msg=name)
    # The resumed run's log has the first run's lines up to its checkpoint, then the continuation.
    assert [r["iteration"] for r in _records(runs["resumed"]) if "losses/policy" in r] == [2, 4, 6]


def test_same_seed_gives_the_same_run(runs: dict[str, Path]) -> None:
    a, b = _weights(runs["straight"]), _weights(runs["again"])
    for name, value in a.items():
        torch.testing.assert_close(b[name], value, rtol=0, atol=0, msg=name)
    assert _records(runs["straight"]) == _records(runs["again"])


def test_mismatched_checkpoint_is_refused(runs: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit, match="(?s)incompatible with the current run.*network.actor_hidden"):
        _run(runs["straight"], "--resume", "--max-iterations", "8", "--set", "network.actor_hidden=[16]")
    assert not (runs["straight"] / "checkpoints" / "ckpt_00000008.pt").exists()


def test_export_refuses_a_policy_of_another_observation(runs: dict[str, Path], tmp_path: Path) -> None:
    """A run's config.yaml naming another observation than its policy was trained on fails with one clear line."""
    run = tmp_path / "run"
    shutil.copytree(runs["straight"], run)
    config = run / "config.yaml"
    config.write_text(config.read_text().replace("kind: parc", "kind: local"))
    humanoid = Humanoid()
    library = load_motions(["walk"], humanoid)
    policy = load_eval_policy(run, read_checkpoint(run)[0], humanoid, library)
    gym = TrackingGym(GymConfig(num_envs=2, threads=1), library, humanoid)
    with pytest.raises(ValueError, match="the 'local' observation has 497 features, the policy in .* reads 725"):
        policy(gym.reset())
    gym.close()


def test_existing_run_needs_resume_and_unknown_keys_fail(runs: dict[str, Path], tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="already holds a run; pass --resume"):
        _run(runs["straight"])
    with pytest.raises(SystemExit, match="unknown key 'ppo.epoch'"):
        _run(tmp_path / "bad", "--set", "ppo.epoch=3")


def test_nan_loss_is_skipped_and_the_weights_restored() -> None:
    cfg = load_config(PPOTrackerConfig, DEBUG)
    humanoid = Humanoid(cfg.gym.physics)
    learner = PPOLearner(cfg, load_motions(["walk"], humanoid), humanoid, np.random.default_rng(0))
    try:
        learner.collect()
        with torch.no_grad():
            learner.net.critic[0].weight[0, 0] = float("nan")  # every value, hence the first minibatch's loss, is NaN
        metrics = learner.update()
        # The guard skipped that step and restored the last good weights; the other 3 of 2 x 2 steps trained on them.
        assert metrics["losses/steps"] == 3 and learner.nan_guard.bad_total == 1
        assert all(torch.isfinite(v).all() for v in learner.net.state_dict().values())
        assert torch.isfinite(learner.net.critic[0].weight[0, 0])
    finally:
        learner.close()


def test_a_truncated_newest_checkpoint_resumes_from_the_previous_one_exactly(
    runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "damaged"
    shutil.copytree(runs["resumed"], run)
    newest = run / "checkpoints" / "ckpt_00000006.pt"
    data = newest.read_bytes()
    newest.write_bytes(data[: len(data) // 3])  # a partial copy
    capsys.readouterr()
    _run(run, "--resume", "--max-iterations", "6")
    err = capsys.readouterr().err.splitlines()
    assert f"warning: {newest}: truncated or damaged (PytorchStreamReader failed reading zip archive: failed finding " \
           "central directory); passed over" in err  # fmt: skip
    assert f"resuming from {run / 'checkpoints' / 'ckpt_00000004.pt'} (iteration 4)" in err
    assert f"warning: {newest} kept as ckpt_00000006.pt.damaged" in err
    assert (run / "checkpoints" / "ckpt_00000006.pt.damaged").read_bytes() == data[: len(data) // 3]
    for name, value in _weights(runs["straight"]).items():  # iterations 5 and 6 again, bit for bit
        torch.testing.assert_close(_weights(run)[name], value, rtol=0, atol=0, msg=name)
    assert _records(run) == _records(runs["straight"])


def test_a_checkpoint_that_cannot_be_written_ends_the_run_in_one_line_and_keeps_the_last(
    runs: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run = tmp_path / "full"
    shutil.copytree(runs["straight"], run)
    before = {p.name: p.read_bytes() for p in (run / "checkpoints").iterdir()}

    def disk_full(obj: object, f: str, *args: object, **kwargs: object) -> None:
        Path(f).write_bytes(b"\0" * 1000)
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(torch, "save", disk_full)
    with pytest.raises(SystemExit) as info:
        _run(run, "--resume", "--max-iterations", "8")
    assert str(info.value) == (f"error: cannot write the checkpoint of iteration 8 in {run / 'checkpoints'}: No space "
                               "left on device; the checkpoints already there are intact (continue with --resume once "
                               "it can be written)")  # fmt: skip
    assert {p.name: p.read_bytes() for p in (run / "checkpoints").iterdir()} == before


@pytest.fixture(scope="module")
def collector_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """With one collector process: 6 iterations straight, and 4 iterations resumed to 6."""
    root = tmp_path_factory.mktemp("ppo-collector")
    out = {"straight": root / "straight", "resumed": root / "resumed"}
    on = ("--set", "collect.processes=1")
    _run(out["straight"], "--max-iterations", "6", *on)
    _run(out["resumed"], "--max-iterations", "4", *on)
    _run(out["resumed"], "--resume", "--max-iterations", "6", *on)
    return out


def test_a_collector_process_gives_the_in_process_numbers_and_resumes_exactly(
    runs: dict[str, Path], collector_runs: dict[str, Path]
) -> None:
    """The learner draws the noise and waits for each rollout, and the worker's gym has the in-process seed: the
    same numbers as collect.processes = 0, bit for bit, and again after a resume."""
    in_process = _weights(runs["straight"])
    for name in ("straight", "resumed"):
        weights = _weights(collector_runs[name])
        for key, value in in_process.items():
            torch.testing.assert_close(weights[key], value, rtol=0, atol=0, msg=f"{name}: {key}")
    assert _records(collector_runs["straight"]) == _records(runs["straight"])
    assert _records(collector_runs["resumed"]) == _records(runs["resumed"])
    collector = read_checkpoint(collector_runs["resumed"])[1]["learner"]["collector"]
    assert len(collector["sources"]) == 1 and collector["pending"] is None  # nothing in flight between iterations


@pytest.mark.parametrize(("value", "message"), [
    ("-1", r"collect\.processes must be >= 0, got -1"),
    ("9", r"collect\.processes \(9\) exceeds gym\.num_envs \(8\)"),
])  # fmt: skip
def test_a_bad_collector_count_fails_with_its_name(tmp_path: Path, value: str, message: str) -> None:
    with pytest.raises(SystemExit, match=message):
        _run(tmp_path / "x", "--set", f"collect.processes={value}")


@pytest.fixture(scope="module")
def amp_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """With AMP on: 6 iterations straight, 4 iterations resumed to 6, and 6 straight with one collector process."""
    root = tmp_path_factory.mktemp("ppo-amp")
    out = {"straight": root / "straight", "resumed": root / "resumed", "process": root / "process"}
    on = ("--set", "amp.weight=0.5")
    _run(out["straight"], "--max-iterations", "6", *on)
    _run(out["resumed"], "--max-iterations", "4", *on)
    _run(out["resumed"], "--resume", "--max-iterations", "6", *on)
    _run(out["process"], "--max-iterations", "6", *on, "--set", "collect.processes=1")
    return out


def _amp_state(out: Path) -> dict:
    return read_checkpoint(out)[1]["learner"]["amp"]


def test_amp_resumes_exactly_and_a_collector_process_gives_the_same_numbers(
    runs: dict[str, Path], amp_runs: dict[str, Path]
) -> None:
    """A debug run with amp.weight 0.5 stopped after 4 iterations and resumed ends bit for bit where the straight run
    does: the policy, the discriminator, its optimiser, normaliser, replay buffer and generator; and the AMP's
    features computed in a collector process give the in-process numbers."""
    straight = _amp_state(amp_runs["straight"])
    assert straight["replay"]["data"].shape == (100, 250)  # full: 64 + 64 + 16 per iteration
    assert straight["normalizer"]["count"] == 6 * (64 + 2 * 32)
    for name in ("resumed", "process"):
        for key, value in _weights(amp_runs["straight"]).items():
            torch.testing.assert_close(_weights(amp_runs[name])[key], value, rtol=0, atol=0, msg=f"{name}: {key}")
        state = _amp_state(amp_runs[name])
        for key, value in straight["disc"].items():
            torch.testing.assert_close(state["disc"][key], value, rtol=0, atol=0, msg=f"{name}: disc.{key}")
        assert state["optimizer"]["state"].keys() == straight["optimizer"]["state"].keys()
        for k, moments in straight["optimizer"]["state"].items():
            for m, value in moments.items():
                torch.testing.assert_close(state["optimizer"]["state"][k][m], value, rtol=0, atol=0)
        for key in ("count", "mean", "var"):
            np.testing.assert_array_equal(state["normalizer"][key], straight["normalizer"][key])
        np.testing.assert_array_equal(state["replay"]["data"], straight["replay"]["data"])
        assert state["replay"]["head"] == straight["replay"]["head"] and state["rng"] == straight["rng"]
        assert _records(amp_runs[name]) == _records(amp_runs["straight"])
    logged = {k for r in _records(amp_runs["straight"]) for k in r}
    for key in ("amp/expert_loss", "amp/policy_loss", "amp/grad_penalty", "amp/expert_accuracy", "amp/policy_accuracy",
                "amp/reward_mean"):  # fmt: skip
        assert key in logged, key
    # AMP changed the policy's numbers (its reward entered GAE); with AMP off no amp/ key is logged.
    actor = "actor.0.weight"
    assert not torch.equal(_weights(amp_runs["straight"])[actor], _weights(runs["straight"])[actor])
    assert not any(k.startswith("amp/") for r in _records(runs["straight"]) for k in r)
