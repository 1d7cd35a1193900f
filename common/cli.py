"""The one error path of every command: a problem the user can fix ends in one line, a bug keeps its traceback.

Every command (``train-supertrack``, ``train-ppo``, ``track-samcon``, ``compare-trackers``, ``watch-policy``,
``export-policy``, ``mimic-motions``) runs its body under :func:`one_line_errors`. An exception the project raises or
expects (bad options, an unreadable input, an unusable output, a full disk, a refused checkpoint) then ends in one
line on stderr, ``error: <file or option>: <problem>``, and the exit status says what happened:

- :data:`EXIT_BAD_INPUT` (2): the command refused its input or options; nothing was written.
- :data:`EXIT_RUN_FAILED` (1): a failure during the run (a full disk, a NaN loss, a failed worker); what was saved
  before stays.

Any other exception is a bug and keeps its traceback. Options are parsed by :class:`CommandParser` (its errors are one
line too), and output paths are checked before any work by :func:`check_output_dir` and :func:`check_output_file`.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NoReturn

EXIT_BAD_INPUT = 2
EXIT_RUN_FAILED = 1
EXIT_NO_RENDERER = 3  # a command that draws (mimic-motions render, watch-policy) on a machine without a GL backend
# Frames a command may be asked to simulate or render in one go (--frames, --seconds, --max-frames): ten minutes at
# 60 Hz. Each frame is kept as a pose (and drawn); 1e9 s asked for 447 GiB before this bound.
MAX_FRAMES = 36_000


class CommandError(SystemExit):
    """Ends a command with ``error: <message>`` on one line of stderr and exit status ``status``, no traceback.

    A ``SystemExit``, so that nothing on its way catches it as an ``Exception``; ``str()`` gives the line.

    Args:
        message: ``"<file or option>: <problem>"``; further lines (a worker's traceback) are printed after it.
        status: :data:`EXIT_BAD_INPUT` or :data:`EXIT_RUN_FAILED`.
    """

    def __init__(self, message: str, status: int = EXIT_BAD_INPUT) -> None:
        super().__init__(status)
        self.message = message.removeprefix("error: ")

    def __str__(self) -> str:
        return f"error: {self.message}"


def one_line(e: BaseException) -> str:
    """The message of ``e`` on one line: a ``KeyError``'s text without its quotes, several lines joined by ``; ``."""
    text = e.args[0] if isinstance(e, KeyError) and e.args and isinstance(e.args[0], str) else str(e)
    out = ""
    for line in (part.strip() for part in text.splitlines()):
        if line:
            out += ("" if not out else " " if out.endswith(":") else "; ") + line
    return out.removeprefix("error: ") or type(e).__name__


def os_error_line(e: OSError) -> str:
    """``"<file>: <problem>"`` of an ``OSError`` (both files of a failed rename)."""
    problem = e.strerror or one_line(e)
    names = [str(n) for n in (e.filename, e.filename2) if n is not None]
    return f"{' -> '.join(names)}: {problem}" if names else problem


@contextlib.contextmanager
def one_line_errors(*expected: type[BaseException]) -> Iterator[None]:
    """Turns the exceptions a command expects into one ``error:`` line and an exit status (also a decorator).

    ``expected`` (e.g. ``ConfigError``, ``MotionFormatError``, ``ReportError``) end with :data:`EXIT_BAD_INPUT`; an
    ``OSError`` not handled closer to where it happened (a full disk while writing) with :data:`EXIT_RUN_FAILED`; a
    :class:`CommandError` with its own status; ``sys.exit("error: ...")`` with :data:`EXIT_BAD_INPUT`. Anything
    else propagates with its traceback.

    A background thread that an ``OSError`` ends (TensorBoard's writer on a full disk) prints no traceback meanwhile:
    the error is kept for the main thread, whose writer raises it at its next write or close (the run's one error
    path, :func:`take_thread_failure`), or, if nothing took it, when the command's body returns. Any other exception
    of a thread is a bug and keeps its traceback.

    Raises:
        CommandError: After printing its line to stderr.
    """
    previous_hook = threading.excepthook

    def keep_thread_failure(args: threading.ExceptHookArgs) -> None:
        if isinstance(args.exc_value, OSError):
            _thread_failures.append(args.exc_value)
        else:
            previous_hook(args)

    threading.excepthook = keep_thread_failure
    try:
        yield
        failure = take_thread_failure()
        if failure is not None:
            raise failure
    except CommandError as e:
        _print(e)
        raise
    except SystemExit as e:
        if not isinstance(e.code, str):  # argparse's 2, --help's 0, a command's own status
            raise
        raise _print(CommandError(e.code, EXIT_BAD_INPUT)) from None
    except expected as e:
        raise _print(CommandError(one_line(e), EXIT_BAD_INPUT)) from None
    except OSError as e:
        raise _print(CommandError(os_error_line(e), EXIT_RUN_FAILED)) from None
    finally:
        threading.excepthook = previous_hook
        _thread_failures.clear()


# OSErrors that ended background threads while a command ran (one_line_errors), oldest first.
_thread_failures: list[OSError] = []


def take_thread_failure() -> OSError | None:
    """The first ``OSError`` that ended a background thread while a command runs under :func:`one_line_errors` (which
    kept it from printing a traceback); None if none. The writer whose thread it was raises it, naming its file;
    taking it forgets every kept one."""
    failure = _thread_failures[0] if _thread_failures else None
    _thread_failures.clear()
    return failure


def exit_status(body: Callable[[], int], *expected: type[BaseException]) -> int:
    """Runs the body of a command whose ``main`` returns its exit status under :func:`one_line_errors`: a refused
    input or a failed run returns its status (the line printed) instead of raising it."""
    try:
        with one_line_errors(*expected):
            return body()
    except CommandError as e:
        return int(e.code) if isinstance(e.code, int) else EXIT_BAD_INPUT


def _print(e: CommandError) -> CommandError:
    print(str(e), file=sys.stderr, flush=True)
    return e


def fail(message: str, status: int = EXIT_BAD_INPUT) -> NoReturn:
    """Raises :class:`CommandError` (its line is printed by :func:`one_line_errors`)."""
    raise CommandError(message, status)


class CommandParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line, ``error: --x: problem (see prog --help)``, exit status 2."""

    def error(self, message: str) -> NoReturn:
        print(f"error: {message.removeprefix('argument ')} (see {self.prog} --help)", file=sys.stderr, flush=True)
        raise SystemExit(EXIT_BAD_INPUT)


def _number(text: str, kind: Callable[[str], float], what: str, ok: Callable[[float], bool]) -> float:
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None
    if not ok(value):
        raise argparse.ArgumentTypeError(f"must be {what}, got {text}")
    return value


def non_negative_int(text: str) -> int:
    """An option's value: an integer >= 0."""
    return int(_number(text, int, "an integer >= 0", lambda v: v >= 0))


def positive_int(text: str) -> int:
    """An option's value: an integer >= 1."""
    return int(_number(text, int, "an integer >= 1", lambda v: v >= 1))


def non_negative_float(text: str) -> float:
    """An option's value: a finite number >= 0 (``inf`` is refused too: a budget must end)."""
    return _number(text, float, "a finite number >= 0", lambda v: math.isfinite(v) and v >= 0)


def positive_float(text: str) -> float:
    """An option's value: a finite number > 0."""
    return _number(text, float, "a finite number > 0", lambda v: math.isfinite(v) and v > 0)


def frame_count(text: str) -> int:
    """An option's value: a number of frames, 1 to :data:`MAX_FRAMES`."""
    return int(_number(text, int, f"an integer from 1 to {MAX_FRAMES}", lambda v: 1 <= v <= MAX_FRAMES))


def pixels(text: str) -> int:
    """An option's value: an image side in pixels, 16 to 4096."""
    return int(_number(text, int, "an integer from 16 to 4096 (pixels)", lambda v: 16 <= v <= 4096))


def _first_existing(path: Path) -> Path:
    """``path`` or its nearest ancestor that exists (``lstat``: a dangling link counts as existing)."""
    for candidate in (path, *path.parents):
        if os.path.lexists(candidate):
            return candidate
    return Path(".")


def _place_problem(folder: Path) -> str | None:
    """Why nothing can be written in ``folder`` (which need not exist yet), or None."""
    base = _first_existing(folder.absolute())
    if not base.is_dir():
        return f"{base} is a file, not a directory"
    if not os.access(base, os.W_OK | os.X_OK):
        return f"{base} is not writable"
    return None


def output_dir_problem(path: str | Path) -> str | None:
    """Why ``path`` cannot be used as an output directory (an existing file, inside a file, not writable), or None.
    Creates nothing."""
    path = Path(path)
    if os.path.lexists(path) and not path.is_dir():
        return "exists and is not a directory"
    return _place_problem(path)


def output_file_problem(path: str | Path) -> str | None:
    """Why ``path`` cannot be written as a file (a directory, inside a file, not writable), or None. Creates nothing."""
    path = Path(path)
    if path.is_dir():
        return "is a directory; give a file name"
    if os.path.lexists(path) and not path.is_file():
        return "exists and is not a regular file"
    return _place_problem(path.parent)


def check_output_dir(path: str | Path, option: str = "--out") -> None:
    """Refuses, before any work, an output directory that cannot be used (:func:`output_dir_problem`).

    Raises:
        CommandError: ``"<option> <path>: <problem>"``, :data:`EXIT_BAD_INPUT`.
    """
    problem = output_dir_problem(path)
    if problem is not None:
        fail(f"{option} {path}: {problem}")


def check_output_file(path: str | Path, option: str = "--out") -> None:
    """Refuses, before any work, an output file that cannot be written (:func:`output_file_problem`).

    Raises:
        CommandError: ``"<option> <path>: <problem>"``, :data:`EXIT_BAD_INPUT`.
    """
    problem = output_file_problem(path)
    if problem is not None:
        fail(f"{option} {path}: {problem}")
