"""Tests of common.sim.buffer.CyclicBuffer against hand-computed layouts and windows."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

from common.sim.buffer import CyclicBuffer

FIELDS = {"step": ((), "int64"), "pos": ((2, 3), "float32")}


def _push_step(
    buf: CyclicBuffer,
    step: int,
    ids: list[int],
    term: Sequence[bool] | None = None,
    trunc: Sequence[bool] | None = None,
) -> None:
    """Push step ``step`` with ``pos`` = step + env / 10 so every frame is identifiable."""
    n = buf.num_envs
    pos = np.broadcast_to((step + np.arange(n) / 10)[:, None, None], (n, 2, 3)).astype(np.float32)
    extra: dict[str, np.ndarray] = {}
    if term is not None:
        extra["terminated"] = np.asarray(term, dtype=bool)
    if trunc is not None:
        extra["truncated"] = np.asarray(trunc, dtype=bool)
    buf.push(step=np.full(n, step, dtype=np.int64), pos=pos, episode_id=np.asarray(ids, np.int64), **extra)


def _tiny_buffer() -> CyclicBuffer:
    """3 characters, 5 rows, 7 pushes (steps 0..6, steps 2..6 stored, head = 2).

    Episode ids per step (done after the marked step):
        char 0: 0 0* 10 10 10+ 20 20   (* terminated, + truncated)
        char 1: 1 1  1  1* 11 11 11
        char 2: 2 2  2  2  2  2  2
    """
    buf = CyclicBuffer(15, 3, FIELDS)
    ids = [(0, 1, 2), (0, 1, 2), (10, 1, 2), (10, 1, 2), (10, 11, 2), (20, 11, 2), (20, 11, 2)]
    term = {1: (True, False, False), 3: (False, True, False)}
    trunc = {4: (True, False, False)}
    for step, step_ids in enumerate(ids):
        _push_step(buf, step, list(step_ids), term.get(step), trunc.get(step))
    return buf


def _episodic_buffer(num_steps: int) -> tuple[CyclicBuffer, np.ndarray]:
    """3 characters, 20 rows, episode lengths cycling per character; returns ids table (steps, N)."""
    buf = CyclicBuffer(60, 3, FIELDS)
    lengths = [[3, 1, 6], [5, 2], [7, 4, 9]]
    next_id = 0
    ids = np.zeros((num_steps, 3), dtype=np.int64)
    current = [0, 0, 0]
    left = [0, 0, 0]
    episode_count = [0, 0, 0]
    for step in range(num_steps):
        done = [False, False, False]
        for n in range(3):
            if left[n] == 0:
                current[n] = next_id
                next_id += 1
                left[n] = lengths[n][episode_count[n] % len(lengths[n])]
                episode_count[n] += 1
            left[n] -= 1
            done[n] = left[n] == 0
        ids[step] = current
        # Alternate the kind of ending so both flags are exercised.
        term = [d and step % 2 == 0 for d in done]
        trunc = [d and step % 2 == 1 for d in done]
        _push_step(buf, step, list(current), term, trunc)
    return buf, ids


def test_push_len_head_arithmetic() -> None:
    buf = CyclicBuffer(10, 3, FIELDS)  # rows = 10 // 3 = 3
    assert (buf.rows, buf.size, buf.head, len(buf), buf.total_pushed) == (3, 0, 0, 0, 0)
    expected = [(1, 1, 3), (2, 2, 6), (0, 3, 9), (1, 3, 9), (2, 3, 9)]  # (head, size, len) after each push
    for step, (head, size, length) in enumerate(expected):
        _push_step(buf, step, [0, 1, 2])
        assert (buf.head, buf.size, len(buf), buf.total_pushed) == (head, size, length, step + 1)
    buf.clear()
    assert (buf.head, buf.size, len(buf), buf.total_pushed) == (0, 0, 0, 5)


def test_constructor_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="capacity"):
        CyclicBuffer(2, 3, FIELDS)
    with pytest.raises(ValueError, match="episode_id"):
        CyclicBuffer(10, 2, {"episode_id": ((), "int64")})


def test_nbytes_matches_hand_count() -> None:
    buf = CyclicBuffer(10, 3, FIELDS)
    # rows 3 x 3 chars x (step 8 + pos 6*4 + episode_id 8 + terminated 1 + truncated 1) bytes
    assert buf.nbytes == 3 * 3 * (8 + 24 + 8 + 1 + 1) == 378


def test_latest_order_before_and_after_wrap() -> None:
    buf = CyclicBuffer(8, 2, FIELDS)  # rows = 4
    for step in range(3):
        _push_step(buf, step, [0, 1])
    out = buf.latest(2)
    np.testing.assert_array_equal(out["step"], [[1, 1], [2, 2]])
    np.testing.assert_allclose(out["pos"][:, :, 0, 0], [[1.0, 1.1], [2.0, 2.1]], rtol=1e-6)
    assert out["pos"].shape == (2, 2, 2, 3)
    for step in range(3, 6):
        _push_step(buf, step, [0, 1])
    assert buf.head == 2
    np.testing.assert_array_equal(buf.latest(4)["step"], [[2, 2], [3, 3], [4, 4], [5, 5]])
    np.testing.assert_array_equal(buf.latest(1)["step"], [[5, 5]])
    np.testing.assert_array_equal(buf.latest(4)["episode_id"], [[0, 1]] * 4)
    assert buf.latest(3)["terminated"].shape == (3, 2)
    with pytest.raises(ValueError, match="5 time steps, 4 stored"):
        buf.latest(5)


def test_valid_window_starts_match_hand_enumeration() -> None:
    buf = _tiny_buffer()
    assert (buf.head, buf.size) == (2, 5)
    # Rows are chronological starts = steps 2, 3, 4, 5; columns characters 0, 1, 2.
    expected_len2 = [[True, True, True], [True, False, True], [False, True, True], [True, True, True]]
    np.testing.assert_array_equal(buf.valid_window_starts(2), expected_len2)
    expected_len3 = [[True, False, True], [False, False, True], [False, True, True]]
    np.testing.assert_array_equal(buf.valid_window_starts(3), expected_len3)


@pytest.mark.parametrize(
    ("length", "expected"),
    [
        (2, {(2, 0), (3, 0), (5, 0), (2, 1), (4, 1), (5, 1), (2, 2), (3, 2), (4, 2), (5, 2)}),
        (3, {(2, 0), (4, 1), (2, 2), (3, 2), (4, 2)}),
        (5, {(2, 2)}),
    ],
)
def test_sampler_returns_exactly_the_valid_starts(length: int, expected: set[tuple[int, int]]) -> None:
    buf = _tiny_buffer()
    out = buf.sample_windows(2000, length, np.random.default_rng(0))
    starts = list(zip(out["step"][:, 0].tolist(), out["env_index"].tolist(), strict=True))
    assert set(starts) == expected
    # Uniform: each of the k starts expects 2000 / k hits; the seeded draw stays within 25 %.
    counts = np.array([starts.count(s) for s in expected])
    assert np.all(np.abs(counts - 2000 / len(expected)) < 0.25 * 2000 / len(expected))
    # Step s is written to row s % 5; a window never crosses the head (steps 6 -> 2 of character 2).
    np.testing.assert_array_equal(out["row_index"], out["step"][:, 0] % 5)
    np.testing.assert_array_equal(np.diff(out["step"], axis=1), 1)


def test_done_flag_allowed_only_on_last_frame() -> None:
    buf = _tiny_buffer()
    out = buf.sample_windows(500, 2, np.random.default_rng(1))
    hit = (out["env_index"] == 0) & (out["step"][:, 0] == 3)  # steps 3, 4 of char 0, truncated at 4
    assert hit.any()
    np.testing.assert_array_equal(out["truncated"][hit], [[False, True]] * int(hit.sum()))
    assert not out["terminated"][:, :-1].any() and not out["truncated"][:, :-1].any()


@pytest.mark.parametrize("length", [1, 4, 8])
def test_windows_never_cross_episodes_or_head(length: int) -> None:
    buf, ids = _episodic_buffer(70)  # 70 pushes into 20 rows: the ring wraps 3 times
    assert (buf.size, buf.head) == (20, 10)
    out = buf.sample_windows(3000, length, np.random.default_rng(length))
    assert out["step"].shape == (3000, length) and out["pos"].shape == (3000, length, 2, 3)
    np.testing.assert_array_equal(out["episode_id"], np.repeat(out["episode_id"][:, :1], length, axis=1))
    np.testing.assert_array_equal(out["step"] - out["step"][:, :1], np.tile(np.arange(length), (3000, 1)))
    assert out["step"].min() >= 50 and out["step"].max() <= 69
    env = out["env_index"]
    np.testing.assert_array_equal(out["episode_id"], ids[out["step"], env[:, None]])
    np.testing.assert_allclose(out["pos"][:, :, 1, 2], out["step"] + env[:, None] / 10, rtol=1e-6)
    assert not (out["terminated"] | out["truncated"])[:, :-1].any()


def test_not_enough_frames_raises() -> None:
    buf = CyclicBuffer(15, 3, FIELDS)
    _push_step(buf, 0, [0, 1, 2])
    with pytest.raises(ValueError, match="1 time steps x 3 characters = 3 frames stored, 0 valid"):
        buf.sample_windows(4, 2, np.random.default_rng(0))
    with pytest.raises(ValueError, match="length 6 exceeds the buffer's 5 rows"):
        buf.sample_windows(4, 6, np.random.default_rng(0))
    # Every episode lasts one step: plenty of frames, still no window of length 2.
    short = CyclicBuffer(15, 3, FIELDS)
    for step in range(5):
        _push_step(short, step, [3 * step, 3 * step + 1, 3 * step + 2], term=[True] * 3)
    with pytest.raises(ValueError, match="15 frames stored, 0 valid window starts"):
        short.sample_windows(4, 2, np.random.default_rng(0))


def test_push_rejects_bad_fields() -> None:
    buf = CyclicBuffer(15, 3, FIELDS)
    good = {"step": np.zeros(3, np.int64), "pos": np.zeros((3, 2, 3), np.float32), "episode_id": np.zeros(3)}
    with pytest.raises(ValueError, match=r"'pos' expected shape \(3, 2, 3\), given shape \(3, 2, 2\)"):
        buf.push(**{**good, "pos": np.zeros((3, 2, 2))})
    with pytest.raises(ValueError, match=r"'terminated' expected shape \(3,\), given shape \(2,\)"):
        buf.push(**good, terminated=np.zeros(2, bool))
    with pytest.raises(ValueError, match=r"missing fields \['step'\]"):
        buf.push(pos=good["pos"], episode_id=good["episode_id"])
    with pytest.raises(ValueError, match=r"unknown fields \['vel'\]"):
        buf.push(**good, vel=np.zeros(3))
    assert (buf.size, buf.total_pushed) == (0, 0)


def test_push_rejects_episode_ids_that_break_uniqueness() -> None:
    buf = CyclicBuffer(15, 3, FIELDS)
    _push_step(buf, 0, [5, 6, 7], term=[False, True, False])
    with pytest.raises(ValueError, match=r"characters \[1\]"):
        _push_step(buf, 1, [5, 6, 8])  # char 1 keeps its id after a done frame
    with pytest.raises(ValueError, match=r"characters \[0\]"):
        _push_step(buf, 1, [4, 9, 7])  # char 0 goes back
    _push_step(buf, 1, [5, 9, 7])
    assert buf.size == 2


def test_sample_windows_is_deterministic() -> None:
    buf, _ = _episodic_buffer(45)
    a = buf.sample_windows(64, 4, np.random.default_rng(123))
    b = buf.sample_windows(64, 4, np.random.default_rng(123))
    c = buf.sample_windows(64, 4, np.random.default_rng(124))
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    assert not np.array_equal(a["step"], c["step"])


@pytest.mark.parametrize("num_steps", [0, 7, 20, 53])
def test_hdf5_round_trip(tmp_path: Path, num_steps: int) -> None:
    buf, _ = _episodic_buffer(num_steps)
    path = tmp_path / "buf.h5"
    buf.save(path)
    loaded = CyclicBuffer.load(path, fields=FIELDS)
    assert (loaded.capacity, loaded.num_envs, loaded.rows) == (60, 3, 20)
    assert (loaded.size, loaded.total_pushed) == (min(num_steps, 20), num_steps)
    assert loaded.head == loaded.size % 20
    assert loaded.fields == buf.fields
    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == "mimictrack.cyclic_buffer" and f.attrs["version"] == 1
        assert tuple(f["pos"].attrs["shape"]) == (2, 3) and np.dtype(f["pos"].attrs["dtype"]) == np.float32
        np.testing.assert_array_equal(f["step"][:, 0], np.arange(num_steps - loaded.size, num_steps))
    want, got = buf.latest(buf.size), loaded.latest(loaded.size)
    for key in want:
        np.testing.assert_array_equal(got[key], want[key])
        assert got[key].dtype == want[key].dtype
    if num_steps >= 20:
        # Same chronological starts for the same seed; only the physical row differs after reloading.
        a = buf.sample_windows(32, 4, np.random.default_rng(5))
        b = loaded.sample_windows(32, 4, np.random.default_rng(5))
        for key in a.keys() - {"row_index"}:
            np.testing.assert_array_equal(a[key], b[key])


@pytest.mark.parametrize("num_steps", [0, 7, 53])
def test_state_dict_round_trip_continues_exactly(num_steps: int) -> None:
    buf, _ = _episodic_buffer(num_steps)
    copy = CyclicBuffer(60, 3, FIELDS)
    copy.load_state_dict(buf.state_dict())
    assert (copy.size, copy.total_pushed) == (buf.size, buf.total_pushed)
    for b in (buf, copy):  # both go on the same way: 4 more steps, with new episode ids
        for step in range(num_steps, num_steps + 4):
            _push_step(b, step, [1000 + step] * 3, term=[True] * 3)
    want, got = buf.latest(buf.size), copy.latest(copy.size)
    for key in want:
        np.testing.assert_array_equal(got[key], want[key])
    a, b = (x.sample_windows(16, 1, np.random.default_rng(2)) for x in (buf, copy))
    for key in a.keys() - {"row_index"}:
        np.testing.assert_array_equal(a[key], b[key])


def test_load_state_dict_rejects_bad_state_and_keeps_its_rows() -> None:
    buf = _tiny_buffer()
    before = buf.latest(buf.size)
    state = buf.state_dict()
    bad_shape = {**state, "rows": {**state["rows"], "pos": state["rows"]["pos"][:, :, :1]}}
    with pytest.raises(ValueError, match=r"field 'pos' expected shape \(5, 3, 2, 3\)"):
        buf.load_state_dict(bad_shape)
    missing = {**state, "rows": {k: v for k, v in state["rows"].items() if k != "step"}}
    with pytest.raises(ValueError, match=r"missing fields \['step'\]"):
        buf.load_state_dict(missing)
    with pytest.raises(ValueError, match="do not fit in 2 rows"):
        CyclicBuffer(6, 3, FIELDS).load_state_dict(state)
    assert (buf.size, buf.head, buf.total_pushed) == (5, 2, 7)
    for key, value in buf.latest(buf.size).items():
        np.testing.assert_array_equal(value, before[key])


def test_load_with_smaller_capacity_keeps_newest_rows(tmp_path: Path) -> None:
    buf, _ = _episodic_buffer(53)
    buf.save(tmp_path / "buf.h5")
    loaded = CyclicBuffer.load(tmp_path / "buf.h5", capacity=15)
    assert (loaded.rows, loaded.size, loaded.head) == (5, 5, 0)
    np.testing.assert_array_equal(loaded.latest(5)["step"][:, 0], [48, 49, 50, 51, 52])


@pytest.mark.parametrize(
    ("fields", "match"),
    [
        ({"step": ((), "int64"), "pos": ((2, 2), "float32")}, r"field 'pos' expected shape \(2, 2\)"),
        (
            {"step": ((), "int32"), "pos": ((2, 3), "float32")},
            r"field 'step' expected shape \(\) dtype int32",
        ),
        ({"step": ((), "int64")}, r"extra fields \['pos'\]"),
        ({**FIELDS, "vel": ((3,), "float32")}, r"fields \['vel'\] are missing"),
    ],
)
def test_load_layout_mismatch_names_field(
    tmp_path: Path, fields: dict[str, tuple[tuple[int, ...], str]], match: str
) -> None:
    buf, _ = _episodic_buffer(5)
    path = tmp_path / "buf.h5"
    buf.save(path)
    with pytest.raises(ValueError, match=match) as info:
        CyclicBuffer.load(path, fields=fields)
    assert str(path) in str(info.value)


def test_load_rejects_truncated_and_foreign_files(tmp_path: Path) -> None:
    buf, _ = _episodic_buffer(25)
    good = tmp_path / "good.h5"
    buf.save(good)
    data = good.read_bytes()
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="truncated.h5: cannot read buffer file"):
        CyclicBuffer.load(truncated)
    text = tmp_path / "notes.h5"
    text.write_text("not hdf5")
    with pytest.raises(ValueError, match="notes.h5: cannot read buffer file"):
        CyclicBuffer.load(text)
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["format"] = "something.else"
    with pytest.raises(ValueError, match="other.h5: format 'something.else'"):
        CyclicBuffer.load(other)
    future = tmp_path / "future.h5"
    future.write_bytes(data)
    with h5py.File(future, "a") as f:
        f.attrs["version"] = 2
    with pytest.raises(ValueError, match="future.h5: layout version 2"):
        CyclicBuffer.load(future)


def test_failed_save_keeps_existing_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    old, _ = _episodic_buffer(10)
    path = tmp_path / "buf.h5"
    old.save(path)
    before = path.read_bytes()
    new, _ = _episodic_buffer(30)
    calls = itertools.count()
    original = h5py.Group.create_dataset

    def failing_create_dataset(self: h5py.Group, *args: Any, **kwargs: Any) -> h5py.Dataset:
        if next(calls) == 2:
            raise RuntimeError("disk full")
        return original(self, *args, **kwargs)

    monkeypatch.setattr(h5py.Group, "create_dataset", failing_create_dataset)
    with pytest.raises(RuntimeError, match="disk full"):
        new.save(path)
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["buf.h5"]
    assert CyclicBuffer.load(path).total_pushed == 10
