"""One command at a time in an output directory: an OS file lock that a killed command cannot leave behind.

Two training commands started with the same ``--out`` (a second terminal, a job scheduler retrying) would both write
the run: two TensorBoard files, interleaved metrics, each overwriting the other's checkpoints. A command that writes a
run directory (``train-*``, ``track-samcon``) or a report folder (``compare-trackers``) first takes an exclusive
``flock`` on the file ``.lock`` inside it, holding its process id; a second command is refused in one line naming the
folder and that process. The kernel drops the lock when its holder exits however it exits (SIGKILL, a crash), so a
stale ``.lock`` file only holds a number, and the next command takes it over. The holder removes the file when it
releases the lock. Only the main process of a data-parallel run takes it (ranks of one run are one writer).

``flock`` belongs to an open file description: two opens of the file conflict even within one process. Where the
system has no ``fcntl`` (Windows, not a target) nothing is locked.
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import os
import sys
from pathlib import Path

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None  # type: ignore[assignment]

LOCK_NAME = ".lock"


class DirectoryLock:
    """The exclusive lock of one output directory, held by this process from :meth:`acquire` to :meth:`release`.

    Args:
        directory: The folder (it must exist when the lock is taken).
        error: The exception a refusal raises (the command's one-line error: ``RunDirError``, ``ReportError``).
        what: How the message names the folder (``run directory``, ``--out``).
    """

    def __init__(self, directory: str | Path, error: type[Exception] = RuntimeError, what: str = "directory") -> None:
        self.directory = Path(directory)
        self.path = self.directory / LOCK_NAME
        self.error, self.what = error, what
        self._fd: int | None = None
        self._pid = os.getpid()

    @property
    def held(self) -> bool:
        """Whether this object holds the lock."""
        return self._fd is not None

    def acquire(self) -> None:
        """Takes the lock and writes this process's id into the lock file; nothing if already held.

        Raises:
            error: If another process holds it (naming the folder and that process's id).
            OSError: If the lock file cannot be made (a read-only folder, no space).
        """
        if self._fd is not None or fcntl is None:
            return
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as e:
                holder = _holder(fd)
                os.close(fd)
                if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise self.error(f"{self.what} {self.directory} is in use by "
                                     f"{'process ' + holder if holder else 'another process'}, which is writing it; "
                                     f"wait until it ends or choose another folder") from None  # fmt: skip
                if e.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS):  # a file system without locks (NFS)
                    print(f"warning: {self.path}: cannot lock ({e.strerror}); nothing stops a second command from "
                          "writing the folder at the same time", file=sys.stderr)  # fmt: skip
                    return
                raise
            # Its previous holder may have removed the file between our open and our lock: lock the file in place.
            try:
                in_place = os.path.samestat(os.fstat(fd), os.stat(self.path))
            except FileNotFoundError:
                in_place = False
            if in_place:
                break
            os.close(fd)
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        except OSError:
            self._fd = fd
            self.release()
            raise
        self._fd, self._pid = fd, os.getpid()
        atexit.register(self.release)  # the file too, not only the lock, at a normal exit without release()

    def release(self) -> None:
        """Removes the lock file and drops the lock (nothing if not held). The file goes first, while still locked, so
        that a command that opened it meanwhile finds it gone (:meth:`acquire`) rather than taking a lock nobody
        sees."""
        if self._fd is None or os.getpid() != self._pid:  # a forked child's copy: the lock is its parent's
            return
        with contextlib.suppress(OSError):
            if os.path.samestat(os.fstat(self._fd), os.stat(self.path)):  # not one a later holder made
                self.path.unlink()
        os.close(self._fd)
        self._fd = None

    def __enter__(self) -> DirectoryLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _holder(fd: int) -> str:
    """The process id written in a lock file ('' while its holder has not written it yet)."""
    with contextlib.suppress(OSError, ValueError):
        text = os.pread(fd, 32, 0).decode("ascii").strip()
        return text if text.isdigit() else ""
    return ""
