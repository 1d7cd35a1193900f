"""The learner registry (report/learners.py): one table that the commands read and that agrees with the learners."""

from __future__ import annotations

import importlib
import importlib.util
from pathlib import Path

import pytest

from report.learners import LEARNERS, trainable
from report.runs import ReportError, export_module
from tests.benchmark_module import benchmark_module

ROOT = Path(__file__).resolve().parents[2]


def test_every_learner_is_registered_once_with_what_each_command_needs() -> None:
    assert list(LEARNERS) == ["supertrack", "ppo", "rsl_rl", "samcon"]
    for name, spec in LEARNERS.items():
        assert spec.name == name
        assert importlib.util.find_spec(spec.export) is not None, spec.export
        assert (ROOT / "configs" / str(spec.configs) / "default.yaml").is_file(), name
    assert trainable() == ["supertrack", "ppo", "rsl_rl"]
    assert [n for n in LEARNERS if LEARNERS[n].policy_keys] == trainable()  # SAMCON has no network to bundle


def test_each_training_command_carries_its_registered_name_and_console_script() -> None:
    tomllib = pytest.importorskip("tomllib")
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    for name in trainable():
        spec = LEARNERS[name]
        command = importlib.import_module(str(spec.train)).COMMAND  # importable without the optional extras
        assert (command.name, command.prog, command.module) == (name, spec.command, spec.train)  # torchrun -m
        assert scripts[str(spec.command)] == f"{spec.train}:main"
        assert (ROOT / "configs" / str(spec.configs) / "debug.yaml").is_file()
    assert scripts["track-samcon"] == "samcon.track:main"


def test_the_suite_trains_the_registered_learners_and_by_default_the_head_to_head() -> None:
    parser = benchmark_module("compare_trackers").build_parser()
    assert parser.parse_args(["--out", "x"]).learners == ["supertrack", "ppo"]
    assert parser.parse_args(["--out", "x", "--learners", "rsl_rl"]).learners == ["rsl_rl"]
    with pytest.raises(SystemExit):
        parser.parse_args(["--out", "x", "--learners", "samcon"])  # a search: track-samcon runs it, not the suite


def test_an_unknown_learner_is_refused_in_one_line_without_any_import(monkeypatch: pytest.MonkeyPatch) -> None:
    imported: list[str] = []
    real_import = importlib.import_module
    monkeypatch.setattr(importlib, "import_module", lambda name, *a: imported.append(name) or real_import(name, *a))
    with pytest.raises(ReportError) as refused:
        export_module("os")
    assert str(refused.value) == "unknown learner 'os' (known: supertrack, ppo, rsl_rl, samcon)"
    assert imported == []
