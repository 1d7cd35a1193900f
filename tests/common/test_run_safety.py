"""The run directory's guards, by hand: names that stay inside it (common.run.contained), its lock
(common.run.lock) and JSON read strictly (common.strict_json). The commands' side is in tests/bad_inputs."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from common.run.contained import check_run_directory, run_file
from common.run.lock import LOCK_NAME, DirectoryLock
from common.strict_json import DuplicateKeyError, parse_json


def test_a_link_inside_the_run_passes_and_one_out_is_named(tmp_path: Path) -> None:
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "kept.pt").write_bytes(b"x")
    (run / "checkpoints" / "ckpt_00000001.pt").symlink_to("../kept.pt")  # inside: fine
    (run / "notes").mkdir()
    (run / "notes" / "elsewhere").symlink_to(tmp_path)  # a folder of the user's: not a run's entry, not searched
    check_run_directory(run)
    (run / "tb").symlink_to(tmp_path / "tb")
    with pytest.raises(ValueError, match=rf"^{run / 'tb'}: a link to {tmp_path / 'tb'}, outside the run directory "
                                         rf"{run}; a run directory names only files inside itself$"):  # fmt: skip
        check_run_directory(run)


def test_a_name_the_run_gives_stays_inside_it(tmp_path: Path) -> None:
    run = tmp_path / "run"
    (run / "sub").mkdir(parents=True)
    assert run_file(run, "samcon.h5") == run / "samcon.h5"
    assert run_file(run, "sub/../samcon.h5") == run / "sub/../samcon.h5"
    absolute = str(run / "samcon.h5")  # refused even inside: a name that travels is relative
    outside = {"../x.h5": tmp_path / "x.h5", "/etc/passwd": Path("/etc/passwd"), ".": run, absolute: Path(absolute)}
    for name, target in outside.items():
        with pytest.raises(KeyError, match=f"names {name!r}, which leads outside the run directory \\(to {target}\\)"):
            run_file(run, name, KeyError, "run_info.json's policy_file")


def test_a_lock_is_one_holder_at_a_time_and_leaves_no_file(tmp_path: Path) -> None:
    first, second = DirectoryLock(tmp_path), DirectoryLock(tmp_path, RuntimeError, "run directory")
    with first:
        assert first.held and (tmp_path / LOCK_NAME).read_text() == f"{os.getpid()}\n"
        with pytest.raises(RuntimeError, match=f"^run directory {tmp_path} is in use by process {os.getpid()}, "):
            second.acquire()  # flock belongs to an open file: a second one conflicts, in one process too
        assert not second.held
    assert not first.held and not (tmp_path / LOCK_NAME).exists()
    (tmp_path / LOCK_NAME).write_text("999999\n")  # left by a killed holder: only a number, no lock
    with second:
        assert (tmp_path / LOCK_NAME).read_text() == f"{os.getpid()}\n"
    assert not (tmp_path / LOCK_NAME).exists()


def test_json_is_read_as_json_but_a_key_twice_is_refused_with_its_lines() -> None:
    plain = '{"a": {"b": [1, {"c": "d,\\"e\\": 1"}]}, "e": 1}'  # a key's look-alike inside a string is no key
    assert parse_json(plain) == json.loads(plain)
    text = '{"runs": [{"label": "a"},\n          {"label": "b",\n           "label": "c"}]}'
    with pytest.raises(DuplicateKeyError) as caught:
        parse_json(text)
    assert str(caught.value) == "duplicate key 'label' (first at line 2): line 3 column 12 (char 62)"
    assert (caught.value.lineno, caught.value.colno) == (3, 12)
    with pytest.raises(DuplicateKeyError, match=r"^duplicate key 'a' \(first at line 1\): line 1 column 10 "):
        parse_json('{"a": 1, "\\u0061": 2}')  # the same key, spelled with an escape
