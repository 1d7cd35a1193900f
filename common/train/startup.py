"""What a training command does before its first iteration, the same for every learner: the shared options, the
config with its overrides, the validation of everything a user gave (config, device, motions, ``--out``), and the run
directory, made only once all of it is accepted (:func:`prepare`, then :func:`start`).
"""

from __future__ import annotations

import argparse
import contextlib
import shutil
from collections.abc import Callable, Mapping
from datetime import datetime
from pathlib import Path
from typing import Any

import torch

from common.bundled_configs import config_help, default_config
from common.bundled_configs import resolve_config as find_config
from common.character.humanoid import Humanoid
from common.cli import EXIT_RUN_FAILED, CommandError, non_negative_float, non_negative_int, one_line, os_error_line
from common.config import ConfigError, load_config
from common.motion.dataset import load_motions
from common.motion.library import MotionLibrary
from common.motion.motion import MotionFormatError
from common.run.contained import check_run_directory
from common.run.directory import RunDir, RunDirError
from common.train.training import check_device


def check_device_available(device: str) -> None:
    """Refuses a device this machine does not have (asked for when a run starts, not when a config is read).

    Raises:
        ValueError: Naming the device.
    """
    kind = torch.device(device)
    if kind.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise ValueError(f"device {device!r}: no CUDA GPU on this machine (torch {torch.__version__})")
        if kind.index is not None and kind.index >= count:
            raise ValueError(f"device {device!r}: this machine has {count} CUDA GPU(s), cuda:0 to cuda:{count - 1}")
    elif kind.type == "mps" and not (hasattr(torch.backends, "mps") and torch.backends.mps.is_available()):
        raise ValueError(f"device {device!r}: MPS is not available on this machine")
    elif kind.type not in ("cpu", "cuda", "mps"):
        raise ValueError(f"device {device!r}: this project runs on cpu, cuda or mps")


def _device_option(text: str) -> str:
    """``--device``'s value: a torch device name."""
    try:
        check_device(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def add_common_arguments(parser: argparse.ArgumentParser, command: str) -> None:
    """The options both training commands share; ``command`` names the bundled config folder (``configs/<command>``)."""
    parser.add_argument("--config", default=None,
                        help=config_help(command) + " (with --resume: the run's own config.yaml, so that --out and "
                             "--resume are enough to continue a run)")  # fmt: skip
    parser.set_defaults(default_config=str(default_config(command)), config_command=command)
    parser.add_argument("--motions", nargs="+", default=None,
                        help="motions to track, overriding train.motions: bundled clip names (walk, run, "
                             "walk_stairs, ...), 'all', 'long', 'terrain', DeepMimic .txt files, folders, or a "
                             "motion dataset .h5")  # fmt: skip
    parser.add_argument("--device", default=None, type=_device_option,
                        help="torch device for the networks, e.g. cpu or cuda (train.device)")  # fmt: skip
    parser.add_argument("--out", default=None,
                        help="run directory (default: runs/<learner>-<date>-<time>); must not hold a run unless "
                             "--resume")  # fmt: skip
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue the run in --out from its latest checkpoint (same config and character)",
    )
    parser.add_argument("--max-minutes", type=non_negative_float, default=None,
                        help="training wall-clock budget in minutes (train.max_minutes)")  # fmt: skip
    parser.add_argument("--max-iterations", type=non_negative_int, default=None,
                        help="iteration budget (train.max_iterations)")  # fmt: skip
    parser.add_argument("--seed", type=non_negative_int, default=None, help="random seed (train.seed)")
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override any config value, e.g. --set gym.num_envs=128 (repeatable)",
    )


def resolve_config(cls: type, args: argparse.Namespace) -> Any:
    """Loads the config file with ``--set`` overrides and the dedicated options applied.

    Without ``--config`` it is the command's default, or with ``--resume`` the run's own ``config.yaml`` (the
    resolved config it was started with); ``args.config`` is set to the file read, for messages.

    Raises:
        ConfigError: As :func:`common.config.load_config`.
        RunDirError: If the run to resume holds a link leading outside it (read before its config is).
    """
    within = None
    if args.config is None:
        saved = Path(args.out) / "config.yaml" if args.resume and args.out else None
        if saved is not None:
            check_run_directory(args.out, RunDirError)
            within = args.out if saved.is_file() else None
        args.config = str(saved) if within is not None else args.default_config
    else:
        args.config = str(find_config(args.config, args.config_command))
    overrides = list(args.overrides)
    if args.motions is not None:
        overrides.append("train.motions=[" + ", ".join(repr(m) for m in args.motions) + "]")
    for option, key in (("device", "train.device"), ("max_minutes", "train.max_minutes"),
                        ("max_iterations", "train.max_iterations"), ("seed", "train.seed")):  # fmt: skip
        value = getattr(args, option)
        if value is not None:
            overrides.append(f"{key}={value}")
    return load_config(cls, args.config, overrides, within=within)


def prepare(
    cls: type,
    args: argparse.Namespace,
    learner_name: str,
    check: Callable[[Any, Humanoid, MotionLibrary], None] | None = None,
) -> tuple[Any, RunDir, Humanoid, MotionLibrary]:
    """Config, model, motions and the run directory (checked, not yet created) of a training command; seeds torch.

    Everything a user gives is validated here: the config and its overrides, the device, the motions,
    ``check(cfg, humanoid, library)`` (what only the model and motions can validate; it raises ValueError naming the
    key) and ``--out``. Nothing is written: :func:`start` creates the run directory once the learner is built too,
    so that a refused start leaves nothing behind and the same ``--out`` can be used again.

    Raises:
        CommandError: One line naming the file, option or key and the problem (exit status 2).
    """
    try:
        cfg = resolve_config(cls, args)
        try:
            check_device_available(cfg.train.device)
        except ValueError as e:
            raise ConfigError(f"{args.config}: train.{e}") from None
        humanoid = Humanoid(cfg.gym.physics)
        library = load_motions(list(cfg.train.motions), humanoid)
        if check is not None:
            try:
                check(cfg, humanoid, library)
            except ValueError as e:
                raise ConfigError(f"{args.config}: {e}") from e
        out = args.out or f"runs/{learner_name}-{datetime.now().strftime('%Y%m%d-%H%M%S')}"
        run_dir = RunDir(out, resume=args.resume, keep_checkpoints=cfg.train.keep_checkpoints, create=False)
    except (ConfigError, RunDirError, MotionFormatError) as e:
        raise CommandError(one_line(e)) from None
    except OSError as e:  # a config or motion file that cannot be read
        raise CommandError(os_error_line(e)) from None
    torch.manual_seed(cfg.train.seed)
    torch.set_num_threads(max(1, cfg.train.torch_threads))
    return cfg, run_dir, humanoid, library


def start(cfg: Any, run_dir: RunDir, library: MotionLibrary, learner_name: str,
          info: Mapping[str, Any] | None = None) -> None:  # fmt: skip
    """Creates and locks the run directory and writes ``config.yaml`` (a new run) and ``run_info.json`` (``info``
    added). The lock is held until ``run_dir.unlock()`` or the end of the process (:meth:`RunDir.lock`).

    If that fails, what it made of a new run is removed again, so that the same ``--out`` can be used once the
    cause is fixed; a directory that another command is writing is left as it is.

    Raises:
        CommandError: If the directory cannot be made or another command is writing it (exit status 2), or its files
            cannot be written (a full disk: exit status 1).
    """
    # The highest folder this start makes (None: the run directory exists), removed again if the start fails.
    made = next((p for p in reversed([run_dir.path, *run_dir.path.absolute().parents]) if not p.exists()), None)
    try:
        run_dir.lock()
    except RunDirError as e:
        _remove_empty_folders(run_dir.path, made)
        raise CommandError(str(e)) from None
    try:
        run_dir.create()
        if not run_dir.resume:
            run_dir.save_config(cfg)
        run_dir.write_run_info({"learner": learner_name, "seed": cfg.train.seed, "motions": list(library.names),
                                **(info or {})})  # fmt: skip
    except (RunDirError, OSError) as e:
        if not run_dir.resume:
            _undo_start(run_dir, made)
        run_dir.unlock()
        if isinstance(e, RunDirError):
            raise CommandError(str(e)) from None
        raise CommandError(f"run directory {run_dir.path}: cannot write {os_error_line(e)}", EXIT_RUN_FAILED) from None


def _remove_empty_folders(path: Path, made: Path | None) -> None:
    """Removes ``path`` and its parents up to ``made`` while they are empty (folders a refused lock made; a folder
    another command has filled meanwhile stays)."""
    if made is None:
        return
    for folder in (path.absolute(), *path.absolute().parents):
        try:
            folder.rmdir()
        except OSError:
            return
        if folder == made.absolute():
            return


def _undo_start(run_dir: RunDir, made: Path | None) -> None:
    """Removes what :func:`start` made of a new run: the folders it made, else (the run directory existed) its
    ``checkpoints/`` (still empty) and ``config.yaml`` (a new run's folder had none)."""
    if made is not None:
        shutil.rmtree(made, ignore_errors=True)
        return
    with contextlib.suppress(OSError):
        run_dir.checkpoint_dir.rmdir()
    with contextlib.suppress(OSError):
        run_dir.config_path.unlink(missing_ok=True)


def setup(
    cls: type,
    args: argparse.Namespace,
    learner_name: str,
    check: Callable[[Any, Humanoid, MotionLibrary], None] | None = None,
    info: Mapping[str, Any] | None = None,
) -> tuple[Any, RunDir, Humanoid, MotionLibrary]:
    """:func:`prepare`, then :func:`start`: config, a created run directory, model and motions (for scripts that
    build their learner themselves).

    Raises:
        CommandError: One line naming the file, option or key and the problem.
    """
    cfg, run_dir, humanoid, library = prepare(cls, args, learner_name, check)
    start(cfg, run_dir, library, learner_name, info)
    return cfg, run_dir, humanoid, library
