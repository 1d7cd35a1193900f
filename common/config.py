"""YAML configs loaded into frozen, possibly nested dataclasses with strict key and type checking.

A config class is a dataclass whose fields are scalars (``int``, ``float``, ``bool``, ``str``, ``Path``),
``Literal[...]``, ``X | None``, ``tuple[X, ...]`` / ``tuple[X, Y]`` / ``list[X]`` (YAML lists),
``dict[str, X]`` or another dataclass (a nested YAML mapping, i.e. a section). Typos must never pass
silently, so unknown keys, wrong types and values outside a ``Literal`` raise :class:`ConfigError` with
the file name and the dotted key path, e.g. ``configs/x.yaml: unknown key 'train.lrr' (allowed: ...)``.

YAML is read with a safe loader that also resolves YAML 1.2 floats such as ``1e-3``: plain PyYAML follows
YAML 1.1 and returns the *string* ``'1e-3'``, which would make ``train.lr=1e-3`` a type error.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import io
import os
import re
import tempfile
import types
from collections.abc import Hashable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin, get_type_hints

import h5py
import yaml

T = TypeVar("T")

_MISSING = object()


class ConfigError(ValueError):
    """A config file, mapping or override does not match its dataclass."""


class _Loader(yaml.SafeLoader):
    """Safe loader that also resolves YAML 1.2 floats without a dot (``1e-3``, ``5E+4``) and refuses a key given twice
    in one mapping (PyYAML keeps the last value without a word, so ``{num_envs: 8, num_envs: 16}`` would train 16)."""

    def construct_mapping(self, node: yaml.Node, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, yaml.MappingNode):
            first: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":  # ``<<: *base``, whose keys this mapping may override
                    continue
                key = self.construct_object(key_node, deep=True)
                if not isinstance(key, Hashable):
                    continue  # refused by the base class, naming it
                if key in first:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"duplicate key {key!r} (first at line {first[key].line + 1})", key_node.start_mark)
                first[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


class YAMLTextError(yaml.YAMLError, ValueError):
    """YAML text that does not parse, or asks for a tag the safe loader refuses (``!!python/object``); a
    ``ValueError`` too, so that a reader catching bad values catches it. ``str()`` is one line (:func:`yaml_problem`).
    """

    def __init__(self, problem: str, problem_mark: Any = None) -> None:
        self.problem, self.problem_mark = problem, problem_mark
        super().__init__(yaml_problem(self))


def parse_yaml(text: str) -> Any:
    """Parse YAML text with the safe loader used for config files and overrides.

    Args:
        text: YAML document.

    Returns:
        The parsed Python object (dicts, lists, scalars).

    Raises:
        YAMLTextError: If the text is not YAML the safe loader reads (one line: the problem and where).
    """
    try:
        return yaml.load(text, Loader=_Loader)  # noqa: S506 -- _Loader derives from SafeLoader
    except YAMLTextError:
        raise
    except yaml.YAMLError as e:
        problem = getattr(e, "problem", None) or (str(e).splitlines() or [type(e).__name__])[0]
        raise YAMLTextError(problem, getattr(e, "problem_mark", None)) from None
    except RecursionError:
        raise YAMLTextError("nested too deeply to read") from None
    except ValueError as e:  # Python's limit on integer digits (a number of thousands of digits)
        raise YAMLTextError(f"a value it cannot read: {str(e).split(';')[0]}") from None


def yaml_problem(e: yaml.YAMLError) -> str:
    """PyYAML's error on one line: the problem and where (its own message spans several, with a source excerpt)."""
    mark = getattr(e, "problem_mark", None)
    problem = getattr(e, "problem", None) or (str(e).splitlines() or [type(e).__name__])[0]
    return f"{problem} at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else problem


_UMASK = os.umask(0o022)  # read once, at import (os.umask sets as it reads)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path`` that replaces ``path`` only if the block succeeds.

    The temporary file lives in the same folder so that ``os.replace`` is an atomic rename; on any
    exception (a full disk at any byte) it is removed and ``path`` keeps its previous content. The file gets the
    mode a plain ``open`` would give it (``path``'s own if it exists, else 0o666 less the umask), not the temporary
    file's 0o600.

    Args:
        path: Final destination.

    Yields:
        Temporary path to write to.

    Raises:
        OSError: Naming ``path`` (not the temporary file) when the folder, the temporary file or the rename fails
            with an ``OSError`` about them (no space left, permission denied, a directory in the way).
    """
    path = Path(path)
    tmp: Path | None = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        os.close(fd)
        tmp = Path(tmp_name)
        yield tmp
        if tmp.exists():
            tmp.chmod(path.stat().st_mode & 0o7777 if path.exists() else 0o666 & ~_UMASK)
        os.replace(tmp, path)
    except OSError as e:
        about = {str(p) for p in path.parents} | ({str(tmp)} if tmp is not None else set())
        if e.errno is None or (e.filename is not None and str(e.filename) not in about):
            raise
        raise OSError(e.errno, e.strerror, str(path)) from e
    finally:
        if tmp is not None:
            tmp.unlink(missing_ok=True)


@contextlib.contextmanager
def hdf5_output(path: str | Path) -> Iterator[h5py.File]:
    """An HDF5 file built in memory, written to ``path`` in one plain write through :func:`atomic_output` once the
    block succeeds. h5py writing straight to a file that fills up fails while freeing its objects and has been seen
    to segfault; this way a full disk at any byte raises ``OSError`` naming ``path``, which keeps its previous
    content, and leaves no temporary file. The file must fit in memory (clips, datasets, SAMCON plans do)."""
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as f:
        yield f
    with atomic_output(path) as tmp:
        tmp.write_bytes(buffer.getbuffer())


def load_config(cls: type[T], path: str | Path, overrides: Sequence[str] = (), within: str | Path | None = None) -> T:
    """Read a YAML config file, apply command-line overrides and build the dataclass.

    A file's keys start from the dataclass defaults, or, with a top-level ``base: other.yaml`` (a path relative to
    the file), from that file's resolved mapping: sections merge key by key, anything else this file names replaces
    the base's value. So an experiment's config can hold only what it changes.

    Args:
        cls: Dataclass type of the config.
        path: YAML file holding a mapping (an empty file means all defaults).
        overrides: ``"section.key=value"`` strings; ``value`` is parsed as YAML (``train.lr=1e-3`` is a float).
        within: The folder every ``base`` file must lie in (a run directory's ``config.yaml`` names nothing outside
            its run); None: anywhere.

    Returns:
        The config instance.

    Raises:
        ConfigError: On unreadable YAML, a malformed or unknown override, unknown keys, missing required
            keys, wrong types, a failing ``__post_init__`` or a ``base`` outside ``within``.
    """
    data = _read_mapping(cls, Path(path), (), None if within is None else Path(within).resolve())
    data = apply_overrides(cls, data, overrides)
    return from_dict(cls, data, source=str(path))


BASE_KEY = "base"


def _read_mapping(cls: type, path: Path, chain: tuple[Path, ...], within: Path | None) -> dict[str, Any]:
    """The top-level mapping of a config file with its ``base`` chain merged in (the base first)."""
    source = str(path)
    if path.exists() and not path.is_file():  # a FIFO or a device would block or never end
        raise ConfigError(f"{source}: not a regular file; a config is a YAML file")
    try:
        data = parse_yaml(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as e:
        raise ConfigError(f"{source}: not a text file (byte 0x{e.object[e.start]:02x} at offset {e.start} is not "
                          "UTF-8); a config is YAML text") from None  # fmt: skip
    except yaml.YAMLError as e:
        raise ConfigError(f"{source}: invalid YAML: {yaml_problem(e)}") from None
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: top level must be a mapping, got {type(data).__name__}")
    data = dict(data)
    if BASE_KEY not in data or BASE_KEY in {f.name for f in dataclasses.fields(cls)}:
        return data
    base = data.pop(BASE_KEY)
    if not isinstance(base, str) or not base:
        raise ConfigError(f"{source}: '{BASE_KEY}' must be the path of another config file, got {base!r}")
    base_path = (path.parent / base).resolve()
    if within is not None and within not in base_path.parents:
        raise ConfigError(f"{source}: '{BASE_KEY}: {base}' lies outside {within} (it resolves to {base_path}); a run "
                          "directory's config names no file outside its run")  # fmt: skip
    if base_path in chain or base_path == path.resolve():
        raise ConfigError(f"{source}: '{BASE_KEY}: {base}' makes a cycle of base files")
    if not base_path.is_file():
        raise ConfigError(f"{source}: '{BASE_KEY}: {base}': no such file {base_path}")
    return _merge(_read_mapping(cls, base_path, (*chain, path.resolve()), within), data)


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``over``'s keys: mappings on both sides merge recursively, other values replace."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def apply_overrides(cls: type, data: Mapping[str, Any], overrides: Sequence[str]) -> dict[str, Any]:
    """Return a copy of ``data`` with ``"a.b=value"`` overrides applied, checking keys against ``cls``.

    Keys are checked here rather than left to :func:`from_dict` so that the error names the override
    instead of blaming the file for a key it does not contain.

    Args:
        cls: Dataclass type the data is meant for.
        data: Raw mapping, e.g. parsed YAML.
        overrides: ``"dotted.key=value"`` strings, applied in order.

    Returns:
        The updated mapping (nested dicts are copied, ``data`` is not modified).

    Raises:
        ConfigError: If an override lacks ``=``, has an empty key or names a key ``cls`` does not have.
    """
    result = _copy_mappings(data)
    for override in overrides:
        key, sep, raw = override.partition("=")
        key = key.strip()
        parts = key.split(".")
        if not sep or not all(parts):
            raise ConfigError(f"override {override!r}: expected 'section.key=value'")
        try:
            value = parse_yaml(raw) if raw.strip() else ""
        except yaml.YAMLError as e:
            raise ConfigError(f"override {override!r}: invalid YAML value: {yaml_problem(e)}") from None
        section_cls: type | None = cls
        node = result
        for depth, part in enumerate(parts):
            dotted = ".".join(parts[: depth + 1])
            if section_cls is None:
                raise ConfigError(f"override {override!r}: '{'.'.join(parts[:depth])}' is not a section")
            names = _init_field_names(section_cls)
            if part not in names:
                raise ConfigError(
                    f"override {override!r}: unknown key '{dotted}' (allowed: {', '.join(sorted(names))})"
                )
            if depth == len(parts) - 1:
                node[part] = value
                break
            section_cls = _dataclass_of(_type_hints(section_cls)[part])
            child = node.get(part)
            if not isinstance(child, dict):
                # A section absent or null in the file starts empty so the override can fill it.
                child = {}
                node[part] = child
            node = child
    return result


def from_dict(cls: type[T], data: Mapping[str, Any], source: str = "<dict>") -> T:
    """Build a (possibly nested) config dataclass from a mapping, checking keys and types.

    Args:
        cls: Dataclass type.
        data: Mapping of field name to value; nested dataclass fields take nested mappings.
        source: Name of where ``data`` came from (a file name), used as prefix of every error message.

    Returns:
        The dataclass instance; missing keys take the field defaults.

    Raises:
        ConfigError: On unknown or missing keys, wrong types, or a ``ValueError`` from ``__post_init__``.
        TypeError: If ``cls`` is not a dataclass type.
    """
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise TypeError(f"{cls!r} is not a dataclass type")
    return _build(cls, data, source, "")


def to_dict(cfg: Any) -> dict[str, Any]:
    """Convert a config dataclass to plain YAML-safe Python (dicts, lists, scalars).

    Args:
        cfg: Dataclass instance.

    Returns:
        Nested dict of its init fields; tuples become lists and paths strings.
    """
    if not (dataclasses.is_dataclass(cfg) and not isinstance(cfg, type)):
        raise TypeError(f"expected a dataclass instance, got {type(cfg).__name__}")
    return _plain(cfg)


def save_config(cfg: Any, path: str | Path) -> None:
    """Write a config dataclass as YAML atomically (temporary file + ``os.replace``).

    Args:
        cfg: Dataclass instance; ``load_config(type(cfg), path)`` gives back an equal object.
        path: Destination file; parent folders are created.
    """
    text = yaml.safe_dump(to_dict(cfg), sort_keys=False, default_flow_style=False, allow_unicode=True)
    with atomic_output(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _build(cls: type, data: Any, source: str, prefix: str) -> Any:
    """Recursive worker of :func:`from_dict`; ``prefix`` is the dotted path of this section."""
    where = f"section '{prefix}'" if prefix else "top level"
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: {where} must be a mapping, got {_show(data)}")
    hints = _type_hints(cls)
    names = _init_field_names(cls)
    for key in data:
        if key not in names:
            path = f"{prefix}.{key}" if prefix else str(key)
            raise ConfigError(f"{source}: unknown key '{path}' (allowed: {', '.join(sorted(names))})")
    kwargs: dict[str, Any] = {}
    for field in dataclasses.fields(cls):
        if not field.init:
            continue
        path = f"{prefix}.{field.name}" if prefix else field.name
        if field.name in data:
            kwargs[field.name] = _convert(data[field.name], hints[field.name], source, path)
        elif field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{source}: missing required key '{path}'")
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except ValueError as e:
        raise ConfigError(f"{source}: invalid {where}: {e}") from e


def _convert(value: Any, tp: Any, source: str, path: str) -> Any:
    """Check ``value`` against annotation ``tp`` and return it converted (lists to tuples, ints to floats)."""
    result = _try_convert(value, tp, source, path)
    if result is _MISSING:
        raise ConfigError(f"{source}: key '{path}' expects {_type_name(tp)}, got {_show(value)}")
    return result


def _try_convert(value: Any, tp: Any, source: str, path: str) -> Any:
    """Return the converted value, or ``_MISSING`` if ``value`` does not have type ``tp`` at this level.

    Errors deeper down (inside a nested section or container element) raise directly so that they name
    the innermost key path.
    """
    origin = get_origin(tp)
    args = get_args(tp)
    if tp is Any:
        return value
    if tp is type(None):
        return None if value is None else _MISSING
    if origin in (Union, types.UnionType):
        if value is None:
            return None if type(None) in args else _MISSING
        arms = [a for a in args if a is not type(None)]
        if len(arms) == 1:
            return _try_convert(value, arms[0], source, path)
        for arm in arms:
            with contextlib.suppress(ConfigError):
                result = _try_convert(value, arm, source, path)
                if result is not _MISSING:
                    return result
        return _MISSING
    if origin is Literal:
        # type() as well as == so that True does not match Literal[1] nor 1 match Literal[1.0].
        return value if any(type(value) is type(a) and value == a for a in args) else _MISSING
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return _build(tp, value, source, path) if isinstance(value, Mapping) else _MISSING
    if tp is bool:
        return value if isinstance(value, bool) else _MISSING
    if tp is int:
        return value if isinstance(value, int) and not isinstance(value, bool) else _MISSING
    if tp is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        return float(value) if ok else _MISSING
    if tp is str:
        return value if isinstance(value, str) else _MISSING
    if tp in (Path, os.PathLike):
        return Path(value) if isinstance(value, (str, Path)) else _MISSING
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            return _MISSING
        if origin is tuple and args and not (len(args) == 2 and args[1] is Ellipsis):
            if len(value) != len(args):
                return _MISSING
            return tuple(
                _convert(v, a, source, f"{path}[{i}]") for i, (v, a) in enumerate(zip(value, args, strict=True))
            )
        elem = args[0] if args else Any
        items = [_convert(v, elem, source, f"{path}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(value, Mapping):
            return _MISSING
        key_tp, val_tp = args if args else (Any, Any)
        return {
            _convert(k, key_tp, source, f"{path}.<key>"): _convert(v, val_tp, source, f"{path}.{k}")
            for k, v in value.items()
        }
    raise TypeError(f"{source}: key '{path}' has an unsupported annotation {tp!r}")


@functools.cache
def _type_hints(cls: type) -> dict[str, Any]:
    """Resolved field annotations (works with ``from __future__ import annotations``)."""
    return get_type_hints(cls)


def _init_field_names(cls: type) -> list[str]:
    """Names of the fields a config file may set, in declaration order."""
    return [f.name for f in dataclasses.fields(cls) if f.init]


def _dataclass_of(tp: Any) -> type | None:
    """The dataclass type behind ``tp`` (also through ``X | None``), or None if it is not a section."""
    if get_origin(tp) in (Union, types.UnionType):
        arms = [a for a in get_args(tp) if a is not type(None)]
        tp = arms[0] if len(arms) == 1 else None
    return tp if isinstance(tp, type) and dataclasses.is_dataclass(tp) else None


def _type_name(tp: Any) -> str:
    """Readable annotation, e.g. ``int``, ``float | None``, ``Literal['adam', 'sgd']``."""
    if tp is type(None):
        return "None"
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return f"a mapping ({tp.__name__})"
    if isinstance(tp, type) and get_origin(tp) is None:
        return tp.__name__
    if get_origin(tp) in (Union, types.UnionType):
        return " | ".join(_type_name(a) for a in get_args(tp))
    return repr(tp).replace("typing.", "")


def _show(value: Any) -> str:
    """Short description of a given value for error messages."""
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{text} ({type(value).__name__})"


def _copy_mappings(data: Mapping[str, Any]) -> dict[str, Any]:
    """Copy nested mappings (not leaves) so overrides never modify the caller's data."""
    return {k: _copy_mappings(v) if isinstance(v, Mapping) else v for k, v in data.items()}


def _plain(value: Any) -> Any:
    """Recursive worker of :func:`to_dict`."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value) if f.init}
    if isinstance(value, Mapping):
        return {_plain(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return value
