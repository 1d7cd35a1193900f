"""Checked reading of the project's HDF5 motion files (clip packs and motion datasets).

An attribute is read with its type checked (a string or ``true`` where a number belongs is refused, not converted),
and an array's shape and type are checked before it is read, so that a file declaring a billion frames is refused
before anything is allocated. Every problem is a :class:`~common.motion.errors.MotionFormatError` naming ``where``
(the file, and the clip inside it).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import h5py
import numpy as np

from common.motion.errors import MotionFormatError

_KINDS: dict[str, tuple[str, Callable[[Any], bool]]] = {
    "str": ("a string", lambda v: isinstance(v, str)),
    "bool": ("true or false", lambda v: isinstance(v, bool | np.bool_)),
    "int": ("an integer", lambda v: isinstance(v, int | np.integer) and not isinstance(v, bool | np.bool_)),
    "number": ("a finite number", lambda v: isinstance(v, int | float | np.integer | np.floating)
               and not isinstance(v, bool | np.bool_) and bool(np.isfinite(v))),
}  # fmt: skip


def describe(value: Any) -> str:
    """An attribute value for messages: ``'60' (a string)``, ``True (a boolean)``, ``an array of shape (2,)``."""
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape}"
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool | np.bool_):
        return f"{bool(value)} (a boolean)"
    if isinstance(value, bytes | str):
        text = value.decode("utf-8", "replace") if isinstance(value, bytes) else value
        return f"{text[:20]!r} (a string)"
    return repr(value)[:40]


def attr(obj: h5py.HLObject, name: str, kind: str, where: str) -> Any:
    """The attribute ``name`` of ``obj``, which must be of ``kind`` (``str``, ``bool``, ``int`` or ``number``).

    Returns:
        A Python ``str``, ``bool``, ``int`` or ``float``.

    Raises:
        MotionFormatError: the attribute is missing, unreadable or of another type.
    """
    if name not in obj.attrs:
        raise MotionFormatError(f"{where}: no '{name}' attribute")
    try:
        value = obj.attrs[name]
    except (OSError, TypeError, ValueError) as e:
        raise MotionFormatError(f"{where}: attribute '{name}' cannot be read ({e})") from None
    if isinstance(value, bytes) and kind == "str":
        value = value.decode("utf-8", "replace")
    wanted, ok = _KINDS[kind]
    if not ok(value):
        raise MotionFormatError(f"{where}: attribute '{name}' must be {wanted}, got {describe(value)}")
    return {"str": str, "bool": bool, "int": int, "number": float}[kind](value)


def check_header(f: h5py.File, where: str, fmt: str, what: str, versions: tuple[int, ...], hint: str = "") -> int:
    """The file's ``format`` and ``version`` attributes, checked: ``format`` must be ``fmt`` and ``version`` one of
    ``versions`` (``what`` names the kind of file in messages: "clip pack"; ``hint`` ends the version message).

    Returns:
        The file's version.

    Raises:
        MotionFormatError: another format (or none), or a version this code does not read.
    """
    found = attr(f, "format", "str", where) if "format" in f.attrs else None
    if found != fmt:
        raise MotionFormatError(f"{where}: not a {what} (format {found!r})")
    version = attr(f, "version", "int", where)
    if version not in versions:
        raise MotionFormatError(f"{where}: {what} version {version}, this code reads "
                                f"{' and '.join(map(str, versions))}{hint}")  # fmt: skip
    return version


def array(group: h5py.Group, name: str, where: str, shape: tuple[int | None, ...], max_rows: int) -> np.ndarray:
    """The float64 values of dataset ``name`` in ``group``, checked before reading.

    Args:
        group: The file or a group in it.
        name: The dataset's key.
        where: The file (and clip) for messages.
        shape: The shape wanted; None where any size goes (the frames).
        max_rows: The most rows (first axis) it may have.

    Raises:
        MotionFormatError: the dataset is missing, not an array of numbers (strings, booleans), of another shape,
            longer than ``max_rows``, or unreadable.
    """
    item = group.get(name)
    if not isinstance(item, h5py.Dataset):
        raise MotionFormatError(f"{where}: no '{name}' array" + ("" if item is None else " (a group is there)"))
    if item.dtype.kind not in "fiu":
        raise MotionFormatError(f"{where}: '{name}' holds {item.dtype} values, not numbers")
    if len(item.shape) != len(shape) or any(s is not None and s != n for s, n in zip(shape, item.shape, strict=True)):
        wanted = "(" + ", ".join("frames" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "")
        raise MotionFormatError(f"{where}: '{name}' has shape {item.shape}, expected {wanted})")
    if item.shape and item.shape[0] > max_rows:
        raise MotionFormatError(f"{where}: '{name}' has {item.shape[0]:,} rows, more than {max_rows:,}")
    try:
        return np.asarray(item[()], dtype=np.float64)
    except (OSError, ValueError) as e:
        raise MotionFormatError(f"{where}: '{name}' cannot be read ({e})") from None
