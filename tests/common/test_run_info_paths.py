"""Records that travel name no path of the machine that wrote them: run_info.json as a run writes it, a bundle made
from a run, and everything shipped under ``pretrained/``."""

from __future__ import annotations

import json
import os
import re
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

import pytest
import yaml

from common.run.checkpoint import load_checkpoint_file
from common.run.command_line import portable_command, portable_command_text, portable_path, program_name
from common.run.directory import RunDir
from common.train.command import TrainingCommand, _launch_info
from common.train.distributed import World
from report.bundle_policy import bundle

ROOT = Path(__file__).resolve().parents[2]
PRETRAINED = ROOT / "pretrained"
# An absolute POSIX path (or one under the user's home) where a word starts: after a space, a quote, '=' or '('.
_ABSOLUTE = re.compile(r"(?:^|(?<=[\s\"'=(:,\[]))(?:~/|/)(?=[\w.~-])[^\s\"',;)\]]*")


def _strings(value: Any) -> list[str]:
    """Every string in a nest of mappings, lists and tuples (keys included)."""
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [s for k, v in value.items() for s in (*_strings(k), *_strings(v))]
    if isinstance(value, (list, tuple)):
        return [s for v in value for s in _strings(v)]
    return []


def _machine_paths(texts: list[str]) -> list[str]:
    """The absolute paths in ``texts``, and any mention of this machine's home, temporary folder, interpreter
    environment, working directory or checkout."""
    prefixes = {str(Path.home()), tempfile.gettempdir(), "/tmp/", sys.prefix, os.getcwd(), str(ROOT)}
    found = [m for t in texts for m in _ABSOLUTE.findall(t)]
    return found + [f"{p} in {t!r}" for t in texts for p in prefixes if p and p != "/" and p in t]


def test_the_path_finder_finds_what_it_should_and_nothing_else() -> None:
    assert _machine_paths(["train-ppo --out /scratch/me/run", "--config=/x.yaml", "see ~/runs", "a=(/b)"]) == [
        "/scratch/me/run", "/x.yaml", "~/runs", "/b"]  # fmt: skip
    assert _machine_paths(["results/supertrack-split-120min", "1/2 and/or 3", "a / b", "split's clips"]) == []


def test_portable_paths_and_commands_by_hand(tmp_path: Path) -> None:
    assert portable_path("runs/a", tmp_path) == "runs/a"
    assert portable_path(str(tmp_path / "runs" / "a"), tmp_path) == "runs/a"
    assert portable_path(str(tmp_path), tmp_path) == "."
    assert portable_path(str(ROOT / "configs" / "ppo" / "debug.yaml"), tmp_path) == "configs/ppo/debug.yaml"
    assert portable_path("/scratch/me/st-run/", tmp_path) == "st-run"
    assert program_name("/home/me/project/.venv/bin/train-ppo") == "train-ppo"
    assert program_name(str(ROOT / "supertrack" / "train.py")) == "python -m supertrack.train"
    assert program_name("/elsewhere/old-checkout/ppo/train.py") == "python -m ppo.train"  # an older run's record
    assert portable_command(["/v/bin/train-ppo", "--out", "/scratch/a b", "--config=/c/d.yaml", "--set", "x=1"],
                            tmp_path) == "train-ppo --out 'a b' --config=d.yaml --set x=1"  # fmt: skip
    assert portable_command_text("/v/bin/train-ppo --out '/scratch/a b'", tmp_path) == "train-ppo --out 'a b'"
    assert portable_command_text("unbalanced 'quote", tmp_path) == "unbalanced 'quote"


@pytest.mark.parametrize("module", [False, True], ids=["console-script", "python-m"])
def test_a_freshly_written_run_info_names_no_path_of_the_machine(
        module: bool, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """A run started the way a user starts one (a console script in the virtual environment, or ``python -m``, which
    puts the module's file in argv[0]), with absolute paths inside the working directory, the project and
    elsewhere."""
    monkeypatch.chdir(tmp_path)
    program = str(ROOT / "supertrack" / "train.py") if module else str(Path(sys.prefix) / "bin" / "train-supertrack")
    elsewhere = [str(Path.home() / "takes" / "walk.txt"), f"--set=train.motions={tempfile.gettempdir()}/m"]
    argv = [program, "--config", str(ROOT / "configs" / "supertrack" / "debug.yaml"), "--out", str(tmp_path / "run"),
            "--motions", *elsewhere]  # fmt: skip
    monkeypatch.setattr(sys, "argv", argv)
    RunDir(tmp_path / "run", resume=False).write_run_info({"seed": 0})
    info = json.loads((tmp_path / "run" / "run_info.json").read_text(encoding="utf-8"))
    assert _machine_paths(_strings(info)) == []
    first = "python -m supertrack.train" if module else "train-supertrack"
    assert info["command"] == (f"{first} --config configs/supertrack/debug.yaml --out run --motions walk.txt "
                               f"--set=train.motions=m")  # fmt: skip
    monkeypatch.setattr(sys, "argv", [str(ROOT / "supertrack" / "train.py"), *argv[1:]])  # a torchrun rank's argv
    monkeypatch.setenv("LOCAL_WORLD_SIZE", "2")
    launch = _launch_info(TrainingCommand("supertrack", "train-supertrack", object, ""),
                          World(rank=0, size=2))  # fmt: skip
    assert _machine_paths(_strings(launch)) == []
    assert launch["command"].startswith("torchrun --nproc_per_node=2 -m supertrack.train --config configs/")


def test_a_bundle_of_a_run_with_an_older_absolute_record_names_no_path(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """A run recorded before commands were written portably (argv[0] in a virtual environment, --out absolute)."""
    run = tmp_path / "scratch" / "st-run"
    shutil.copytree(PRETRAINED / "general", run)
    info = json.loads((run / "run_info.json").read_text(encoding="utf-8"))
    info["command"] = f"{sys.prefix}/bin/train-supertrack --motions walk --out {run} --seed 0"
    (run / "run_info.json").write_text(json.dumps(info), encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    out = bundle(run, tmp_path / "bundles" / "mine")
    source = json.loads((out / "run_info.json").read_text(encoding="utf-8"))["source"]
    assert source["run"] == "scratch/st-run"
    assert source["command"] == "train-supertrack --motions walk --out scratch/st-run --seed 0"
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    source = json.loads((bundle(run, tmp_path / "b2") / "run_info.json").read_text(encoding="utf-8"))["source"]
    assert source["run"] == "st-run" and source["command"].endswith("--out st-run --seed 0")


def _shipped_strings(path: Path) -> list[str]:
    if path.suffix == ".pt":
        return _strings(load_checkpoint_file(path))
    text = path.read_text(encoding="utf-8")
    if path.suffix == ".json":
        return _strings(json.loads(text))
    if path.suffix in (".yaml", ".yml"):
        return _strings(yaml.safe_load(text))
    return [text]


def test_nothing_shipped_under_pretrained_names_an_absolute_path() -> None:
    files = sorted(p for p in PRETRAINED.rglob("*") if p.is_file())
    assert files, "pretrained/ is empty"
    found = {str(p.relative_to(ROOT)): _machine_paths(_shipped_strings(p)) for p in files}
    assert {k: v for k, v in found.items() if v} == {}
