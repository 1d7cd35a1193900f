"""Tests of common.run.checkpoint: only tensors, arrays and plain values are read; damage is found and passed over."""

from __future__ import annotations

import io
import json
import os
import pickle
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from common.run.checkpoint import CheckpointError, check_plain, load_checkpoint_file
from common.run.directory import RunDir, load_newest_checkpoint, read_checkpoint


class _WritesAMarker:
    """Unpickling this object calls ``open(marker, "w")``: the way a pickle runs code of its author's choosing."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, tuple[str, str]]:
        return (open, (str(self.marker), "w"))


def _state(x: float) -> dict[str, Any]:
    """Every kind of value a training checkpoint holds (RNG states as numpy and python give them)."""
    gen = np.random.default_rng(3)
    return {
        "w": torch.full((2, 3), x), "buffer": {"sim": np.arange(6, dtype=np.float32).reshape(2, 3),
                                               "done": np.array([True, False]), "count": np.int64(7)},
        "rng": {"numpy": gen.bit_generator.state, "python": (3, tuple(range(5)), None), "torch": torch.get_rng_state()},
        "names": ["walk", "run"], "lr": 1e-3, "none": None,
    }  # fmt: skip


def test_a_state_of_tensors_arrays_and_plain_values_round_trips_exactly(tmp_path: Path) -> None:
    run = RunDir(tmp_path / "r", resume=False)
    path = run.save_checkpoint(_state(1.5), iteration=1)
    got = load_checkpoint_file(path)
    want = _state(1.5)
    assert torch.equal(got["w"], want["w"]) and torch.equal(got["rng"]["torch"], want["rng"]["torch"])
    np.testing.assert_array_equal(got["buffer"]["sim"], want["buffer"]["sim"])
    assert got["buffer"]["sim"].dtype == np.float32 and got["buffer"]["done"].dtype == np.bool_
    assert got["buffer"]["count"] == 7 and got["rng"]["numpy"] == want["rng"]["numpy"]
    assert got["rng"]["python"] == want["rng"]["python"] and got["names"] == ["walk", "run"] and got["none"] is None


@pytest.mark.parametrize(("value", "where"), [
    ({"a": {"b": object()}}, r"state\.a\.b is a builtins\.object"),
    ({"a": [1, np.array(["x"])]}, r"state\.a\[1\]: numpy <U1 values"),
    ({"a": {1.5: 2}}, r"state\.a: key 1\.5 is a float"),
    ({"gen": np.random.default_rng(0)}, r"state\.gen is a numpy\.random\._generator\.Generator"),
])  # fmt: skip
def test_saving_anything_else_is_refused_naming_the_entry_and_writes_nothing(
    tmp_path: Path, value: dict[str, Any], where: str
) -> None:
    with pytest.raises(TypeError, match=where):
        check_plain(value)
    run = RunDir(tmp_path / "r", resume=False)
    with pytest.raises(TypeError, match=where):
        run.save_checkpoint(value, iteration=1)
    assert list(run.checkpoint_dir.iterdir()) == []


def test_a_checkpoint_whose_pickle_would_run_code_is_refused_and_nothing_runs(tmp_path: Path) -> None:
    marker = tmp_path / "marker"
    evil = tmp_path / "evil.pt"
    torch.save({"meta": {"learner": "ppo"}, "learner": _WritesAMarker(marker)}, evil)
    with pytest.raises(CheckpointError, match=rf"{evil}: refused, not opened: .*GLOBAL (io|builtins)\.open"):
        load_checkpoint_file(evil)
    # A bare pickle (not torch's zip format) is refused the same way.
    legacy = tmp_path / "legacy.pt"
    legacy.write_bytes(pickle.dumps({"x": _WritesAMarker(marker)}))
    with pytest.raises(CheckpointError, match=rf"{legacy}: refused, not opened"):
        load_checkpoint_file(legacy)
    assert not marker.exists()


@pytest.mark.parametrize(("damage", "problem"), [
    (lambda b: b[: len(b) // 2], r"truncated or damaged \(PytorchStreamReader failed reading zip archive"),
    (lambda b: b"", r"truncated or damaged \(EOFError\)"),
    (lambda b: b"not a checkpoint at all\n", r"refused, not opened: not a checkpoint as torch\.save writes them"),
])  # fmt: skip
def test_a_damaged_newest_checkpoint_is_passed_over_naming_it_and_the_problem(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], damage: Any, problem: str
) -> None:
    run = RunDir(tmp_path / "r", resume=False)
    run.save_checkpoint(_state(1.0), iteration=1)
    newest = run.save_checkpoint(_state(2.0), iteration=2)
    newest.write_bytes(damage(newest.read_bytes()))
    path, state, passed_over = load_newest_checkpoint(run.checkpoint_dir)
    assert path == run.checkpoint_path(1) and passed_over == [newest]
    assert torch.equal(state["w"], torch.full((2, 3), 1.0))
    (line,) = capsys.readouterr().err.splitlines()
    assert re.fullmatch(rf"warning: {re.escape(str(newest))}: {problem}.*; passed over", line)


def test_bits_flipped_inside_a_tensor_are_found_by_the_recorded_digest(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = RunDir(tmp_path / "r", resume=False)
    run.save_checkpoint(_state(1.0), iteration=1)
    newest = run.save_checkpoint(_state(2.0), iteration=2)
    data = bytearray(newest.read_bytes())
    at = data.find(np.full(6, 2.0, dtype=np.float32).tobytes())  # the tensor w's 6 float32s, stored raw in the zip
    assert at > 0
    data[at + 1] ^= 0x01
    newest.write_bytes(bytes(data))
    assert load_checkpoint_file(newest)["w"][0, 0] != 2.0  # without the digest, the changed value reads silently
    path, _, _ = load_newest_checkpoint(run.checkpoint_dir)
    assert path == run.checkpoint_path(1)
    assert capsys.readouterr().err == (f"warning: {newest}: damaged: its SHA-256 differs from the one recorded in "
                                       "latest.json when it was written; passed over\n")  # fmt: skip


def test_a_damaged_pointer_leaves_the_checkpoints_usable(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = RunDir(tmp_path / "r", resume=False)
    run.save_checkpoint(_state(1.0), iteration=1)
    run.pointer_path.write_text('{"latest": "ckpt_0000', encoding="utf-8")
    path, state, _ = load_newest_checkpoint(run.checkpoint_dir)
    assert path == run.checkpoint_path(1) and torch.equal(state["w"], torch.full((2, 3), 1.0))
    assert capsys.readouterr().err.startswith(f"warning: {run.pointer_path}: unreadable")
    run.save_checkpoint(_state(2.0), iteration=2)  # rewritten whole
    assert json.loads(run.pointer_path.read_text())["latest"] == "ckpt_00000002.pt"


def test_no_intact_checkpoint_lists_every_problem(tmp_path: Path) -> None:
    run = RunDir(tmp_path / "r", resume=False)
    for it in (1, 2):
        run.save_checkpoint(_state(it), iteration=it).write_bytes(b"")
    with pytest.raises(CheckpointError, match=r"no intact checkpoint \(.*ckpt_00000002\.pt: .*; .*ckpt_00000001\.pt"):
        load_newest_checkpoint(run.checkpoint_dir)


def test_a_write_that_fails_midway_keeps_the_previous_checkpoint_and_pointer(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run = RunDir(tmp_path / "r", resume=False)
    run.save_checkpoint(_state(1.0), iteration=1)
    before = {p.name: p.read_bytes() for p in run.checkpoint_dir.iterdir()}
    real_save = torch.save

    def disk_full(obj: Any, f: Any, *args: Any, **kwargs: Any) -> None:
        real_save(obj, f, *args, **kwargs)
        with open(f, "r+b") as out:  # half of it made it to disk
            out.truncate(os.path.getsize(f) // 2)
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(torch, "save", disk_full)
    with pytest.raises(OSError, match="No space left"):
        run.save_checkpoint(_state(2.0), iteration=2)
    assert {p.name: p.read_bytes() for p in run.checkpoint_dir.iterdir()} == before  # no partial file either
    monkeypatch.undo()
    assert read_checkpoint(run.path)[0] == run.checkpoint_path(1)


def test_read_checkpoint_names_what_is_not_a_checkpoint(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError, match=r"nowhere: no such checkpoint file or run directory"):
        read_checkpoint(tmp_path / "nowhere")
    with pytest.raises(CheckpointError, match=r": not a run directory \(no checkpoints/\)"):
        read_checkpoint(tmp_path)
    torch.save([1, 2], tmp_path / "list.pt")
    with pytest.raises(CheckpointError, match=r"list\.pt: holds a list, not a checkpoint's dict"):
        read_checkpoint(tmp_path / "list.pt")


def test_any_damage_to_a_checkpoint_reads_or_is_refused_naming_the_file(tmp_path: Path) -> None:
    path = RunDir(tmp_path / "r", resume=False).save_checkpoint(_state(1.0), iteration=1)
    good = path.read_bytes()
    with zipfile.ZipFile(path) as z:
        pickle_size = next(i for i in z.infolist() if i.filename.endswith("data.pkl")).file_size
    start = good.index(b"\x80\x02")  # torch writes data.pkl first, with pickle protocol 2 (opcode PROTO 2)
    rng = np.random.default_rng(0)
    seen = set()
    for trial in range(300):  # cut short, or one byte of the pickle changed: what disks and partial copies do
        data = bytearray(good)
        if trial % 10 == 0:
            data = data[: rng.integers(len(data))]
        else:
            data[start + rng.integers(pickle_size)] = rng.integers(256)
        bad = tmp_path / "bad.pt"
        bad.write_bytes(bytes(data))
        try:
            load_checkpoint_file(bad)
        except CheckpointError as e:
            assert str(e).startswith(f"{bad}: ")
            seen.add(str(e).split(" (")[1].split(" ")[0] if " (" in str(e) else str(e))
    # Torch's own errors for these are of many types (RuntimeError, OSError, KeyError, IndexError, AssertionError...).
    assert len(seen) >= 4, seen


class _DiskFull:
    """A binary file on a disk that has ``room`` bytes left: the write that would pass it raises ENOSPC."""

    def __init__(self, file: Any, room: int) -> None:
        self.file, self.room = file, room

    def write(self, data: Any) -> int:
        size = memoryview(data).nbytes
        if size > self.room:
            self.file.write(memoryview(data).cast("B")[: self.room])  # what fitted stays in the file
            self.room = 0
            raise OSError(28, "No space left on device")
        self.room -= size
        return self.file.write(data)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.file, name)

    def __enter__(self) -> _DiskFull:
        return self

    def __exit__(self, *exc: object) -> None:
        self.file.close()


def _fill_disk_at(room: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """From now on, files opened for writing fill the disk after ``room`` bytes: torch's own writer (given a path)
    fails as torch fails then, with its ``RuntimeError``, and Python's file objects raise ``OSError(ENOSPC)``."""
    real_open, real_save = Path.open, torch.save

    def open_(self: Path, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        file = real_open(self, mode, *args, **kwargs)
        return _DiskFull(file, room) if "w" in mode and "b" in mode else file

    def save(obj: Any, f: Any, *args: Any, **kwargs: Any) -> None:
        if not isinstance(f, (str, os.PathLike)):
            return real_save(obj, f, *args, **kwargs)
        with real_open(Path(f), "wb") as out:  # a full disk under torch's own writer: part of it, then torch's error
            out.write(b"PK\x03\x04" + b"\0" * max(0, room - 4))
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 768 vs 662")

    monkeypatch.setattr(Path, "open", open_)
    monkeypatch.setattr(torch, "save", save)


def test_a_disk_that_fills_at_any_byte_leaves_the_previous_checkpoint_and_no_temporary_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run = RunDir(tmp_path / "r", resume=False)
    run.save_checkpoint(_state(1.0), iteration=1)
    before = {p.name: p.read_bytes() for p in run.checkpoint_dir.iterdir()}
    size = _file_object_size({**_state(2.0), "iteration": 2})
    # Every 101st byte of the checkpoint, the first and the last: torch's RuntimeError, then the retry's ENOSPC.
    for room in [0, 1, *range(2, size, 101), size - 1]:
        with monkeypatch.context() as m:
            _fill_disk_at(room, m)
            with pytest.raises(OSError) as info:
                run.save_checkpoint(_state(2.0), iteration=2)
        assert (info.value.errno, info.value.filename) == (28, str(run.checkpoint_path(2))), room
        assert {p.name: p.read_bytes() for p in run.checkpoint_dir.iterdir()} == before, room
    assert read_checkpoint(run.path)[0] == run.checkpoint_path(1)


def test_a_checkpoint_fits_on_a_disk_with_exactly_its_room(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The retry through a file object writes the same bytes: when they fit, the checkpoint is written after all."""
    run = RunDir(tmp_path / "r", resume=False)
    with monkeypatch.context() as m:
        _fill_disk_at(_file_object_size({**_state(2.0), "iteration": 2}), m)
        run.save_checkpoint(_state(2.0), iteration=2)
    _, state, _ = load_newest_checkpoint(run.checkpoint_dir)
    assert torch.equal(state["w"], torch.full((2, 3), 2.0)) and state["iteration"] == 2
    assert sorted(p.name for p in run.checkpoint_dir.iterdir()) == ["ckpt_00000002.pt", "latest.json"]


def _file_object_size(state: dict[str, Any]) -> int:
    """Bytes of ``state`` saved by torch to a file object (its zip names its folder ``archive``, not the file's)."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    return len(buffer.getvalue())


def test_torch_failing_for_another_reason_keeps_its_traceback(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(obj: Any, f: Any, *args: Any, **kwargs: Any) -> None:
        raise RuntimeError("a bug inside torch")

    run = RunDir(tmp_path / "r", resume=False)
    monkeypatch.setattr(torch, "save", broken)
    with pytest.raises(RuntimeError, match="a bug inside torch"):
        run.save_checkpoint(_state(2.0), iteration=2)
    assert sorted(p.name for p in run.checkpoint_dir.iterdir()) == []


def test_hdf5_writers_on_a_disk_that_fills_keep_the_previous_file_and_leave_no_temporary_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A clip pack (the writer mimic-motions and the long clips use) built in memory by hdf5_output: a full disk at
    the first, the last and every 1,001st byte raises OSError naming the file, which keeps its previous content."""
    from common.motion.dataset import bundled_motion_dir, read_clip_pack
    from common.motion.motion import write_clip_pack

    sources = [bundled_motion_dir() / f"humanoid3d_{name}.txt" for name in ("walk", "jump")]
    pack = tmp_path / "pack.h5"
    write_clip_pack(pack, sources[:1])
    before = pack.read_bytes()
    write_clip_pack(tmp_path / "full.h5", sources)
    size = (tmp_path / "full.h5").stat().st_size
    for room in [0, *range(1, size, 1001), size - 1]:
        with monkeypatch.context() as m:
            _fill_disk_at(room, m)
            with pytest.raises(OSError) as info:
                write_clip_pack(pack, sources)
        assert (info.value.errno, info.value.filename) == (28, str(pack)), room
        assert pack.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["full.h5", "pack.h5"]
    write_clip_pack(pack, sources)  # with room, the same call writes the file the readers accept
    assert sorted(c.name for c in read_clip_pack(pack)) == ["jump", "walk"]
