"""The configs that ship with the project (``configs/<command>/*.yaml``) and how a ``--config`` value finds them.

Every command that takes ``--config`` resolves it the same way, so that it works from any working directory:
an existing file is read as given; otherwise a bare name (``paper``, ``paper.yaml``) or a path as written in the
documentation (``configs/ppo/paper.yaml``) is looked up among the bundled configs of the command. The bundled
folder is the repository's ``configs/``, found relative to this package (an editable or source install).
"""

from __future__ import annotations

import re
from pathlib import Path

CONFIG_ROOT = Path(__file__).resolve().parents[1] / "configs"
# Trained policies that ship with the project (``pretrained/<name>/``: a run directory reduced to its policy), made
# by ``python -m report.bundle_policy``; ``pretrained`` alone names the general tracker.
PRETRAINED_ROOT = CONFIG_ROOT.parent / "pretrained"
DEFAULT_PRETRAINED = "general"


def bundled_configs(command: str) -> list[str]:
    """Names of the bundled configs of ``command`` (``supertrack``, ``ppo``, ``samcon``), sorted; [] if none."""
    folder = CONFIG_ROOT / command
    return sorted(p.name for p in folder.glob("*.yaml")) if folder.is_dir() else []


def default_config(command: str) -> Path:
    """The bundled ``default.yaml`` of ``command``."""
    return CONFIG_ROOT / command / "default.yaml"


def resolve_config(value: str | Path, command: str) -> Path:
    """The config file ``value`` names for ``command``.

    Args:
        value: A path, a bundled config's name with or without ``.yaml``, or ``configs/<command>/<name>.yaml``
            (resolved against the bundled folder when it is not a file relative to the working directory).
        command: The command's config folder (``supertrack``, ``ppo``, ``samcon``).

    Returns:
        The existing file it names, or ``value`` unchanged when nothing matches (the loader then says the file
        does not exist, naming it as the user wrote it).
    """
    path = Path(value)
    if path.is_file():
        return path
    candidates = []
    if len(path.parts) == 1:
        candidates += [CONFIG_ROOT / command / path.name, CONFIG_ROOT / command / f"{path.name}.yaml"]
    if path.parts[:1] == ("configs",):
        candidates.append(CONFIG_ROOT.parent / path)
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    return path


def resolve_run(value: str | Path) -> Path:
    """The run directory ``value`` names: an existing path as given, else ``pretrained`` (the bundled general
    tracker) or ``pretrained:NAME`` (another bundled policy); anything else unchanged, for the caller's message."""
    text = str(value)
    if (Path(value) / "run_info.json").is_file() or not (text == "pretrained" or text.startswith("pretrained:")):
        return Path(value)  # a run directory of that name wins (the repository's own pretrained/ folder is none)
    return PRETRAINED_ROOT / (text.partition(":")[2] or DEFAULT_PRETRAINED)


def config_help(command: str) -> str:
    """The ``--config`` help text listing the command's bundled configs."""
    names = ", ".join(n.removesuffix(".yaml") for n in bundled_configs(command)) or "none found"
    return (f"YAML config file, or the name of a bundled one ({names}; in {CONFIG_ROOT / command}); "
            "default: default")  # fmt: skip


def plain_help(docstring: str) -> str:
    """A module docstring as ``--help`` text: reStructuredText roles and literals (``x``, :mod:`x`, `x`) become plain
    words and ``Example::`` becomes ``Example:``."""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", r"\1", docstring)
    text = re.sub(r"``([^`]+)``", r"\1", text)
    text = re.sub(r"`([^`]+)`", r"\1", text)
    return text.replace("::\n", ":\n")
