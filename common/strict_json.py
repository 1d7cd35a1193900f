"""JSON read strictly: a key given twice in one object is refused, naming the key and its line.

Python's ``json`` keeps the last value of a repeated key without a word (``{"learner": "ppo", "learner": "samcon"}``
reads as a SAMCON run), so every JSON file the project reads (clips, ``run_info.json``, ``latest.json``,
``metrics.jsonl``, results) goes through :func:`parse_json`. YAML's counterpart is the loader of
:func:`common.config.parse_yaml`.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from typing import Any

# A JSON string, or one of the characters that give a string its role (a key before ':', a value after).
_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|[{}\[\]:,]')


class DuplicateKeyError(json.JSONDecodeError):
    """A JSON object that holds a key twice. A ``JSONDecodeError`` (so a ``ValueError``), so that every reader's
    handling of bad JSON takes it; ``str()`` is one line: ``duplicate key 'k' (first at line 2): line 3 column 5 (char
    40)``."""


class _Repeated(Exception):
    """Raised from inside ``json.loads`` by :func:`_unique`; turned into :class:`DuplicateKeyError` with its place."""

    def __init__(self, key: str) -> None:
        super().__init__(key)
        self.key = key


def _unique(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``json``'s ``object_pairs_hook``: the object as a dict, unless a key repeats."""
    out = dict(pairs)
    if len(out) != len(pairs):
        seen: set[str] = set()
        raise _Repeated(next(k for k, _ in pairs if k in seen or seen.add(k)))  # type: ignore[func-returns-value]
    return out


def parse_json(text: str, parse_int: Callable[[str], Any] | None = None) -> Any:
    """``json.loads(text)``, refusing an object that holds a key twice.

    Args:
        text: JSON text.
        parse_int: As ``json.loads``'s (e.g. a bound on the digits of an integer).

    Raises:
        DuplicateKeyError: Naming the key, the line of its first and of its second occurrence.
        json.JSONDecodeError: If the text is not JSON.
    """
    try:
        return json.loads(text, object_pairs_hook=_unique, parse_int=parse_int)
    except _Repeated as e:
        raise _duplicate(text, e.key) from None


def _duplicate(text: str, key: str) -> DuplicateKeyError:
    """The error for the first key, in reading order, that its object holds twice (``key`` if none is found: the
    text before the object ``json`` refused is valid JSON, so the scan finds one)."""
    stack: list[dict[str, int] | None] = []  # per open object: {key: offset of its first occurrence}; None: a list
    wants_key = False
    for token in _TOKEN.finditer(text):
        kind = token.group()
        if kind in "{[":
            stack.append({} if kind == "{" else None)
            wants_key = kind == "{"
        elif kind in "}]":
            stack.pop()
            wants_key = False
        elif kind in ",:":
            wants_key = kind == "," and bool(stack) and stack[-1] is not None
        elif wants_key and stack and stack[-1] is not None:
            name = json.loads(kind)
            if name in stack[-1]:
                first = text.count("\n", 0, stack[-1][name]) + 1
                return DuplicateKeyError(f"duplicate key {name!r} (first at line {first})", text, token.start())
            stack[-1][name] = token.start()
    return DuplicateKeyError(f"duplicate key {key!r}", text, 0)
