"""A command line as ``run_info.json`` records it: what the user typed, without the training machine's paths.

A run directory (and a bundle made from one, ``pretrained/``) travels to other machines, so its records name paths
relative to the working directory or the project, or not at all. The program is named as the user would type it
(``train-supertrack``, not ``/home/me/project/.venv/bin/train-supertrack``; ``python -m supertrack.train``, not the
module's file path that ``python -m`` puts in ``argv[0]``), and every absolute path among the arguments (``--out
/scratch/me/run``, ``--config=/home/me/x.yaml``, ``KEY=/path``) becomes relative to the working directory when it lies
inside it, else relative to the project when it lies inside that, else its name alone (``run``).
"""

from __future__ import annotations

import os
import shlex
from collections.abc import Sequence
from pathlib import Path, PurePosixPath

PROJECT_ROOT = Path(__file__).resolve().parents[2]


def portable_path(path: str, cwd: str | Path | None = None) -> str:
    """``path`` as a record may name it: unchanged if relative; else relative to ``cwd`` (default: the working
    directory) or to the project when inside either, else its last component (the root ``/`` stays ``/``)."""
    if not os.path.isabs(path):
        return path
    absolute = Path(os.path.normpath(path))
    for base in (Path(cwd if cwd is not None else os.getcwd()), PROJECT_ROOT):
        if absolute == base:
            return "."
        if absolute.is_relative_to(base):
            return absolute.relative_to(base).as_posix()
    return absolute.name or path


def portable_args(args: Sequence[str], cwd: str | Path | None = None) -> list[str]:
    """Command-line arguments with every absolute path made portable (:func:`portable_path`), also after ``=``."""
    out = []
    for arg in args:
        if os.path.isabs(arg):
            out.append(portable_path(arg, cwd))
            continue
        # ``--opt=/path``, ``KEY=/path``, ``--set=KEY=/path``: the value after the first '=' that starts a path.
        cut = next((i + 1 for i, c in enumerate(arg) if c == "=" and os.path.isabs(arg[i + 1 :])), None)
        out.append(arg if cut is None else arg[:cut] + portable_path(arg[cut:], cwd))
    return out


def program_name(argv0: str) -> str:
    """The program of ``argv[0]`` as a user types it: a module's file inside the project (``python -m`` puts its path
    there) becomes ``python -m <module>`` (a script outside a package ``python <path>``); any other program its file
    name (a console script in a virtual environment: ``train-supertrack``)."""
    path = PurePosixPath(argv0)
    if path.suffix == ".py":
        # The shortest tail of the path that is a file of this project (an old record may name another checkout).
        tail = next((path.parts[i:] for i in range(len(path.parts) - 1, -1, -1)
                     if path.parts[i] != "/" and PROJECT_ROOT.joinpath(*path.parts[i:]).is_file()), None)  # fmt: skip
        if tail is not None:
            if len(tail) > 1 and all((PROJECT_ROOT.joinpath(*tail[:i]) / "__init__.py").is_file()
                                     for i in range(1, len(tail))):  # fmt: skip
                return "python -m " + ".".join((*tail[:-1], PurePosixPath(tail[-1]).stem))
            return "python " + "/".join(tail)
    return path.name or argv0


def portable_command(argv: Sequence[str], cwd: str | Path | None = None) -> str:
    """``argv`` (default use: ``sys.argv``) as one shell-quoted line with no absolute path of this machine."""
    if not argv:
        return ""
    return " ".join([program_name(argv[0]), *map(shlex.quote, portable_args(argv[1:], cwd))])


def portable_command_text(command: str, cwd: str | Path | None = None) -> str:
    """A recorded command line (an older run's, which may hold absolute paths) made portable the same way; a line
    that does not split as shell words is returned as it is."""
    try:
        return portable_command(shlex.split(command), cwd)
    except ValueError:
        return command
