"""Checkpoint files that are safe to open and whose damage is found: what :class:`common.run.directory.RunDir` writes.

A checkpoint holds only tensors, numpy arrays and plain Python values (dicts, lists, tuples, str, int, float,
bool, None); RNG states are already of that kind (a numpy Generator's ``bit_generator.state`` is a dict of ints,
python's ``random.getstate()`` a tuple of ints, torch's a byte tensor). :func:`save_checkpoint_file` refuses
anything else before writing, and :func:`load_checkpoint_file` reads with ``torch.load(weights_only=True)`` plus an
allow-list of the numpy functions that rebuild arrays of numbers: a file whose pickle asks for any other object
(the way a pickle runs code) is refused naming the file, and nothing of it runs. Opening a run directory someone
sent is therefore safe.

Next to the numbered checkpoints, ``latest.json`` names the newest one and records the size and SHA-256 of every
kept one. It is a separate file written atomically after the checkpoint it names, so damage to a checkpoint cannot
also damage the pointer (the hard link ``latest.pt`` that earlier versions kept was the same bytes on disk), and the
recorded digests reveal damage that would still unpickle (flipped bits inside a tensor).
"""

from __future__ import annotations

import errno
import hashlib
import io
import json
import pickle
import re
import sys
import warnings
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import torch

try:
    from numpy._core import multiarray as _np_multiarray
except ImportError:  # numpy < 2
    from numpy.core import multiarray as _np_multiarray

from common.config import atomic_output
from common.strict_json import parse_json

POINTER_NAME = "latest.json"
LEGACY_LATEST_NAME = "latest.pt"
DAMAGED_SUFFIX = ".damaged"
_PLAIN = (str, int, float, bool, bytes, type(None))
_TORCH_LEAVES = (torch.Tensor, torch.dtype, torch.device, torch.Size)
# Arrays of numbers and booleans only: an object array's items would be further pickles.
_NUMBER_KINDS = "biufc"
_NUMBER_DTYPES = sorted({type(np.dtype(c)) for c in np.typecodes["All"] if np.dtype(c).kind in _NUMBER_KINDS},
                        key=lambda t: t.__name__)  # fmt: skip
# What numpy's pickles of such arrays and scalars call: ndarray.__new__ on ndarray itself, dtype from a type code,
# a scalar from raw bytes. Under numpy 1.x the module was numpy.core, hence the second names.
_NUMPY_GLOBALS: list[Any] = [
    _np_multiarray._reconstruct, _np_multiarray.scalar, np.ndarray, np.dtype, *_NUMBER_DTYPES,
    (_np_multiarray._reconstruct, "numpy.core.multiarray._reconstruct"),
    (_np_multiarray.scalar, "numpy.core.multiarray.scalar"),
]  # fmt: skip
_REFUSED_RE = re.compile(r"(Unsupported global: GLOBAL [\w.]+|unsupported GLOBAL [\w.]+|got <class '[\w.]+'>"
                         r"|Unsupported operand \d+)")  # fmt: skip


class CheckpointError(ValueError):
    """A checkpoint that cannot be read, or may not be: the message names the file and the problem."""


def check_plain(value: Any, where: str = "state") -> None:
    """Raise TypeError naming the first entry of ``value`` that is not a tensor, number array or plain value."""
    if isinstance(value, Mapping):
        for k, v in value.items():
            if not isinstance(k, (str, int)):
                raise TypeError(f"{where}: key {k!r} is a {type(k).__name__}; checkpoint keys are str or int")
            check_plain(v, f"{where}.{k}")
    elif isinstance(value, (list, tuple)) and not isinstance(value, torch.Size):
        if type(value) not in (list, tuple):
            raise TypeError(f"{where} is a {type(value).__name__}; a checkpoint holds plain lists and tuples")
        for i, v in enumerate(value):
            check_plain(v, f"{where}[{i}]")
    elif isinstance(value, (np.ndarray, np.generic)):
        if value.dtype.kind not in _NUMBER_KINDS or value.dtype.hasobject:
            what = f"{value.dtype} values" + (" holding object references" if value.dtype.hasobject else "")
            raise TypeError(f"{where}: numpy {what}; a checkpoint holds arrays of numbers or booleans")
    elif not isinstance(value, _PLAIN + _TORCH_LEAVES):
        raise TypeError(f"{where} is a {type(value).__module__}.{type(value).__name__}; a checkpoint holds only "
                        "tensors, numpy arrays and plain Python values")  # fmt: skip


def file_digest(path: Path) -> str:
    """SHA-256 of a file, hex."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def save_checkpoint_file(state: Mapping[str, Any], path: Path) -> dict[str, Any]:
    """Write ``state`` to ``path`` atomically; returns its pointer record (iteration, bytes, sha256).

    If the write fails part-way (a full disk at any byte), ``path`` keeps its previous content and the partial file is
    removed.

    Raises:
        TypeError: Naming the entry if ``state`` holds anything but tensors, number arrays and plain values.
        OSError: Naming ``path`` if it cannot be written (torch's own failure of a write is raised as the ``OSError``
            behind it, e.g. ENOSPC, or as EIO).
    """
    check_plain(state)
    with atomic_output(path) as tmp:
        _torch_save(dict(state), tmp)
        record = {"iteration": state.get("iteration"), "bytes": tmp.stat().st_size, "sha256": file_digest(tmp)}
    return record


# What torch raises when a write of its zip writer failed (the disk filled): it does not pass the OSError on.
_TORCH_WRITE_FAILED = re.compile(r"inline_container|PytorchStreamWriter|unexpected pos|write failed|iostream error")


class _KeepsWriteErrors(io.RawIOBase):
    """A binary file for ``torch.save`` that keeps the first ``OSError`` of a write, which torch would drop."""

    def __init__(self, file: BinaryIO) -> None:
        super().__init__()
        self.file = file
        self.error: OSError | None = None

    def writable(self) -> bool:
        return True

    def write(self, data: Any) -> int:
        try:
            return self.file.write(data)
        except OSError as e:
            self.error = self.error or e
            raise

    def flush(self) -> None:
        self.file.flush()


def _torch_save(state: dict[str, Any], path: Path) -> None:
    """``torch.save(state, path)``, with a failed write raised as the ``OSError`` behind it.

    torch reports a write that failed (a full disk) as ``RuntimeError: [enforce fail at inline_container.cc:...]
    unexpected pos`` or ``basic_ios::clear: iostream error``, its errno lost. Then the save is tried once more
    through a file object that keeps the write's ``OSError`` (ENOSPC): the failure is reported as what it is, and a
    passing hiccup is written after all.

    Raises:
        OSError: Naming ``path``: the write's own error, else EIO with torch's message.
    """
    try:
        torch.save(state, path)
        return
    except RuntimeError as e:
        first = e
    with path.open("wb") as f:
        out = _KeepsWriteErrors(f)
        try:
            torch.save(state, out)
        except RuntimeError:
            if out.error is not None and out.error.errno is not None:
                raise OSError(out.error.errno, out.error.strerror, str(path)) from first
            if not _TORCH_WRITE_FAILED.search(str(first)):
                raise first from None  # not a write that failed: a bug, with its traceback
            detail = str(first).splitlines()[0].strip()
            raise OSError(errno.EIO, f"the write failed part-way (torch: {detail})", str(path)) from first


def load_checkpoint_file(path: str | Path, map_location: str | torch.device | None = "cpu",
                         sha256: str | None = None) -> dict[str, Any]:  # fmt: skip
    """Read a checkpoint without running anything it holds.

    Args:
        path: The checkpoint file.
        map_location: Passed to ``torch.load``.
        sha256: The digest recorded when it was written, if known; a file that differs is refused as damaged.

    Returns:
        The saved mapping.

    Raises:
        CheckpointError: ``"<path>: <problem>"`` for a missing, truncated, damaged or foreign file, and for one whose
            pickle asks for objects other than tensors, number arrays and plain values (refused unopened).
    """
    path = Path(path)
    try:
        with torch.serialization.safe_globals(_NUMPY_GLOBALS), warnings.catch_warnings():
            # torch warns about the pickle protocol of files it did not write; the refusal below says enough.
            warnings.simplefilter("ignore", UserWarning)
            state = torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as e:
        found = _REFUSED_RE.search(str(e))
        if "Weights only load failed" in str(e) and found and found.group(1).startswith("Unsupported operand"):
            raise CheckpointError(f"{path}: refused, not opened: not a checkpoint as torch.save writes them "
                                  f"({found.group(1).lower()} of a pickle)") from None
        if "Weights only load failed" in str(e) and found:
            raise CheckpointError(f"{path}: refused, not opened: it asks for objects other than tensors, arrays and "
                                  f"plain values ({found.group(1)}); a checkpoint of this project never does") from None
        raise CheckpointError(f"{path}: damaged or not a checkpoint (the pickle inside is broken)") from None
    except FileNotFoundError:
        raise CheckpointError(f"{path}: no such checkpoint file") from None
    except IsADirectoryError:
        raise CheckpointError(f"{path}: a directory, not a checkpoint file") from None
    except Exception as e:  # noqa: BLE001 - see below
        # torch reports a cut-short zip as RuntimeError or OSError(EINVAL), an empty file as EOFError, and changed
        # bytes as KeyError, UnicodeDecodeError, ValueError, IndexError or AssertionError (found by changing bytes of
        # a real checkpoint): all mean the same to a user, a file that does not read.
        first = str(e).split(". ")[0].strip()
        detail = first if isinstance(e, (RuntimeError, OSError)) and first else f"{type(e).__name__} {first}".strip()
        raise CheckpointError(f"{path}: truncated or damaged ({detail})") from None
    if not isinstance(state, dict):
        raise CheckpointError(f"{path}: holds a {type(state).__name__}, not a checkpoint's dict")
    try:
        check_plain(state)
        problem = None
    except TypeError as e:
        problem = str(e)
    if problem is not None:
        # Changed bytes of a dtype's pickled flags can make numbers look like object pointers (seen once in 300
        # changed bytes): numpy then prints a traceback when it frees the array, which is kept quiet here.
        previous_hook, sys.unraisablehook = sys.unraisablehook, lambda unraisable: None
        try:
            del state
        finally:
            sys.unraisablehook = previous_hook
        raise CheckpointError(f"{path}: damaged ({problem})")
    # After the load, so that a cut-short file gets torch's more telling message; loading ran nothing.
    if sha256 is not None and file_digest(path) != sha256:
        raise CheckpointError(f"{path}: damaged: its SHA-256 differs from the one recorded in {POINTER_NAME} "
                              "when it was written")  # fmt: skip
    return state


def read_pointer(checkpoint_dir: Path) -> dict[str, Any]:
    """``latest.json`` of ``checkpoint_dir``: ``{"latest": name, "checkpoints": {name: record}}``; {} if absent.

    Raises:
        CheckpointError: If it exists but is not such a JSON object (the checkpoints themselves are unaffected).
    """
    path = checkpoint_dir / POINTER_NAME
    try:
        pointer = parse_json(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return {}
    except (OSError, ValueError) as e:
        raise CheckpointError(f"{path}: unreadable ({e})") from None
    if not isinstance(pointer, dict) or not isinstance(pointer.get("checkpoints", {}), dict):
        raise CheckpointError(f"{path}: not a checkpoint pointer (expected an object with 'latest', 'checkpoints')")
    return pointer


def recorded_digest(path: Path) -> str | None:
    """The SHA-256 that ``latest.json`` next to ``path`` recorded for it when it was written; None if none."""
    try:
        record = read_pointer(path.parent).get("checkpoints", {}).get(path.name)
    except CheckpointError:
        return None
    digest = record.get("sha256") if isinstance(record, Mapping) else None
    return digest if isinstance(digest, str) else None


def write_pointer(checkpoint_dir: Path, latest: str, records: Mapping[str, Mapping[str, Any]]) -> None:
    """Atomically write ``latest.json`` naming ``latest`` and the records of the kept checkpoints."""
    doc = {"latest": latest, "checkpoints": {k: dict(v) for k, v in sorted(records.items())}}
    with atomic_output(checkpoint_dir / POINTER_NAME) as tmp:
        tmp.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")


def set_aside(path: Path) -> Path:
    """Rename a checkpoint that did not read to ``<name>.damaged``: kept for a look, never read or pruned again."""
    target = path.with_name(path.name + DAMAGED_SUFFIX)
    path.replace(target)
    return target


def candidates(checkpoint_dir: Path, numbered: list[tuple[int, Path]]) -> Iterator[Path]:
    """Checkpoints to try, newest first: the numbered ones, then a legacy ``latest.pt`` (runs of earlier versions)."""
    yield from (p for _, p in reversed(numbered))
    legacy = checkpoint_dir / LEGACY_LATEST_NAME
    if legacy.is_file():
        yield legacy


def load_newest_intact(checkpoint_dir: Path, numbered: list[tuple[int, Path]], warn: Callable[[str], None],
                       map_location: str | torch.device | None = "cpu",
                       required: tuple[str, ...] = ()) -> tuple[Path, dict[str, Any], list[Path]]:  # fmt: skip
    """The newest checkpoint of ``checkpoint_dir`` that reads, saying of each newer one why it was passed over.

    Args:
        checkpoint_dir: The run's ``checkpoints/``.
        numbered: Its numbered checkpoints, oldest first.
        warn: Called with one line per checkpoint passed over (file and problem) once an intact one is found, and
            for an unreadable pointer.
        map_location: Passed to ``torch.load``.
        required: Entries a checkpoint must have to count as intact.

    Returns:
        ``(path, state, passed_over)``: the newer checkpoints that did not read, newest first.

    Raises:
        CheckpointError: If there is no checkpoint, or none reads (every problem listed).
    """
    try:
        read_pointer(checkpoint_dir)
    except CheckpointError as e:
        warn(f"{e}; checking the checkpoints without it")
    problems, passed_over = [], []
    for path in candidates(checkpoint_dir, numbered):
        try:
            state = load_checkpoint_file(path, map_location, sha256=recorded_digest(path))
            missing = [k for k in required if k not in state]
            if missing:
                raise CheckpointError(f"{path}: not a training checkpoint (no {', '.join(missing)})")
        except CheckpointError as e:
            problems.append(str(e))
            passed_over.append(path)
            continue
        for problem in problems:  # only now: if none reads, the one error below says it all
            warn(problem)
        return path, state, passed_over
    if not problems:
        raise CheckpointError(f"{checkpoint_dir}: no checkpoint")
    raise CheckpointError(f"{checkpoint_dir}: no intact checkpoint ({'; '.join(problems)})")
