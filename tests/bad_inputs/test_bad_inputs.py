"""The bad-input corpus (cases.yaml) through the real commands: one line naming the culprit, its exit status, no
traceback, no change.

Each case runs the command's ``main(argv)`` in process (fast: the debug runs are made once); a few also run as real
processes, to show that what a user sees on stderr is that one line and no traceback. A case with ``file_size_limit``
runs as a real process whose files cannot grow past that many bytes (``RLIMIT_FSIZE``): the disk "fills" at a chosen
byte under torch's, h5py's, onnx's and ffmpeg's own writers. Training on a full disk, which must leave its run
directory's earlier checkpoints intact, is tested below the corpus.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import re
import resource
import shutil
import signal
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
from report import compare, export_policy, watch
from samcon import track as track_samcon
from supertrack import train as train_supertrack

ROOT = Path(__file__).resolve().parents[2]
CORPUS = Path(__file__).resolve().parent
CASES: list[dict[str, Any]] = parse_yaml((CORPUS / "cases.yaml").read_text(encoding="utf-8"))
MAINS: dict[str, Callable[[list[str]], Any]] = {
    "train-ppo": train_ppo.main, "train-supertrack": train_supertrack.main, "compare-trackers": compare.main,
    "mimic-motions": motion_cli.main, "track-samcon": track_samcon.main, "watch-policy": watch.main,
    "export-policy": export_policy.main,
}  # fmt: skip
MODULES = {"train-ppo": "ppo.train", "train-supertrack": "supertrack.train", "compare-trackers": "report.compare",
           "mimic-motions": "common.tools.motions", "track-samcon": "samcon.track", "watch-policy": "report.watch",
           "export-policy": "report.export_policy"}  # fmt: skip
PPO_CONFIG = str(ROOT / "configs" / "ppo" / "debug.yaml")
ST_CONFIG = str(ROOT / "configs" / "supertrack" / "debug.yaml")
SAMCON_CONFIG = str(ROOT / "configs" / "samcon" / "debug.yaml")
# What a case may need of the machine: export-policy's packages, no CUDA GPU (a case asking for one).
NEEDS: dict[str, Callable[[], bool]] = {
    "onnx": lambda: all(importlib.util.find_spec(p) is not None for p in ("onnx", "onnxruntime", "onnxscript")),
    "no_cuda": lambda: not torch.cuda.is_available(),
}


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
    # A YAML tag asks the loader to build a Python object (here: run a shell command); the safe loader refuses it.
    (_copy_run(ppo_run, made / "yaml_tag_run") / "config.yaml").write_text(
        f"train: !!python/object/apply:os.system ['touch {marker}']\n", encoding="utf-8")
    (_copy_run(ppo_run, made / "list_info_run") / "run_info.json").write_text("[1, 2]\n", encoding="utf-8")
    info = _copy_run(ppo_run, made / "no_learner_run") / "run_info.json"
    info.write_text(json.dumps({k: v for k, v in json.loads(info.read_text(encoding="utf-8")).items()
                                if k != "learner"}), encoding="utf-8")  # fmt: skip
    (made / "a_file").write_text("not a directory\n", encoding="utf-8")
    _make_runs_naming_outside(ws, made, ppo_run, st_run)
    _make_runs_repeating_a_key(made, ppo_run)
    readonly = made / "readonly"
    _copy_run(ppo_run, readonly / "ppo_run")
    for path in sorted(readonly.rglob("*"), reverse=True) + [readonly]:
        path.chmod(0o555 if path.is_dir() else 0o444)


def _set_info(run: Path, **entries: Any) -> None:
    info = run / "run_info.json"
    info.write_text(json.dumps({**json.loads(info.read_text(encoding="utf-8")), **entries}), encoding="utf-8")


def _link_out(entry: Path, target: Path) -> None:
    """Replaces ``entry`` of a run by a link to ``target`` (outside the run), a copy of what ``entry`` held."""
    if entry.is_dir():
        shutil.copytree(entry, target)
        shutil.rmtree(entry)
    else:
        shutil.copy(entry, target)
        entry.unlink()
    entry.symlink_to(target)


def _make_runs_naming_outside(ws: Path, made: Path, ppo_run: Path, st_run: Path) -> None:
    """Runs that name a file outside themselves (common.run.contained). What they name outside is a good copy of what
    they held, so that only the place refuses it."""
    outside = ws / "outside"
    outside.mkdir()
    _set_info(_copy_run(ppo_run, made / "policy_file_up_run"), policy_file="../../../../etc/passwd")
    _set_info(_copy_run(ppo_run, made / "policy_file_absolute_run"), policy_file="/etc/passwd")
    _link_out(_only_checkpoint(_copy_run(ppo_run, made / "linked_checkpoint_run")), outside / "ckpt.pt")
    _link_out(_copy_run(ppo_run, made / "linked_checkpoints_run") / "checkpoints", outside / "checkpoints")
    _link_out(_copy_run(ppo_run, made / "linked_metrics_run") / "metrics.jsonl", outside / "metrics.jsonl")
    _link_out(_copy_run(st_run, made / "linked_config_run") / "config.yaml", outside / "config.yaml")
    _link_out(_only_checkpoint(_copy_run(st_run, made / "st_linked_checkpoint_run")), outside / "st_ckpt.pt")
    config = _copy_run(ppo_run, made / "base_outside_run") / "config.yaml"
    shutil.copy(config, outside / "base.yaml")
    config.write_text("base: ../../outside/base.yaml\n" + config.read_text(encoding="utf-8"), encoding="utf-8")


def _make_runs_repeating_a_key(made: Path, ppo_run: Path) -> None:
    """Runs whose JSON or YAML gives a key twice in one mapping (read strictly: common.strict_json, parse_yaml)."""
    info = _copy_run(ppo_run, made / "repeated_info_run") / "run_info.json"
    text = info.read_text(encoding="utf-8")
    assert '"learner": "ppo"' in text
    info.write_text(text.replace('"learner": "ppo"', '"learner": "ppo",\n  "learner": "samcon"'), encoding="utf-8")
    metrics = _copy_run(ppo_run, made / "repeated_metrics_run") / "metrics.jsonl"
    metrics.write_text('{"iteration": 1, "samples": 64, "iteration": 2}\n' + metrics.read_text(encoding="utf-8"),
                       encoding="utf-8")  # fmt: skip
    config = _copy_run(ppo_run, made / "repeated_config_run") / "config.yaml"
    text = config.read_text(encoding="utf-8")
    assert text.startswith("train:\n")
    config.write_text(text.replace("train:\n", "train:\n  seed: 5\n", 1), encoding="utf-8")


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
            "samcon_config": SAMCON_CONFIG, "ppo_run": str(root / "ppo_run"), "st_run": str(root / "st_run"),
            "made": str(root / "made"), "out": str(root / "new_run"), "file": str(root / "made" / "a_file"),
            "readonly": str(root / "made" / "readonly")}  # fmt: skip


def _read_only(where: dict[str, str], monkeypatch: pytest.MonkeyPatch) -> None:
    """Makes ``{readonly}`` read-only for root too. Its mode is 0o555, which stops any other user; root may write
    anywhere, so for root ``os.access`` reports what it reports to them (the commands ask it before writing)."""
    if os.geteuid() != 0:
        return
    real_access, folder = os.access, Path(where["readonly"])

    def access(path: Any, mode: int, *args: Any, **kwargs: Any) -> bool:
        inside = Path(os.fspath(path)).absolute()
        if mode & os.W_OK and (inside == folder or folder in inside.parents):
            return False
        return real_access(path, mode, *args, **kwargs)

    monkeypatch.setattr(os, "access", access)


def _skip_unless_possible(case: dict[str, Any]) -> None:
    for need in case.get("needs", []):
        if not NEEDS[need]():
            pytest.skip(f"needs {need}")


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


def _check_line(case: dict[str, Any], where: dict[str, str], lines: list[str]) -> None:
    assert len(lines) == 1, lines
    assert lines[0].startswith("error: "), lines[0]
    for name in case["names"]:
        assert _fill(name, where) in lines[0], lines[0]
    assert re.search(case["problem"], lines[0]), lines[0]


IN_PROCESS = [c for c in CASES if "file_size_limit" not in c]
FULL_DISK = [c for c in CASES if "file_size_limit" in c]


@pytest.mark.parametrize("case", IN_PROCESS, ids=[c["id"] for c in IN_PROCESS])
def test_a_bad_input_gets_one_line_and_changes_nothing(case: dict[str, Any], debug_runs: dict[str, Path],
                                                       tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                       monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    _skip_unless_possible(case)
    for name in ("DISPLAY", "WAYLAND_DISPLAY"):  # watch-policy writes a video then, as on a server
        monkeypatch.delenv(name, raising=False)
    where = _workspace(tmp_path, debug_runs)
    _read_only(where, monkeypatch)
    before = _tree(tmp_path)
    capsys.readouterr()
    status, message = _call(case["command"], [_fill(a, where) for a in case["args"]])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    _check_line(case, where, [line for line in (err + "\n" + message).splitlines() if line.strip()])
    assert status == case.get("status", 2), f"exit status {status}; stderr: {err}"
    assert _tree(tmp_path) == before  # nothing changed, added (no run directory, no report) or removed
    assert not (tmp_path / "MARKER").exists()  # no pickle ran, no YAML tag


def _process(case: dict[str, Any], where: dict[str, str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """The case's command as a real process (``python -m module``); with ``file_size_limit``, no file it writes may
    grow past that many bytes (as on a disk that fills there: the write fails with EFBIG instead of ENOSPC)."""
    limit = case.get("file_size_limit")

    def limit_files() -> None:
        if limit is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # else the process is killed; children inherit it
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "PYTHONDONTWRITEBYTECODE": "1"}
    return subprocess.run([sys.executable, "-m", MODULES[case["command"]], *(_fill(a, where) for a in case["args"])],
                          cwd=cwd, env=env, capture_output=True, text=True, timeout=600,
                          preexec_fn=limit_files)  # fmt: skip


REAL_PROCESS = ["clip_binary", "report_of_a_run_whose_checkpoints_run_code", "render_seconds_too_many_frames",
                "export_a_run_whose_config_has_a_yaml_tag"]  # fmt: skip


@pytest.mark.parametrize("case", [c for c in CASES if c["id"] in REAL_PROCESS] + FULL_DISK,
                         ids=[c["id"] for c in CASES if c["id"] in REAL_PROCESS] + [c["id"] for c in FULL_DISK])
def test_a_real_process_prints_that_one_line_and_no_traceback(case: dict[str, Any], debug_runs: dict[str, Path],
                                                              tmp_path: Path) -> None:  # fmt: skip
    _skip_unless_possible(case)
    where = _workspace(tmp_path, debug_runs)
    before = _tree(tmp_path)
    done = _process(case, where, tmp_path)
    assert "Traceback" not in done.stderr and done.returncode == case.get("status", 2), done.stderr[-3000:]
    _check_line(case, where, done.stderr.splitlines())
    assert _tree(tmp_path) == before and not (tmp_path / "MARKER").exists()  # no temporary file left either


def test_the_corpus_covers_every_command() -> None:
    counts = {command: sum(c["command"] == command for c in CASES) for command in MAINS}
    assert min(counts.values()) >= 5, counts
    assert len({c["id"] for c in CASES}) == len(CASES)


@pytest.mark.parametrize(("command", "learner"), [("train-ppo", "ppo"), ("train-supertrack", "st")])
def test_training_on_a_full_disk_ends_in_one_line_and_keeps_the_earlier_checkpoints(
        command: str, learner: str, debug_runs: dict[str, Path], tmp_path: Path) -> None:  # fmt: skip
    """The disk fills under torch's own writer (files may not grow past 100 kB: config, run info and metrics fit, a
    checkpoint of 0.6-1.2 MB does not): exit status 1, one error line naming the run directory, the earlier
    checkpoints and latest.json as they were, no temporary file; --resume then continues once there is room."""
    run = _copy_run(debug_runs[learner], tmp_path / "run")
    before = {p.name: p.read_bytes() for p in (run / "checkpoints").iterdir()}
    case = {"command": command, "file_size_limit": 100_000, "args": ["--resume", "--out", str(run),
                                                                     "--max-iterations", "8"]}  # fmt: skip
    done = _process(case, {}, tmp_path)
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr[-3000:]
    errors = [line for line in done.stderr.splitlines() if line.startswith("error")]
    assert errors == [f"error: cannot write the checkpoint of iteration 8 in {run / 'checkpoints'}: File too large; "
                      "the checkpoints already there are intact (continue with --resume once it can be written)"]
    assert {p.name: p.read_bytes() for p in (run / "checkpoints").iterdir()} == before
    assert not [p for p in run.rglob("*") if p.name.startswith(".")]  # no temporary file
    done = _process({**case, "file_size_limit": None}, {}, tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert json.loads((run / "checkpoints" / "latest.json").read_text())["latest"] == "ckpt_00000008.pt"


def test_convert_on_a_disk_that_fills_at_any_byte_keeps_the_old_dataset(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """``mimic-motions convert`` over an existing dataset, the disk full after ``room`` bytes (of Python's writes;
    the HDF5 file is built in memory, so h5py never meets the full disk): exit status 1, one line, the old file."""
    out = tmp_path / "motions.h5"
    assert motion_cli.main(["convert", "walk", "--out", str(out)]) == 0
    good = out.read_bytes()
    real_open = Path.open

    class DiskFull:
        def __init__(self, file: Any, room: int) -> None:
            self.file, self.room = file, room

        def write(self, data: Any) -> int:
            if memoryview(data).nbytes > self.room:
                self.file.write(memoryview(data).cast("B")[: self.room])
                raise OSError(28, "No space left on device")
            self.room -= memoryview(data).nbytes
            return self.file.write(data)

        def __enter__(self) -> Any:
            return self

        def __exit__(self, *exc: object) -> None:
            self.file.close()

    for room in [0, 1, *range(2, len(good), len(good) // 7), len(good) - 1]:
        with monkeypatch.context() as m:
            m.setattr(Path, "open", lambda self, mode="r", *a, room=room, **k: (
                DiskFull(real_open(self, mode, *a, **k), room) if "w" in mode else real_open(self, mode, *a, **k)))
            capsys.readouterr()
            assert motion_cli.main(["convert", "walk", "run", "--out", str(out)]) == 1
        (line,) = capsys.readouterr().err.splitlines()
        assert line == f"error: {out}: cannot write it: No space left on device; nothing was changed"
        assert out.read_bytes() == good and sorted(p.name for p in tmp_path.iterdir()) == ["motions.h5"], room


def test_a_run_that_cannot_write_its_first_files_leaves_nothing_so_the_same_out_works_after(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """A full disk before the first iteration (config.yaml cannot be written): exit status 1, one line, and the run
    directory and the folders made for it removed again, or, in an empty folder that existed, what was made in it."""
    from common.run.directory import RunDir

    def disk_full(self: RunDir, cfg: Any) -> None:
        raise OSError(28, "No space left on device", str(self.config_path))

    (tmp_path / "empty").mkdir()
    for out in (tmp_path / "new" / "run", tmp_path / "empty"):
        with monkeypatch.context() as m:
            m.setattr(RunDir, "save_config", disk_full)
            with pytest.raises(SystemExit) as info:
                train_ppo.main(["--config", PPO_CONFIG, "--out", str(out)])
        assert info.value.code == 1
        assert capsys.readouterr().err.splitlines()[-1] == (f"error: run directory {out}: cannot write "
                                                            f"{out / 'config.yaml'}: No space left on device")
        assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == ["empty"]
    assert train_ppo.main(["--config", PPO_CONFIG, "--max-iterations", "1", "--out", str(tmp_path / "empty")]) == 0
