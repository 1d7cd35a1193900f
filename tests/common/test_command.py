"""The training commands' shared main: bundled configs from any directory, --help, Ctrl-C, the learner registry."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from common.bundled_configs import CONFIG_ROOT, bundled_configs, resolve_config
from ppo.train import build_parser as ppo_parser
from samcon.track import build_parser as samcon_parser
from supertrack.train import build_parser as supertrack_parser

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parents[2]


def test_bundled_configs_are_listed_and_found_by_name_or_documented_path(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    assert bundled_configs("ppo") == ["debug.yaml", "default.yaml", "paper.yaml"]
    assert bundled_configs("no-such-command") == []
    monkeypatch.chdir(tmp_path)  # outside the repository: nothing relative to the working directory exists
    paper = CONFIG_ROOT / "supertrack" / "paper.yaml"
    assert resolve_config("paper", "supertrack") == paper
    assert resolve_config("paper.yaml", "supertrack") == paper
    assert resolve_config("configs/supertrack/paper.yaml", "supertrack") == paper
    assert resolve_config("nosuch", "supertrack") == Path("nosuch")  # left as written, for the loader's message
    mine = tmp_path / "paper.yaml"  # a file of the user's own wins over the bundled one of the same name
    mine.write_text("train: {}\n")
    assert resolve_config("paper.yaml", "supertrack") == Path("paper.yaml")


@pytest.mark.parametrize(("parser", "names"), [
    (supertrack_parser, "debug, default, paper"),
    (ppo_parser, "debug, default, paper"),
    (samcon_parser, "debug, default, feedback-walk, lqr-walk, oracle, polish"),
])  # fmt: skip
def test_help_lists_the_bundled_configs_without_markup(parser, names: str) -> None:  # noqa: ANN001
    text = " ".join(parser().format_help().split())  # argparse wraps the help text
    assert f"the name of a bundled one ({names};" in text
    assert "``" not in text and ":func:" not in text and ":mod:" not in text


def _command(name: str) -> list[str]:
    script = BIN / name
    assert script.is_file(), f"{script}: the project's console scripts are not installed in this environment"
    return [str(script)]


def _outside_env() -> dict[str, str]:
    """The environment without PYTHONPATH: the command must find the package and its configs by itself."""
    return {**{k: v for k, v in os.environ.items() if k != "PYTHONPATH"}, "OMP_NUM_THREADS": "1"}


@pytest.mark.parametrize("command", ["train-supertrack", "train-ppo"])
def test_a_training_command_runs_from_a_directory_outside_the_repository(command: str, tmp_path: Path) -> None:
    proc = subprocess.run([*_command(command), "--config", "debug", "--max-iterations", "2", "--out", "run"],
                          cwd=tmp_path, env=_outside_env(), capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    info = json.loads((tmp_path / "run" / "run_info.json").read_text())
    assert (tmp_path / "run" / "checkpoints" / "latest.json").is_file() and info["seed"] == 0
    assert not (ROOT / "run").exists()


def test_track_samcon_finds_its_bundled_config_from_a_directory_outside_the_repository(tmp_path: Path) -> None:
    # The debug config (6 frames of walk, a few samples): the search runs and the run directory is written where asked.
    proc = subprocess.run([*_command("track-samcon"), "--config", "debug", "--motions", "walk", "--out", "run"],
                          cwd=tmp_path, env=_outside_env(), capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads((tmp_path / "run" / "run_info.json").read_text())["learner"] == "samcon"


@pytest.mark.parametrize("command", ["train-supertrack", "train-ppo"])
def test_ctrl_c_stops_after_the_iteration_with_an_evaluation_and_a_checkpoint(command: str, tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc = subprocess.Popen([*_command(command), "--config", "debug", "--max-iterations", "100000", "--out", str(out),
                             "--set", "train.eval_every_iterations=100000", "--set", "train.log_every=1"],
                            cwd=tmp_path, env=_outside_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None:
            metrics = out / "metrics.jsonl"
            if metrics.is_file() and metrics.read_text().count("\n") >= 2:
                break
            time.sleep(0.2)
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr[-2000:]
    assert "stopping after this iteration" in stderr and "Traceback" not in stderr
    latest = json.loads((out / "checkpoints" / "latest.json").read_text())
    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert "eval/mpjpe_g" in records[-1] and str(records[-1]["iteration"]) in json.dumps(latest)


@pytest.mark.parametrize("command", ["train-supertrack", "train-ppo", "track-samcon", "compare-trackers",
                                     "watch-policy", "export-policy", "mimic-motions"])  # fmt: skip
def test_every_commands_help_is_plain_text(command: str) -> None:
    proc = subprocess.run([*_command(command), "--help"], env=_outside_env(), capture_output=True, text=True,
                          timeout=120)  # fmt: skip
    assert proc.returncode == 0 and proc.stdout.startswith("usage: "), proc.stderr[-2000:]
    for markup in ("``", ":mod:", ":func:", ":class:", ":meth:", "::\n"):
        assert markup not in proc.stdout, f"{command} --help shows {markup!r}"
