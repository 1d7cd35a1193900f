"""The bad-input corpus (cases.yaml) through the real commands: one line naming the culprit, no traceback, no change.

Each case runs the command's ``main(argv)`` in process (fast: the debug runs are made once); two of them also run
as real processes, to show that what a user sees on stderr is that one line and no traceback.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import torch

from common.config import parse_yaml
from common.tools import motions as motion_cli
from ppo import train as train_ppo
from report import compare
from supertrack import train as train_supertrack

ROOT = Path(__file__).resolve().parents[2]
CORPUS = Path(__file__).resolve().parent
CASES: list[dict[str, Any]] = parse_yaml((CORPUS / "cases.yaml").read_text(encoding="utf-8"))
MAINS: dict[str, Callable[[list[str]], Any]] = {
    "train-ppo": train_ppo.main, "train-supertrack": train_supertrack.main, "compare-trackers": compare.main,
    "mimic-motions": motion_cli.main,
}  # fmt: skip
PPO_CONFIG = str(ROOT / "configs" / "ppo" / "debug.yaml")
ST_CONFIG = str(ROOT / "configs" / "supertrack" / "debug.yaml")


class _WritesAMarker:
    """Unpickling it calls ``open(marker, "w")``: a stand-in for any code a shared pickle could run."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, tuple[str, str]]:
        return (open, (str(self.marker), "w"))


def _copy_run(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _only_checkpoint(run: Path) -> Path:
    (path,) = sorted((run / "checkpoints").glob("ckpt_*.pt"))
    return path


def _make_inputs(ws: Path) -> None:
    """The inputs that cannot live in the repository as files: checkpoints and damaged run directories."""
    made, ppo_run, st_run = ws / "made", ws / "ppo_run", ws / "st_run"
    made.mkdir()
    marker = ws / "MARKER"
    torch.save({"meta": {"learner": "supertrack"}, "learner": _WritesAMarker(marker)}, made / "evil.pt")
    data = _only_checkpoint(st_run).read_bytes()
    (made / "truncated.pt").write_bytes(data[: len(data) // 2])
    (made / "empty.pt").write_bytes(b"")
    evil_run = _copy_run(st_run, made / "evil_run")
    torch.save({"meta": {"learner": "supertrack"}, "iteration": 6, "samples": 0, "train_seconds": 0.0, "rng": {},
                "learner": {"policy": _WritesAMarker(marker)}}, _only_checkpoint(evil_run))  # fmt: skip
    truncated_run = _copy_run(ppo_run, made / "truncated_run")
    ckpt = _only_checkpoint(truncated_run)
    ckpt.write_bytes(ckpt.read_bytes()[:1000])
    for path in (_copy_run(ppo_run, made / "no_checkpoint_run") / "checkpoints").iterdir():
        path.unlink()
    foreign_run = _copy_run(ppo_run, made / "foreign_run")
    torch.save({"w": torch.ones(3)}, _only_checkpoint(foreign_run))
    (foreign_run / "checkpoints" / "latest.json").unlink()  # else its digest finds the file changed first
    (made / "empty_dir").mkdir()
    (_copy_run(ppo_run, made / "binary_info_run") / "run_info.json").write_bytes(b"\x00\xff\xfe binary")
    (_copy_run(ppo_run, made / "binary_config_run") / "config.yaml").write_bytes(b"\xff\xfe\x00 binary")
    metrics = _copy_run(ppo_run, made / "garbage_metrics_run") / "metrics.jsonl"
    metrics.write_text("not json\n" + metrics.read_text(encoding="utf-8"), encoding="utf-8")
    info = _copy_run(ppo_run, made / "unknown_learner_run") / "run_info.json"
    info.write_text(info.read_text(encoding="utf-8").replace('"learner": "ppo"', '"learner": "dqn"'), encoding="utf-8")


@pytest.fixture(scope="module")
def debug_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One finished debug run of each learner (a few seconds each)."""
    torch.set_num_threads(1)
    base = tmp_path_factory.mktemp("debug_runs")
    assert train_ppo.main(["--config", PPO_CONFIG, "--out", str(base / "ppo")]) == 0
    train_supertrack.main(["--config", ST_CONFIG, "--out", str(base / "st")])
    return {"ppo": base / "ppo", "st": base / "st"}


def _workspace(root: Path, debug_runs: dict[str, Path]) -> dict[str, str]:
    """A fresh copy of the corpus, both runs and the made inputs; the placeholders of cases.yaml."""
    shutil.copytree(CORPUS, root / "corpus", ignore=shutil.ignore_patterns("*.py", "__pycache__"))
    _copy_run(debug_runs["ppo"], root / "ppo_run")
    _copy_run(debug_runs["st"], root / "st_run")
    _make_inputs(root)
    return {"corpus": str(root / "corpus"), "ws": str(root), "ppo_config": PPO_CONFIG, "st_config": ST_CONFIG,
            "ppo_run": str(root / "ppo_run"), "st_run": str(root / "st_run"), "made": str(root / "made"),
            "out": str(root / "new_run")}  # fmt: skip


def _fill(text: str, where: dict[str, str]) -> str:
    return re.sub(r"\{(\w+)\}", lambda m: where.get(m.group(1), m.group(0)), text)


def _tree(root: Path) -> dict[str, str]:
    """{relative path: SHA-256} of every file under ``root`` (and every folder, as "dir")."""
    return {str(p.relative_to(root)): "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*"))}  # fmt: skip


def _call(command: str, argv: list[str]) -> tuple[int, str]:
    """(exit status, the message of a ``sys.exit("...")``) of one in-process run of a command."""
    try:
        status = MAINS[command](argv)
    except SystemExit as e:
        if isinstance(e.code, str):
            return 1, e.code
        return int(e.code or 0), ""
    return int(status or 0), ""


@pytest.mark.parametrize("case", CASES, ids=[c["id"] for c in CASES])
def test_a_bad_input_gets_one_line_and_changes_nothing(
    case: dict[str, Any], debug_runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    where = _workspace(tmp_path, debug_runs)
    before = _tree(tmp_path)
    capsys.readouterr()
    status, message = _call(case["command"], [_fill(a, where) for a in case["args"]])
    err = capsys.readouterr().err
    lines = [line for line in (err + "\n" + message).splitlines() if line.strip()]
    assert status != 0, f"exit status 0; stderr: {err}"
    assert "Traceback" not in err
    assert len(lines) == 1, lines
    for name in case["names"]:
        assert _fill(name, where) in lines[0], lines[0]
    assert re.search(case["problem"], lines[0]), lines[0]
    assert _tree(tmp_path) == before  # nothing changed, added (no run directory, no report) or removed
    assert not (tmp_path / "MARKER").exists()  # no pickle ran


@pytest.mark.parametrize("case_id", ["clip_binary", "report_of_a_run_whose_checkpoints_run_code"])
def test_a_real_process_prints_that_one_line_and_no_traceback(
    case_id: str, debug_runs: dict[str, Path], tmp_path: Path
) -> None:
    case = next(c for c in CASES if c["id"] == case_id)
    where = _workspace(tmp_path, debug_runs)
    before = _tree(tmp_path)
    module = {"train-ppo": "ppo.train", "compare-trackers": "report.compare"}[case["command"]]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-m", module, *(_fill(a, where) for a in case["args"])], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 1 and done.stdout == ""
    (line,) = done.stderr.splitlines()
    assert line.startswith("error: ") and re.search(case["problem"], line)
    assert _tree(tmp_path) == before and not (tmp_path / "MARKER").exists()
