"""What a command writes, under faults of its own writers and of other commands: one line, its exit status, nothing
lost.

- A full disk under TensorBoard's writer thread (its ``RecordWriter.write`` raises ENOSPC from the N-th record on, in a
  real process): the run ends on its one error path, exit status 1, the line naming ``tb/``, and no thread prints a
  traceback; a resumed run keeps its checkpoints and continues once there is room.
- A second command on an output directory another process writes (:mod:`common.run.lock`): refused in one line naming
  the directory and that process, exit status 2, the workspace as it was. A lock left by a process killed with SIGKILL
  stops nothing: the kernel dropped it with the process.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch

from common.run.lock import LOCK_NAME
from ppo import train as train_ppo
from tests.bad_inputs.test_bad_inputs import (
    PPO_CONFIG,
    ROOT,
    SAMCON_CONFIG,
    ST_CONFIG,
    _call,
    _copy_run,
    _process,
    _tree,
)

ENV = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "PYTHONDONTWRITEBYTECODE": "1"}
# Runs a module as ``python -m`` does, TensorBoard's record writer failing from its FAIL_AT-th record on: a disk that
# fills under its writer thread. Arguments: module, FAIL_AT, the module's own arguments.
FULL_DISK_UNDER_TENSORBOARD = """
import errno, runpy, sys
from tensorboard.summary.writer import record_writer
module, fail_at = sys.argv[1], int(sys.argv[2])
sys.argv = [module, *sys.argv[3:]]
written, real_write = [0], record_writer.RecordWriter.write
def write(self, data):
    written[0] += 1
    if written[0] >= fail_at:
        raise OSError(errno.ENOSPC, "No space left on device")
    return real_write(self, data)
record_writer.RecordWriter.write = write
runpy.run_module(module, run_name="__main__", alter_sys=True)
"""
# Takes a directory's lock as a command does and holds it until killed.
HOLD_LOCK = """
import sys, time
from common.run.lock import DirectoryLock
DirectoryLock(sys.argv[1]).acquire()
print("locked", flush=True)
time.sleep(600)
"""


@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished debug run of train-ppo (4 iterations, a few seconds)."""
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("writers") / "ppo"
    assert train_ppo.main(["--config", PPO_CONFIG, "--out", str(out)]) == 0
    return out


def _full_disk_run(module: str, fail_at: int, args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", FULL_DISK_UNDER_TENSORBOARD, module, str(fail_at), *args], cwd=cwd,
                          env=ENV, capture_output=True, text=True, timeout=600)  # fmt: skip


def _one_error_line(done: subprocess.CompletedProcess[str], status: int) -> str:
    """The one ``error:`` line of a process that ended with ``status`` and printed no traceback from any thread."""
    assert done.returncode == status, done.stderr[-3000:]
    assert "Traceback" not in done.stderr and "Exception in thread" not in done.stderr, done.stderr[-3000:]
    (line,) = [line for line in done.stderr.splitlines() if line.startswith("error")]
    return line


def _no_temporary_or_lock_file(run: Path) -> None:
    assert not [p for p in run.rglob("*") if p.name.startswith(".")]  # no .lock, no temporary file


def test_a_full_disk_at_the_first_tensorboard_write_ends_in_one_line(tmp_path: Path) -> None:
    """A new run whose first TensorBoard record cannot be written (opened at the first log line): exit status 1, one
    line naming tb/, nothing written outside the run directory."""
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / "kept.txt").write_text("kept\n")
    before = _tree(tmp_path)
    out = tmp_path / "run"
    done = _full_disk_run("ppo.train", 1, ["--config", PPO_CONFIG, "--out", str(out)], tmp_path)
    assert _one_error_line(done, 1) == (f"error: run directory {out}: cannot write {out / 'tb'}: No space left on "
                                        "device; its checkpoints are intact (continue with --resume once it can be "
                                        "written)")  # fmt: skip
    assert {k: v for k, v in _tree(tmp_path).items() if not k.startswith("run")} == before
    assert len((out / "metrics.jsonl").read_text().splitlines()) == 1  # the record it failed on, before TensorBoard's
    _no_temporary_or_lock_file(out)


def test_a_disk_that_fills_under_the_writers_of_a_new_run_ends_in_one_line(tmp_path: Path) -> None:
    """The issue's probe: no file of the run may grow past 5,000 bytes (RLIMIT_FSIZE: the write fails with EFBIG).
    config.yaml and run_info.json fit; TensorBoard's events file outgrows it first, in its writer thread, unless
    metrics.jsonl does (both are logged at the same lines): one line naming that file, exit status 1, no traceback."""
    out = tmp_path / "run"
    done = _process({"command": "train-ppo", "file_size_limit": 5000,
                     "args": ["--config", PPO_CONFIG, "--out", str(out)]}, {}, tmp_path)  # fmt: skip
    line = _one_error_line(done, 1)
    assert re.fullmatch(f"error: run directory {re.escape(str(out))}: cannot write {re.escape(str(out))}/"
                        r"(tb|metrics\.jsonl): File too large; its checkpoints are intact \(continue with --resume "
                        r"once it can be written\)", line), line  # fmt: skip
    _no_temporary_or_lock_file(out)


def test_a_full_disk_under_tensorboard_mid_run_keeps_the_checkpoints(ppo_run: Path, tmp_path: Path) -> None:
    """A resumed run whose TensorBoard thread fails in its second log line: exit status 1, one line, the checkpoints
    and latest.json as they were; resumed again once there is room, it continues to its budget."""
    run = _copy_run(ppo_run, tmp_path / "run")
    checkpoints = {p.name: p.read_bytes() for p in (run / "checkpoints").iterdir()}
    per_line = max(len(json.loads(line)) - 3 for line in (run / "metrics.jsonl").read_text().splitlines())
    resume = ["--resume", "--out", str(run), "--max-iterations", "8"]
    # The resumed writer's first records: the file version and the session's start, then one per scalar logged.
    done = _full_disk_run("ppo.train", 3 + per_line + 1, resume, tmp_path)
    assert _one_error_line(done, 1) == (f"error: run directory {run}: cannot write {run / 'tb'}: No space left on "
                                        "device; its checkpoints are intact (continue with --resume once it can be "
                                        "written)")  # fmt: skip
    assert "ppo: 7/8" in done.stderr  # it failed during the run, not at its start
    assert {p.name: p.read_bytes() for p in (run / "checkpoints").iterdir()} == checkpoints
    _no_temporary_or_lock_file(run)
    assert train_ppo.main(resume) == 0
    assert json.loads((run / "checkpoints" / "latest.json").read_text())["latest"] == "ckpt_00000008.pt"


@pytest.fixture()
def holder() -> Iterator[list[subprocess.Popen[str]]]:
    """The lock-holding processes a test starts, killed at its end."""
    started: list[subprocess.Popen[str]] = []
    yield started
    for process in started:
        process.kill()
        process.wait(timeout=60)


def _hold_lock(directory: Path, started: list[subprocess.Popen[str]]) -> int:
    """Starts a process that holds ``directory``'s lock as a command does; its process id, once it holds it."""
    process = subprocess.Popen([sys.executable, "-c", HOLD_LOCK, str(directory)], env=ENV, stdout=subprocess.PIPE,
                               text=True)  # fmt: skip
    started.append(process)
    assert process.stdout is not None and process.stdout.readline() == "locked\n"
    return process.pid


LOCKED = [  # command, its arguments ({run}: a finished PPO run, {empty}: an empty folder), the folder it locks
    ("train-ppo", ["--resume", "--out", "{run}"], "run directory {run}"),
    ("train-supertrack", ["--config", ST_CONFIG, "--out", "{empty}"], "run directory {empty}"),
    ("track-samcon", ["--config", SAMCON_CONFIG, "--out", "{empty}"], "run directory {empty}"),
    ("compare-trackers", ["{run}", "--out", "{empty}", "--no-render", "--no-pushes"], "--out {empty}"),
]


@pytest.mark.parametrize(("command", "args", "folder"), LOCKED, ids=[c[0] for c in LOCKED])
def test_a_second_command_on_a_directory_in_use_is_refused_in_one_line(
        command: str, args: list[str], folder: str, ppo_run: Path, tmp_path: Path,
        holder: list[subprocess.Popen[str]], capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    where = {"run": str(_copy_run(ppo_run, tmp_path / "run")), "empty": str(tmp_path / "empty")}
    (tmp_path / "empty").mkdir()
    locked = folder.format(**where).removeprefix("--out ").removeprefix("run directory ")
    pid = _hold_lock(Path(locked), holder)
    before = _tree(tmp_path)
    capsys.readouterr()
    status, message = _call(command, [a.format(**where) for a in args])
    err = capsys.readouterr().err
    assert "Traceback" not in err and not message
    assert err.splitlines() == [f"error: {folder.format(**where)} is in use by process {pid}, which is writing it; "
                                "wait until it ends or choose another folder"]  # fmt: skip
    assert status == 2
    assert _tree(tmp_path) == before


def test_a_lock_left_by_a_killed_run_stops_nothing(ppo_run: Path, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """A real training run holds its run directory: a second resume is refused naming it; killed with SIGKILL, it
    leaves its .lock file (holding its dead id) but no lock, and the next resume trains to its budget."""
    run = _copy_run(ppo_run, tmp_path / "run")
    first = subprocess.Popen([sys.executable, "-m", "ppo.train", "--resume", "--out", str(run), "--max-iterations",
                              "1000000"], env=ENV, cwd=tmp_path, stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        deadline = time.monotonic() + 300
        while not ((run / LOCK_NAME).is_file() and (run / LOCK_NAME).read_text().strip() == str(first.pid)):
            assert first.poll() is None and time.monotonic() < deadline, "the first run never took its lock"
            time.sleep(0.1)
        capsys.readouterr()
        assert _call("train-ppo", ["--resume", "--out", str(run)]) == (2, "")
        assert capsys.readouterr().err.splitlines() == [
            f"error: run directory {run} is in use by process {first.pid}, which is writing it; wait until it ends or "
            "choose another folder"]  # fmt: skip
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=60)
    assert (run / LOCK_NAME).read_text().strip() == str(first.pid)  # stale: nobody holds its lock
    assert train_ppo.main(["--resume", "--out", str(run), "--max-iterations", "6"]) == 0
    assert json.loads((run / "checkpoints" / "latest.json").read_text())["latest"] == "ckpt_00000006.pt"
    assert not (run / LOCK_NAME).exists()


def test_a_lock_left_by_a_killed_holder_stops_no_report(ppo_run: Path, tmp_path: Path,
                                                        holder: list[subprocess.Popen[str]]) -> None:  # fmt: skip
    """compare-trackers into a folder whose lock holder was killed: the report is written, the stale file removed."""
    out = tmp_path / "report"
    out.mkdir()
    _hold_lock(out, holder)
    holder[0].send_signal(signal.SIGKILL)
    holder[0].wait(timeout=60)
    assert (out / LOCK_NAME).is_file()
    assert _call("compare-trackers", [str(ppo_run), "--out", str(out), "--no-render", "--no-pushes"]) == (0, "")
    assert (out / "report.md").is_file() and not (out / LOCK_NAME).exists()
