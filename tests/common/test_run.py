"""Tests of common.run.directory: run directories, atomic checkpoints, compatibility checks, RNG state and run info."""

from __future__ import annotations

import json
import random
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from common.config import load_config
from common.run.directory import (
    RunDir,
    RunDirError,
    check_compatible,
    load_run_checkpoint,
    rng_state,
    set_rng_state,
)
from common.train.training import next_mark


@dataclass(frozen=True)
class _Cfg:
    lr: float = 1e-3
    hidden: tuple[int, ...] = (8, 8)


def _ckpt_names(run: RunDir) -> list[str]:
    return sorted(p.name for p in run.checkpoint_dir.iterdir())


def test_new_run_creates_layout_and_refuses_reuse_without_resume(tmp_path: Path) -> None:
    run = RunDir(tmp_path / "a" / "run", resume=False)
    assert run.checkpoint_dir.is_dir()
    run.save_config(_Cfg(lr=0.5))
    assert load_config(_Cfg, run.config_path) == _Cfg(lr=0.5)
    with pytest.raises(RunDirError, match="already holds a run; pass --resume to continue it or choose another --out"):
        RunDir(run.path, resume=False)


def test_existing_empty_directory_is_accepted(tmp_path: Path) -> None:
    (tmp_path / "out").mkdir()
    assert RunDir(tmp_path / "out", resume=False).checkpoint_dir.is_dir()


def test_resume_without_checkpoint_errors(tmp_path: Path) -> None:
    with pytest.raises(RunDirError, match="cannot resume: .* has no checkpoint"):
        RunDir(tmp_path / "fresh", resume=True)
    RunDir(tmp_path / "started", resume=False)
    with pytest.raises(RunDirError, match="cannot resume"):
        RunDir(tmp_path / "started", resume=True)


def test_save_and_resume_latest_checkpoint(tmp_path: Path) -> None:
    run = RunDir(tmp_path / "r", resume=False)
    run.save_checkpoint({"w": torch.arange(3), "meta": {"lr": 0.1}}, iteration=5)
    run.save_checkpoint({"w": torch.arange(4), "meta": {"lr": 0.1}}, iteration=10)
    resumed = RunDir(tmp_path / "r", resume=True)
    path, state, passed_over = resumed.load_latest_checkpoint()
    assert path == run.checkpoint_path(10) and passed_over == []
    assert state["iteration"] == 10
    assert torch.equal(state["w"], torch.arange(4))
    assert _ckpt_names(run) == ["ckpt_00000005.pt", "ckpt_00000010.pt", "latest.json"]
    pointer = json.loads(run.pointer_path.read_text())
    assert pointer["latest"] == "ckpt_00000010.pt" and sorted(pointer["checkpoints"]) == _ckpt_names(run)[:2]
    with pytest.raises(ValueError, match="state\\['iteration'\\] = 3"):
        run.save_checkpoint({"iteration": 3}, iteration=4)


def test_failed_save_keeps_previous_checkpoint_and_leaves_no_temp_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run = RunDir(tmp_path / "r", resume=False)
    run.save_checkpoint({"w": torch.ones(2)}, iteration=1)

    def broken_save(obj: Any, f: Any, *args: Any, **kwargs: Any) -> None:
        Path(f).write_bytes(b"half a checkpoint")
        raise OSError("disk full")

    before = {name: (run.checkpoint_dir / name).read_bytes() for name in _ckpt_names(run)}
    monkeypatch.setattr(torch, "save", broken_save)
    with pytest.raises(OSError, match="disk full"):
        run.save_checkpoint({"w": torch.zeros(2)}, iteration=2)
    monkeypatch.undo()
    assert {name: (run.checkpoint_dir / name).read_bytes() for name in _ckpt_names(run)} == before
    assert _ckpt_names(run) == ["ckpt_00000001.pt", "latest.json"]
    path, state, _ = RunDir(run.path, resume=True).load_latest_checkpoint()
    assert state["iteration"] == 1 and torch.equal(state["w"], torch.ones(2))


def test_keeps_newest_k_numbered_checkpoints(tmp_path: Path) -> None:
    run = RunDir(tmp_path / "r", resume=False, keep_checkpoints=2)
    for it in (100, 200, 300, 400):
        run.save_checkpoint({"x": it}, iteration=it)
    assert _ckpt_names(run) == ["ckpt_00000300.pt", "ckpt_00000400.pt", "latest.json"]
    assert [it for it, _ in run.numbered_checkpoints()] == [300, 400]
    assert sorted(json.loads(run.pointer_path.read_text())["checkpoints"]) == ["ckpt_00000300.pt", "ckpt_00000400.pt"]
    assert run.load_latest_checkpoint()[1]["x"] == 400
    with pytest.raises(ValueError, match="keep_checkpoints"):
        RunDir(tmp_path / "k", resume=False, keep_checkpoints=0)


def test_newest_numbered_checkpoint_wins_over_a_stale_pointer_and_a_legacy_latest_is_read(tmp_path: Path) -> None:
    run = RunDir(tmp_path / "r", resume=False)
    run.save_checkpoint({"x": 1}, iteration=1)
    pointer_of_1 = run.pointer_path.read_bytes()
    run.save_checkpoint({"x": 2}, iteration=2)
    # As if the process died after writing ckpt 2 but before writing latest.json.
    run.pointer_path.write_bytes(pointer_of_1)
    assert run.latest_checkpoint_path() == run.checkpoint_path(2)
    assert RunDir(run.path, resume=True).load_latest_checkpoint()[1]["x"] == 2
    # A run directory of an earlier version: only the hard link latest.pt (a copy here) to a pruned checkpoint.
    legacy = run.checkpoint_dir / "latest.pt"
    shutil.copyfile(run.checkpoint_path(1), legacy)
    for _, path in run.numbered_checkpoints():
        path.unlink()
    assert RunDir(run.path, resume=True).load_latest_checkpoint()[:2] == (legacy, {"x": 1, "iteration": 1})
    run.save_checkpoint({"x": 3}, iteration=3)  # supersedes the stale legacy copy, which goes
    assert _ckpt_names(run) == ["ckpt_00000003.pt", "latest.json"]


def test_check_compatible_lists_every_difference(tmp_path: Path) -> None:
    saved = {"character": "humanoid", "obs_dim": 10, "cfg": {"lr": 0.1, "hidden": (8, 8), "gone": 1}}
    same = {"character": "humanoid", "obs_dim": 10, "cfg": {"lr": 0.1, "hidden": [8, 8], "gone": 1}}
    check_compatible(saved, same, "p")  # tuples and lists compare equal: no error
    current = {"character": "amp", "obs_dim": 10, "cfg": {"lr": 0.2, "hidden": [8, 8], "new": True}}
    with pytest.raises(ValueError) as info:
        check_compatible(saved, current, tmp_path / "ckpt.pt")
    lines = str(info.value).splitlines()
    assert lines[0] == f"checkpoint {tmp_path / 'ckpt.pt'} is incompatible with the current run (4 differences):"
    assert lines[1:] == [
        "  cfg.gone: saved 1, current '<missing>'",
        "  cfg.lr: saved 0.1, current 0.2",
        "  cfg.new: saved '<missing>', current True",
        "  character: saved 'humanoid', current 'amp'",
    ]


def _draw(np_rng: np.random.Generator) -> tuple[list[float], list[float], list[float]]:
    return [random.random() for _ in range(3)], np_rng.random(3).tolist(), torch.rand(3).tolist()


def test_rng_state_round_trip_through_checkpoint(tmp_path: Path) -> None:
    random.seed(1)
    torch.manual_seed(2)
    np_rng = np.random.default_rng(3)
    _draw(np_rng)
    run = RunDir(tmp_path / "r", resume=False)
    run.save_checkpoint({"rng": rng_state(np_rng)}, iteration=1)
    expected = _draw(np_rng)
    _draw(np_rng)  # move every generator further on before restoring
    other_rng = np.random.default_rng(99)
    set_rng_state(run.load_latest_checkpoint()[1]["rng"], other_rng)
    assert _draw(other_rng) == expected


def test_write_run_info_records_machine_and_resumes(tmp_path: Path) -> None:
    run = RunDir(tmp_path / "r", resume=False)
    info = run.write_run_info({"seed": 7})
    saved = json.loads(run.run_info_path.read_text())
    assert saved == info
    assert saved["seed"] == 7 and saved["torch"] == torch.__version__ and saved["numpy"] == np.__version__
    assert saved["torch_threads"] == torch.get_num_threads() and isinstance(saved["cpu"], str)
    run.save_checkpoint({}, iteration=1)
    resuming = RunDir(run.path, resume=True)
    resuming.write_run_info({"seed": 8})
    assert "resumes" not in json.loads(run.run_info_path.read_text())  # not before the checkpoint is restored
    resuming.confirm_resume([])
    resumed = json.loads(run.run_info_path.read_text())
    assert resumed["seed"] == 7 and [r["seed"] for r in resumed["resumes"]] == [8]


def test_load_run_checkpoint_returns_config_and_learner_and_names_what_is_missing(tmp_path: Path) -> None:
    run = RunDir(tmp_path / "run", resume=False)
    run.save_config(_Cfg(lr=0.5))
    path = run.save_checkpoint({"learner": {"policy": {"w": torch.ones(2)}, "iteration": 3}}, iteration=3)
    cfg, learner = load_run_checkpoint(_Cfg, run.path, path, "policy")
    assert cfg == _Cfg(lr=0.5)
    assert torch.equal(learner["policy"]["w"], torch.ones(2))
    with pytest.raises(ValueError, match=r"ckpt_00000003\.pt: the learner state has no sizes, net; .*_Cfg"):
        load_run_checkpoint(_Cfg, run.path, path, "policy", "sizes", "net")
    other = tmp_path / "weights.pt"
    torch.save({"w": torch.ones(2)}, other)
    with pytest.raises(ValueError, match=r"weights\.pt: no learner state"):
        load_run_checkpoint(_Cfg, run.path, other, "policy")


def test_a_run_directory_is_checked_without_being_made_and_refused_where_it_cannot_be(tmp_path: Path) -> None:
    run = RunDir(tmp_path / "a" / "run", resume=False, create=False)
    assert not (tmp_path / "a").exists()
    run.create()
    assert run.checkpoint_dir.is_dir()
    (tmp_path / "file").write_text("x")
    with pytest.raises(RunDirError, match=rf"run directory {tmp_path / 'file' / 'run'}: .*file is a file, not a dir"):
        RunDir(tmp_path / "file" / "run", resume=False, create=False)
    with pytest.raises(RunDirError, match=r"file: exists and is not a directory"):
        RunDir(tmp_path / "file", resume=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "file"]


def test_atomic_output_names_the_destination_when_the_disk_is_full(tmp_path: Path) -> None:
    from common.config import atomic_output

    (tmp_path / "x.json").write_text("old")
    with pytest.raises(OSError) as info, atomic_output(tmp_path / "x.json") as tmp:
        tmp.write_text("half")
        raise OSError(28, "No space left on device", str(tmp))
    assert (info.value.errno, info.value.filename) == (28, str(tmp_path / "x.json"))
    assert [p.name for p in tmp_path.iterdir()] == ["x.json"] and (tmp_path / "x.json").read_text() == "old"


def test_an_option_added_since_the_checkpoint_is_accepted_only_at_its_default() -> None:
    saved = {"learner": "ppo", "config": {"lr": 0.1}}
    defaults = {"learner": "ppo", "config": {"lr": 0.5, "amp": {"weight": 0.0, "hidden": (256, 256)}}}
    at_default = {"learner": "ppo", "config": {"lr": 0.1, "amp": {"weight": 0.0, "hidden": [256, 256]}}}
    check_compatible(saved, at_default, "p", defaults)  # the new section at its defaults: the same run
    changed = {"learner": "ppo", "config": {"lr": 0.1, "amp": {"weight": 0.3, "hidden": [256, 256]}}}
    with pytest.raises(ValueError, match=r"\(1 differences\):\n  config.amp.weight: saved '<missing>', current 0.3$"):
        check_compatible(saved, changed, "p", defaults)
    with pytest.raises(ValueError, match="config.lr: saved 0.1, current 0.5"):  # a saved key is never excused
        check_compatible(saved, {"learner": "ppo", "config": {"lr": 0.5}}, "p", defaults)
    with pytest.raises(ValueError, match="2 differences"):  # without defaults every new key differs
        check_compatible(saved, at_default, "p")


def test_evaluations_fall_on_a_grid_that_a_resume_or_a_late_evaluation_does_not_shift() -> None:
    assert next_mark(0.0, 900.0) == 900.0  # a fresh run: the first evaluation after 15 minutes
    assert next_mark(600.0, 900.0) == 900.0  # resumed from a 10-minute checkpoint: still at 15, not at 25
    assert next_mark(903.7, 900.0) == 1800.0  # evaluated 3.7 s late: the next one is still at 30
    assert next_mark(900.0, 900.0) == 1800.0
    assert next_mark(3, 4) == 4 and next_mark(4, 4) == 8  # iterations
