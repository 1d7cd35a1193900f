"""Tests of common.cli: the one error path of every command (one line, exit status 2 or 1, bugs keep tracebacks)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

from common.cli import (
    EXIT_BAD_INPUT,
    EXIT_RUN_FAILED,
    CommandError,
    CommandParser,
    check_output_dir,
    check_output_file,
    exit_status,
    frame_count,
    non_negative_float,
    one_line,
    one_line_errors,
    output_dir_problem,
    output_file_problem,
)
from common.config import ConfigError


def _run(body: Any, *expected: type[BaseException]) -> None:
    with one_line_errors(*expected):
        body()


def test_an_expected_error_ends_in_one_line_and_status_2(capsys: pytest.CaptureFixture[str]) -> None:
    def body() -> None:
        raise ConfigError("configs/x.yaml: checkpoint a.pt is incompatible (2 differences):\n  lr: 1, 2\n  seed: 0, 1")

    with pytest.raises(CommandError) as info:
        _run(body, ConfigError)
    assert info.value.code == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err == "error: configs/x.yaml: checkpoint a.pt is incompatible (2 differences): lr: 1, 2; seed: 0, 1\n"


def test_an_os_error_ends_in_one_line_naming_the_file_and_status_1(capsys: pytest.CaptureFixture[str]) -> None:
    def body() -> None:
        raise OSError(28, "No space left on device", "runs/a/metrics.jsonl")

    with pytest.raises(CommandError) as info:
        _run(body)
    assert info.value.code == EXIT_RUN_FAILED
    assert capsys.readouterr().err == "error: runs/a/metrics.jsonl: No space left on device\n"


def test_a_message_exit_and_a_command_error_print_their_line_once(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(CommandError) as info:
        _run(lambda: exit("error: --init-from x.pt: not a SuperTrack checkpoint"))
    assert info.value.code == 2 and str(info.value) == "error: --init-from x.pt: not a SuperTrack checkpoint"

    def failed() -> None:
        raise CommandError("the run failed", EXIT_RUN_FAILED)

    with pytest.raises(CommandError) as info:
        _run(failed)
    assert info.value.code == 1
    assert capsys.readouterr().err == "error: --init-from x.pt: not a SuperTrack checkpoint\nerror: the run failed\n"


def test_an_unexpected_exception_keeps_its_traceback(capsys: pytest.CaptureFixture[str]) -> None:
    def bug() -> None:
        raise ValueError("a bug")

    with pytest.raises(ValueError, match="a bug"):
        _run(bug, ConfigError)
    with pytest.raises(SystemExit) as info:  # argparse's own status passes through
        _run(lambda: exit(0))
    assert info.value.code == 0 and capsys.readouterr().err == ""


def test_exit_status_returns_the_status_of_a_command_that_returns_it(capsys: pytest.CaptureFixture[str]) -> None:
    def refused() -> int:
        raise ConfigError("x.yaml: unknown key 'a'")

    assert exit_status(refused, ConfigError) == 2 and exit_status(lambda: 0) == 0
    assert capsys.readouterr().err == "error: x.yaml: unknown key 'a'\n"


def test_one_line_drops_a_key_errors_quotes_and_joins_lines() -> None:
    assert one_line(KeyError("no clip 'x' in the library")) == "no clip 'x' in the library"
    assert one_line(ValueError("error: a\n\n  b:\n  c")) == "a; b: c"
    assert one_line(ValueError()) == "ValueError"


def test_an_option_error_is_one_line_with_status_2(capsys: pytest.CaptureFixture[str]) -> None:
    parser = CommandParser(prog="tool")
    parser.add_argument("--frames", type=frame_count)
    parser.add_argument("--minutes", type=non_negative_float)
    for argv, message in [(["--frames", "0"], "--frames: must be an integer from 1 to 36000, got 0"),
                          (["--frames", "2.5"], "--frames: must be an integer from 1 to 36000, got '2.5'"),
                          (["--minutes", "inf"], "--minutes: must be a finite number >= 0, got inf"),
                          (["--nope"], "unrecognized arguments: --nope")]:  # fmt: skip
        with pytest.raises(SystemExit) as info:
            parser.parse_args(argv)
        assert info.value.code == 2
        assert capsys.readouterr().err == f"error: {message} (see tool --help)\n"


def test_output_paths_are_refused_before_anything_is_made(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "file").write_text("x")
    (tmp_path / "dir").mkdir()
    assert output_dir_problem(tmp_path / "new" / "deeper") is None and output_dir_problem(tmp_path / "dir") is None
    assert output_dir_problem(tmp_path / "file") == "exists and is not a directory"
    assert output_dir_problem(tmp_path / "file" / "run") == f"{tmp_path / 'file'} is a file, not a directory"
    assert output_file_problem(tmp_path / "dir") == "is a directory; give a file name"
    assert output_file_problem(tmp_path / "file" / "a" / "b.h5") == f"{tmp_path / 'file'} is a file, not a directory"
    assert output_file_problem(tmp_path / "file") is None and output_file_problem(tmp_path / "new" / "b.h5") is None
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **k: Path(p) != tmp_path / "dir" and real_access(p, mode, **k))
    assert output_dir_problem(tmp_path / "dir" / "run") == f"{tmp_path / 'dir'} is not writable"
    with pytest.raises(CommandError, match=rf"^error: --onnx {tmp_path / 'dir' / 'p.onnx'}: .* is not writable$"):
        check_output_file(tmp_path / "dir" / "p.onnx", "--onnx")
    with pytest.raises(CommandError, match=r"^error: --out .*file: exists and is not a directory$"):
        check_output_dir(tmp_path / "file")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir", "file"]
