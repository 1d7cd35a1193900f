"""Fixed-capacity cyclic buffer of frames from N characters stepped in lock-step.

Layout: every field is one preallocated array of shape (rows, N, *shape) with ``rows = capacity // N``.
A row is one time step of the gym, column n is character n. ``push`` writes row ``head`` and advances
``head`` cyclically, so once the ring is full the oldest row is overwritten. The chronological order of
the stored rows is ``(head - size + k) % rows`` for k = 0 .. size - 1 (oldest first).

Frame semantics: row t of character n holds the state observed at step t, the action applied at step t
and the outcome of that step (reward; ``terminated`` / ``truncated`` = the episode ended after this step).
The frame after a done frame belongs to a new episode with a new ``episode_id``. Episode ids are globally
unique and, per character, never decrease, so a run of frames of one character lies in a single episode
exactly when its first and last ``episode_id`` are equal; ``push`` rejects ids that break this.

Three bookkeeping fields are always present: ``episode_id`` (int64), ``terminated`` (bool) and
``truncated`` (bool).
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Mapping
from typing import Any

import h5py
import numpy as np

FORMAT_NAME = "mimictrack.cyclic_buffer"
LAYOUT_VERSION = 1
BOOKKEEPING_FIELDS: dict[str, tuple[tuple[int, ...], np.dtype]] = {
    "episode_id": ((), np.dtype(np.int64)),
    "terminated": ((), np.dtype(np.bool_)),
    "truncated": ((), np.dtype(np.bool_)),
}
_OPTIONAL_FIELDS = ("terminated", "truncated")

FieldSpec = Mapping[str, tuple[tuple[int, ...], np.dtype | str]]


class CyclicBuffer:
    """Preallocated ring of time steps for ``num_envs`` characters.

    Args:
        capacity: Capacity in frames (one frame = one character at one time step); rounded down to a
            multiple of ``num_envs``.
        num_envs: Number of characters N pushed together at every step.
        fields: Field name -> (per-frame shape, dtype), e.g. ``{"reward": ((), "float32")}``.

    Raises:
        ValueError: If ``capacity < num_envs``, ``num_envs < 1`` or a field uses a bookkeeping name.
    """

    def __init__(self, capacity: int, num_envs: int, fields: FieldSpec) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        if capacity < num_envs:
            raise ValueError(f"capacity ({capacity} frames) must be >= num_envs ({num_envs})")
        clash = sorted(set(fields) & set(BOOKKEEPING_FIELDS))
        if clash:
            raise ValueError(f"field names {clash} are reserved for bookkeeping fields")
        self.capacity = int(capacity)
        self.num_envs = int(num_envs)
        self._rows = self.capacity // self.num_envs
        self.user_fields: dict[str, tuple[tuple[int, ...], np.dtype]] = {
            name: (tuple(int(d) for d in shape), np.dtype(dtype)) for name, (shape, dtype) in fields.items()
        }
        self.fields: dict[str, tuple[tuple[int, ...], np.dtype]] = {**self.user_fields, **BOOKKEEPING_FIELDS}
        # np.zeros maps pages lazily, so resident memory grows only as rows are first written.
        self._arrays: dict[str, np.ndarray] = {
            name: np.zeros((self._rows, self.num_envs, *shape), dtype=dtype)
            for name, (shape, dtype) in self.fields.items()
        }
        self._head = 0
        self._size = 0
        self.total_pushed = 0

    @property
    def rows(self) -> int:
        """Number of time steps the ring holds when full (``capacity // num_envs``)."""
        return self._rows

    @property
    def size(self) -> int:
        """Number of stored time steps (``<= rows``)."""
        return self._size

    @property
    def head(self) -> int:
        """Row the next ``push`` writes."""
        return self._head

    @property
    def nbytes(self) -> int:
        """Bytes of all preallocated field arrays."""
        return sum(arr.nbytes for arr in self._arrays.values())

    @property
    def arrays(self) -> Mapping[str, np.ndarray]:
        """Raw storage, field -> array (rows, N, *shape) in physical (not chronological) row order."""
        return self._arrays

    def __len__(self) -> int:
        """Number of stored frames (``size * num_envs``)."""
        return self._size * self.num_envs

    def clear(self) -> None:
        """Forget all stored steps; the arrays stay allocated and ``total_pushed`` is kept."""
        self._head = 0
        self._size = 0

    def _chronological_rows(self, start: np.ndarray | int, count: int) -> np.ndarray:
        """Physical rows of chronological indices ``start .. start + count - 1`` (0 = oldest stored)."""
        return (self._head - self._size + np.asarray(start)[..., None] + np.arange(count)) % self._rows

    def push(self, **batch: np.ndarray) -> None:
        """Write one time step of all N characters.

        Args:
            **batch: One array per field of shape (N, *shape); every user field and ``episode_id`` is
                required, ``terminated`` and ``truncated`` default to False.

        Raises:
            ValueError: On a missing, unknown or wrongly shaped field, or on episode ids that decrease or
                do not change after a done frame (either would let a window span two episodes).
        """
        missing = [name for name in self.fields if name not in batch and name not in _OPTIONAL_FIELDS]
        extra = [name for name in batch if name not in self.fields]
        if missing or extra:
            raise ValueError(f"push: missing fields {missing}, unknown fields {extra}")
        values: dict[str, np.ndarray] = {}
        for name, value in batch.items():
            arr = np.asarray(value)
            expected = (self.num_envs, *self.fields[name][0])
            if arr.shape != expected:
                raise ValueError(f"push: field {name!r} expected shape {expected}, given shape {arr.shape}")
            values[name] = arr
        if self._size > 0:
            prev = (self._head - 1) % self._rows
            prev_id = self._arrays["episode_id"][prev]
            prev_done = self._arrays["terminated"][prev] | self._arrays["truncated"][prev]
            new_id = values["episode_id"]
            bad = (new_id < prev_id) | (prev_done & (new_id == prev_id))
            if bad.any():
                envs = np.flatnonzero(bad)
                raise ValueError(
                    f"push: episode_id of characters {envs.tolist()} decreased or was reused after a done "
                    f"frame (previous {prev_id[envs].tolist()}, given {new_id[envs].tolist()})"
                )
        row = self._head
        for name, arr in self._arrays.items():
            if name in values:
                arr[row] = values[name]
            else:
                arr[row] = False
        self._head = (row + 1) % self._rows
        self._size = min(self._size + 1, self._rows)
        self.total_pushed += 1

    def valid_window_starts(self, length: int) -> np.ndarray:
        """Mask of chronological window starts whose ``length`` frames lie in one episode.

        Args:
            length: Window length in time steps.

        Returns:
            Bool array (max(size - length + 1, 0), N); entry [k, n] is True when the frames of character n
            at chronological indices k .. k + length - 1 share one episode_id.
        """
        if length < 1:
            raise ValueError(f"window length must be >= 1, got {length}")
        num_starts = self._size - length + 1
        if num_starts <= 0:
            return np.zeros((0, self.num_envs), dtype=bool)
        # Ids of one character never decrease, so equal ids at both ends mean one episode throughout.
        ids = np.take(self._arrays["episode_id"], self._chronological_rows(0, self._size), axis=0)
        return ids[:num_starts] == ids[length - 1 :]

    def sample_windows(self, batch: int, length: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """Sample windows of consecutive steps of one character, uniformly over all valid starts.

        Args:
            batch: Number of windows B.
            length: Window length L in time steps.
            rng: Source of randomness.

        Returns:
            Field -> array (B, L, *shape) for every field including the bookkeeping ones, plus
            ``env_index`` (B,) the character and ``row_index`` (B,) the physical row of each window start.

        Raises:
            ValueError: If ``length`` exceeds ``rows`` or no valid window exists.
        """
        if batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch}")
        if length > self._rows:
            raise ValueError(f"window length {length} exceeds the buffer's {self._rows} rows")
        valid = np.flatnonzero(self.valid_window_starts(length))
        if valid.size == 0:
            raise ValueError(
                f"no valid window of length {length}: {self._size} time steps x {self.num_envs} characters "
                f"= {len(self)} frames stored, 0 valid window starts, {batch} windows asked"
            )
        flat = valid[rng.integers(0, valid.size, size=batch)]
        start, env = np.divmod(flat, self.num_envs)
        rows = self._chronological_rows(start, length)
        frames = rows * self.num_envs + env[:, None]
        # np.take on a (rows * N, frame size) view is several times faster than 2-index fancy indexing.
        out = {
            name: np.take(arr.reshape(self._rows * self.num_envs, -1), frames, axis=0).reshape(
                batch, length, *self.fields[name][0]
            )
            for name, arr in self._arrays.items()
        }
        out["env_index"] = env
        out["row_index"] = rows[:, 0]
        return out

    def latest(self, steps: int) -> dict[str, np.ndarray]:
        """Newest ``steps`` time steps of all characters, oldest first.

        Args:
            steps: Number of time steps T.

        Returns:
            Field -> array (T, N, *shape) for every field including the bookkeeping ones.

        Raises:
            ValueError: If fewer than ``steps`` time steps are stored.
        """
        if steps < 0 or steps > self._size:
            raise ValueError(f"latest: asked for {steps} time steps, {self._size} stored")
        rows = self._chronological_rows(self._size - steps, steps)
        return {name: np.take(arr, rows, axis=0) for name, arr in self._arrays.items()}

    def state_dict(self) -> dict[str, Any]:
        """The stored steps for a checkpoint: ``total_pushed`` and ``rows`` (every field, oldest first)."""
        return {"total_pushed": self.total_pushed, "rows": self.latest(self._size)}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Replace the stored steps with :meth:`state_dict` output; windows are then sampled exactly as before.

        Raises:
            ValueError: If a field is missing or unknown, the fields disagree on the number of steps, a field has
                the wrong per-step shape, or there are more steps than ``rows``. The buffer is unchanged then.
        """
        rows = state["rows"]
        missing, extra = sorted(set(self.fields) - set(rows)), sorted(set(rows) - set(self.fields))
        if missing or extra:
            raise ValueError(f"load_state_dict: missing fields {missing}, unknown fields {extra}")
        steps = {name: len(rows[name]) for name in self.fields}
        count = steps["episode_id"]
        if any(n != count for n in steps.values()):
            raise ValueError(f"load_state_dict: fields hold different numbers of steps {steps}")
        if count > self._rows:
            raise ValueError(f"load_state_dict: {count} steps do not fit in {self._rows} rows")
        for name, (shape, _) in self.fields.items():
            expected = (count, self.num_envs, *shape)
            if np.shape(rows[name]) != expected:
                raise ValueError(
                    f"load_state_dict: field {name!r} expected shape {expected}, given {np.shape(rows[name])}"
                )
        for name, arr in self._arrays.items():
            arr[:count] = rows[name]
        self._head = count % self._rows
        self._size = count
        self.total_pushed = int(state["total_pushed"])

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the stored steps in chronological order to HDF5, atomically.

        The file is written under a temporary name in the same directory and moved over ``path`` with
        ``os.replace``, so a failure leaves any existing file at ``path`` untouched.

        Args:
            path: Destination file.
        """
        path = os.fspath(path)
        directory, base = os.path.split(os.path.abspath(path))
        tmp = os.path.join(directory, f".{base}.{uuid.uuid4().hex}.tmp")
        start = (self._head - self._size) % self._rows
        # Chronological rows are [start, rows) then [0, head) once wrapped; slices avoid a full copy.
        first = min(self._size, self._rows - start)
        try:
            with h5py.File(tmp, "w") as f:
                f.attrs["format"] = FORMAT_NAME
                f.attrs["version"] = LAYOUT_VERSION
                f.attrs["capacity"] = self.capacity
                f.attrs["num_envs"] = self.num_envs
                f.attrs["total_pushed"] = self.total_pushed
                f.attrs["user_fields"] = list(self.user_fields)
                for name, (shape, dtype) in self.fields.items():
                    arr = self._arrays[name]
                    dset = f.create_dataset(name, shape=(self._size, self.num_envs, *shape), dtype=dtype)
                    dset.attrs["shape"] = np.asarray(shape, dtype=np.int64)
                    dset.attrs["dtype"] = dtype.str
                    if first > 0:
                        dset[:first] = arr[start : start + first]
                    if self._size > first:
                        dset[first:] = arr[: self._size - first]
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.remove(tmp)
            raise

    @classmethod
    def load(
        cls, path: str | os.PathLike[str], fields: FieldSpec | None = None, capacity: int | None = None
    ) -> CyclicBuffer:
        """Rebuild a buffer written by ``save``; ``head`` follows the last stored row.

        Args:
            path: HDF5 file written by ``save``.
            fields: Expected user fields; if given, the file's layout must match exactly.
            capacity: Capacity in frames of the new buffer (default: the saved one). If it holds fewer rows
                than stored, only the newest rows are kept.

        Returns:
            The rebuilt buffer.

        Raises:
            ValueError: If the file is not a readable buffer file of this format and version, or its layout
                does not match ``fields``.
        """
        path = os.fspath(path)
        try:
            with h5py.File(path, "r") as f:
                return cls._from_file(f, path, fields, capacity)
        except (OSError, KeyError) as exc:
            raise ValueError(f"{path}: cannot read buffer file ({type(exc).__name__}: {exc})") from exc

    @classmethod
    def _from_file(cls, f: h5py.File, path: str, fields: FieldSpec | None, capacity: int | None) -> CyclicBuffer:
        """Validate an open file's layout and copy its rows into a new buffer."""
        fmt = f.attrs.get("format")
        version = f.attrs.get("version")
        # h5py hands back numpy scalars; .item() keeps the messages readable.
        fmt, version = (v.item() if isinstance(v, np.generic) else v for v in (fmt, version))
        if fmt != FORMAT_NAME:
            raise ValueError(f"{path}: format {fmt!r} is not {FORMAT_NAME!r}")
        if version != LAYOUT_VERSION:
            raise ValueError(f"{path}: layout version {version!r} is not supported (expected {LAYOUT_VERSION})")
        names = [str(n) for n in f.attrs["user_fields"]]
        stored: dict[str, tuple[tuple[int, ...], np.dtype]] = {
            name: (tuple(int(d) for d in f[name].attrs["shape"]), np.dtype(f[name].attrs["dtype"])) for name in names
        }
        if fields is not None:
            expected = {name: (tuple(int(d) for d in s), np.dtype(d)) for name, (s, d) in fields.items()}
            missing = sorted(expected.keys() - stored.keys())
            extra = sorted(stored.keys() - expected.keys())
            if missing or extra:
                raise ValueError(f"{path}: fields {missing} are missing from the file, file has extra fields {extra}")
            for name, (shape, dtype) in expected.items():
                if stored[name] != (shape, dtype):
                    raise ValueError(
                        f"{path}: field {name!r} expected shape {shape} dtype {dtype}, "
                        f"file has shape {stored[name][0]} dtype {stored[name][1]}"
                    )
            stored = {name: stored[name] for name in expected}
        num_envs = int(f.attrs["num_envs"])
        buf = cls(int(f.attrs["capacity"]) if capacity is None else capacity, num_envs, stored)
        size = f["episode_id"].shape[0]
        for name, (shape, _) in buf.fields.items():
            if f[name].shape != (size, num_envs, *shape):
                raise ValueError(
                    f"{path}: dataset {name!r} has shape {f[name].shape}, expected {(size, num_envs, *shape)}"
                )
        keep = min(size, buf.rows)
        if keep > 0:
            for name, arr in buf._arrays.items():
                f[name].read_direct(arr, np.s_[size - keep : size], np.s_[:keep])
        buf._size = keep
        buf._head = keep % buf.rows
        buf.total_pushed = int(f.attrs["total_pushed"])
        return buf
