"""The import rules of docs/architecture.md hold: every import statement of every module is allowed by the doc's
layer table, read from the doc itself, so that the doc and the code cannot drift apart.

A unit is a row's package: a subpackage of ``common/`` (``common/sim``), the base modules ``common/*.py``, or a
top-level package (``ppo``, with ``ppo/rslrl`` inside it). A unit may import itself and the units its row's "may
import" column names in backticks (``common/`` names every unit of ``common/``); words outside backticks are prose.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "architecture.md"
PACKAGES = ("common", "supertrack", "ppo", "samcon", "report", "studies", "benchmarks")
BASE = "common/*.py"


def unit_of_file(path: str) -> str:
    """The unit of a module file given relative to the repository (``common/sim/gym.py`` -> ``common/sim``)."""
    parts = path.split("/")
    if parts[0] != "common":
        return parts[0]
    return BASE if len(parts) == 2 else f"common/{parts[1]}"


def unit_of_module(module: str, root: Path = ROOT) -> str | None:
    """The unit of a dotted module name (``common.sim.gym`` -> ``common/sim``); None outside the project."""
    parts = module.split(".")
    if parts[0] not in PACKAGES:
        return None
    if parts[0] != "common":
        return parts[0]
    if len(parts) == 1:
        return BASE  # ``import common``: its __init__
    return f"common/{parts[1]}" if (root / "common" / parts[1]).is_dir() else BASE


def parse_rules(text: str) -> dict[str, set[str]]:
    """The layer table of the doc's "Layers" section: unit -> the units it may import (itself included).

    Raises:
        ValueError: If the table is missing or names something that is not a unit.
    """
    section = text.split("\n## Layers\n", 1)[1].split("\n## ", 1)[0] if "\n## Layers\n" in text else ""
    rows = [line for line in section.splitlines() if line.startswith("|")][2:]  # past the header and its rule
    if not rows:
        raise ValueError("docs/architecture.md: no table under '## Layers'")
    named: dict[str, list[str]] = {}
    for row in rows:
        cells = [c.strip() for c in row.strip().strip("|").split("|")]
        if len(cells) != 3:
            raise ValueError(f"docs/architecture.md: a layer row needs 3 cells: {row}")
        units = [u.rstrip("/") for u in re.findall(r"`([^`]+)`", cells[0])]
        if not units:
            raise ValueError(f"docs/architecture.md: a layer row names no package: {row}")
        for unit in units:
            named[unit] = [u.rstrip("/") for u in re.findall(r"`([^`]+)`", cells[2])]
    common_units = {u for u in named if u == BASE or u.startswith("common/")}
    rules: dict[str, set[str]] = {}
    for unit, allowed in named.items():
        rules[unit] = {unit}
        for name in allowed:
            if name == "common":
                rules[unit] |= common_units
            elif name in named:
                rules[unit].add(name)
            else:
                raise ValueError(f"docs/architecture.md: {unit}'s row may import {name!r}, which is no row's package")
    return rules


def imported_modules(source: str, path: str) -> Iterable[tuple[int, str]]:
    """(line, dotted module) of every import in ``source`` (a file at ``path`` relative to the repository), inside
    functions too; ``from X import name`` yields ``X.name`` (it may be a module), relative imports are resolved."""
    package = path.split("/")[:-1]
    for node in ast.walk(ast.parse(source, filename=path)):
        if isinstance(node, ast.Import):
            yield from ((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            module = ".".join([*base, *([node.module] if node.module else [])])
            yield from ((node.lineno, f"{module}.{alias.name}") for alias in node.names)


def violations(files: Iterable[tuple[str, str]], rules: dict[str, set[str]]) -> list[str]:
    """What breaks ``rules`` among ``files`` ((path relative to the repository, source) pairs), one line each."""
    found = []
    for path, source in files:
        unit = unit_of_file(path)
        if unit not in rules:
            found.append(f"{path}: its package {unit} has no row in docs/architecture.md's layer table")
            continue
        for line, module in imported_modules(source, path):
            target = unit_of_module(module)
            if target is not None and target not in rules[unit]:
                found.append(f"{path}:{line}: {unit} imports {module} ({target}), which its row does not allow")
    return found


def project_files() -> list[tuple[str, str]]:
    return [(p.relative_to(ROOT).as_posix(), p.read_text(encoding="utf-8"))
            for package in PACKAGES for p in sorted((ROOT / package).rglob("*.py"))
            if "__pycache__" not in p.parts]  # fmt: skip


@pytest.fixture(scope="module")
def rules() -> dict[str, set[str]]:
    return parse_rules(DOC.read_text(encoding="utf-8"))


def test_every_import_is_allowed_by_the_layer_table(rules: dict[str, set[str]]) -> None:
    files = project_files()
    assert len(files) > 100
    assert violations(files, rules) == []


def test_the_table_states_the_rules_the_doc_describes(rules: dict[str, set[str]]) -> None:
    """The parse reads the doc as a person does (the rules its prose summarises)."""
    common = {u for u in rules if u == BASE or u.startswith("common/")}
    assert {"common/maths", "common/sim", "common/run", "common/train", BASE} <= common
    assert rules["common/maths"] == {"common/maths"}
    assert rules[BASE] == {BASE}
    assert rules["common/run"] == {"common/run", BASE}
    assert all(rules[u] <= common for u in common)  # common/ knows nothing above it
    for learner in ("supertrack", "ppo", "samcon"):
        assert rules[learner] == common | {learner}  # common/ only: never each other
    assert rules["report"] == common | {"report"}  # learners only by name, through the registry
    assert [u for u in rules if "studies" in rules[u]] == ["studies", "benchmarks"]
    assert [u for u in rules if "benchmarks" in rules[u]] == ["benchmarks"]


@pytest.mark.parametrize(("path", "source", "expected"), [
    ("common/sim/fake.py", "from report.runs import Run\n", "common/sim imports report.runs.Run (report)"),
    ("common/maths/fake.py", "def f():\n    import common.config\n", "maths imports common.config (common/*.py)"),
    ("common/run/fake.py", "from ..sim import gym\n", "common/run imports common.sim.gym (common/sim)"),
    ("common/config.py", "from common import motion\n", "common/*.py imports common.motion (common/motion)"),
    ("ppo/rslrl/fake.py", "import supertrack.models\n", "ppo imports supertrack.models (supertrack)"),
    ("samcon/fake.py", "from studies.samcon import assist\n", "samcon imports studies.samcon.assist (studies)"),
], ids=["upward", "in-a-function", "relative", "base-upward", "learner-to-learner", "product-to-studies"])  # fmt: skip
def test_a_made_up_forbidden_import_is_reported(rules: dict[str, set[str]], path: str, source: str,
                                                expected: str) -> None:  # fmt: skip
    found = violations([(path, source)], rules)
    assert len(found) == 1 and expected in found[0], found


def test_allowed_imports_and_other_libraries_pass(rules: dict[str, set[str]]) -> None:
    source = "import numpy\nfrom rsl_rl.env import VecEnv\nfrom common.sim.gym import TrackingGym\nfrom ppo import gae"
    assert violations([("ppo/rslrl/fake.py", source)], rules) == []
    assert violations([("common/motion/fake.py", "from common.config import ConfigError\n")], rules) == []


def test_a_package_missing_from_the_table_and_a_table_naming_no_package_are_reported(
        rules: dict[str, set[str]]) -> None:  # fmt: skip
    assert "has no row" in violations([("common/newlayer/x.py", "")], rules)[0]
    doc = "# A\n\n## Layers\n| package | what | may import |\n|---|---|---|\n| `common/maths` | x | `common/mats` |\n"
    with pytest.raises(ValueError, match="'common/mats', which is no row's package"):
        parse_rules(doc)
    with pytest.raises(ValueError, match="no table"):
        parse_rules("# A\n\n## Layers\nprose only\n")
