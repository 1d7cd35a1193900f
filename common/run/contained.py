"""What a run directory names stays inside it.

A run directory travels (a colleague's run, a downloaded bundle), so what it holds is input like any other: a
``run_info.json`` whose ``policy_file`` is ``../../../../etc/passwd`` or ``/etc/passwd``, a checkpoint or ``tb/``
that is a link to another folder, a ``config.yaml`` whose ``base`` is a file elsewhere. A command that opens a run
(``compare-trackers``, ``watch-policy``, ``export-policy``, ``bundle_policy``, ``--resume``, ``--init-from``) would
read, or on resume write, a file outside the run. Every such name is resolved here, links included, and one that
leads outside the run is refused before anything is opened, in one line naming the run, the entry and where it leads
(a ``base`` outside: :func:`common.config.load_config`'s ``within``).
"""

from __future__ import annotations

from pathlib import Path

_WHY = "a run directory names only files inside itself"
# The folders of a run directory's layout (common.run.directory): what a run reads or writes lies in them or at its top.
RUN_FOLDERS = ("checkpoints", "tb")


def _inside(path: Path, root: Path) -> bool:
    return path == root or root in path.parents


def run_file(run_dir: str | Path, name: str | Path, error: type[Exception] = ValueError,
             named_by: str = "it") -> Path:  # fmt: skip
    """``run_dir / name``, for a file name read from the run (``run_info.json``'s ``policy_file``).

    Args:
        run_dir: The run directory.
        name: The name the run gives, relative to ``run_dir``.
        error: The exception raised (the caller's one-line error: ``ReportError``, ``RunDirError``, ...).
        named_by: Where the name was read, for the message (``run_info.json's policy_file``).

    Returns:
        ``run_dir / name``, as the run spells it.

    Raises:
        error: If the name is absolute or, links and ``..`` resolved, leads outside ``run_dir``.
    """
    root, path = Path(run_dir).resolve(), Path(run_dir) / name
    target = path.resolve()
    if Path(name).is_absolute() or target == root or root not in target.parents:
        raise error(f"{run_dir}: {named_by} names {str(name)!r}, which leads outside the run directory (to {target}); "
                    f"{_WHY}")  # fmt: skip
    return path


def check_run_directory(run_dir: str | Path, error: type[Exception] = ValueError) -> None:
    """Refuses a run directory holding a link that leads outside it: among its own entries (every file a run reads
    or writes lies at its top or in :data:`RUN_FOLDERS`: ``checkpoints/``, ``tb/``), a checkpoint, ``checkpoints/``,
    ``tb/``, ``metrics.jsonl`` or ``config.yaml`` linked to another folder. Links are read, not followed; other
    folders of the user's inside it are not searched (an ``--out`` given to a new run may be any folder); a missing
    ``run_dir`` passes (the caller says what is missing).

    Raises:
        error: Naming the entry and where it leads.
    """
    root = Path(run_dir)
    if not root.is_dir():
        return
    resolved = root.resolve()
    # Its top first: a layout folder read through a link (one inside the run) holds the run's files too.
    for folder in (root, *(root / name for name in RUN_FOLDERS)):
        for entry in sorted(folder.iterdir()) if folder.is_dir() else ():
            if entry.is_symlink() and not _inside(target := entry.resolve(), resolved):
                raise error(f"{entry}: a link to {target}, outside the run directory {run_dir}; {_WHY}")
