"""``train-supertrack``: train SuperTrack (world model + policy through it) on motion clips.

The command is the shared :func:`common.train.command.train_main` with SuperTrack's learner and its own option,
``--init-from`` (fine-tuning from another run's networks).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from common.character.humanoid import Humanoid
from common.config import to_dict
from common.evaluation.evaluate import EvalResult
from common.motion.library import MotionLibrary
from common.run.checkpoint import CheckpointError
from common.run.directory import read_checkpoint
from common.sim.collect import CollectorError
from common.train.command import TrainingCommand, train_main
from common.train.distributed import World
from supertrack.config import SuperTrackConfig, TerrainConfig
from supertrack.learner import SuperTrackLearner, clip_weights

DESCRIPTION = """\
Train a SuperTrack tracker (Fussell et al. 2021): a world model learns the simulator from the gym's frames and the
policy learns by back-propagating a tracking loss through it. The run is evaluated periodically by the shared
evaluator (eval/...); the world model's accuracy is logged as world_model/...

Config sections (any key can be overridden with --set section.key=value): train (budget, seed, device, logging,
eval), gym (characters, physics, termination), world_model and policy (network sizes, batch, window, learning
rate, loss weights; policy also sigma and alpha_deg), buffer (capacity, held-back characters), collect (gym steps
per iteration, warm-up, worker processes, clip_weights), diagnostics (world-model error horizons), terrain (the
heightmap and contact labels the networks read on terrain, W's contact output; off). Bundled configs: default (a
2-core CPU), paper (the paper's sizes, for a GPU), debug (tests)."""

EXAMPLES = (
    "train-supertrack --motions walk --out runs/st-walk",
    "train-supertrack --out runs/st-walk --resume --max-minutes 120   # continue the same run",
    "train-supertrack --config paper --device cuda --motions all --out runs/st-all",
    "train-supertrack --set 'collect.clip_weights={walk: 10}' --motions walk jog run   # oversample walk",
    "train-supertrack --init-from runs/st-walk --motions run --out runs/st-run   # fine-tune walk to run",
    "torchrun --standalone --nproc_per_node=2 -m supertrack.train --set gym.threads=1 --out runs/st-2ranks"
    "   # 2 ranks",
)  # fmt: skip


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """SuperTrack's own option: ``--init-from``."""
    parser.add_argument("--init-from", default=None, metavar="RUN_DIR|CHECKPOINT",
                        help="start the world model and policy (with the normalisers they were trained with) from "
                             "another SuperTrack run's newest checkpoint, or from a checkpoint file; optimisers, "
                             "buffer, gym and counters start fresh: fine-tuning, e.g. a walk run as the start for "
                             "run. The network sizes must match. Recorded in run_info.json; not with "
                             "--resume")  # fmt: skip


def _read_init(path: str) -> tuple[Path, dict[str, Any]]:
    """The ``--init-from`` checkpoint and its contents; exits naming the file if it is not a SuperTrack checkpoint."""
    try:
        source, state = read_checkpoint(path)
    except CheckpointError as e:
        sys.exit(f"error: --init-from {e}")
    meta = state.get("meta") if isinstance(state, dict) else None
    if not isinstance(meta, dict) or meta.get("learner") != "supertrack" or "learner" not in state:
        learner = meta.get("learner") if isinstance(meta, dict) else None
        sys.exit(f"error: --init-from {source}: not a SuperTrack checkpoint (learner: {learner!r})")
    return source, state


def _check_init_fits(source: Path, state: dict[str, Any], cfg: SuperTrackConfig, humanoid: Humanoid) -> None:
    """The ``--init-from`` networks fit this run: same character and network sizes (ValueError naming both)."""
    meta = state["meta"]
    if list(meta.get("bodies", [])) != list(humanoid.body_names):
        raise ValueError(f"--init-from {source}: another character (bodies {meta.get('bodies')})")
    here, before = to_dict(cfg), {"terrain": to_dict(TerrainConfig())}  # runs from before a section: its defaults
    for section, key in (("world_model", "hidden"), ("policy", "hidden"), ("policy", "root_offset"),
                         *(("terrain", k) for k in ("heightmap_extent", "heightmap_spacing", "contact_weight",
                                                    "contact_frames"))):  # fmt: skip
        theirs = meta.get("config", {}).get(section, before.get(section, {})).get(key)
        # W's contact output exists or not: its weight's value does not size anything.
        same = bool(theirs) == bool(here[section][key]) if key == "contact_weight" else theirs == here[section][key]
        if not same:
            raise ValueError(f"--init-from {source}: {section}.{key} is {theirs} there and {here[section][key]} here; "
                             "the networks must have the same sizes")  # fmt: skip


def _prepare(args: argparse.Namespace) -> tuple[Path, dict[str, Any]] | None:
    """The ``--init-from`` checkpoint, read before anything is written."""
    if args.init_from is None:
        return None
    if args.resume:
        sys.exit("error: --init-from starts a new run from another run's networks; --resume continues this run's "
                 "own checkpoint: use one or the other")  # fmt: skip
    return _read_init(args.init_from)


def _check(cfg: SuperTrackConfig, humanoid: Humanoid, library: MotionLibrary,
           init: tuple[Path, dict[str, Any]] | None) -> None:  # fmt: skip
    """What only the model and motions can validate, before the run directory is made."""
    clip_weights(cfg, library)
    if init is not None:
        _check_init_fits(*init, cfg, humanoid)


def _info(init: tuple[Path, dict[str, Any]] | None) -> dict[str, Any]:
    return {} if init is None else {"init_from": str(init[0]), "init_iteration": init[1].get("iteration")}


def _make_learner(cfg: SuperTrackConfig, humanoid: Humanoid, library: MotionLibrary, rng: np.random.Generator,
                  init: tuple[Path, dict[str, Any]] | None, world: World) -> SuperTrackLearner:  # fmt: skip
    learner = SuperTrackLearner(cfg, humanoid, library, rng, world)
    if init is not None:
        try:
            learner.init_networks(init[1]["learner"])
        except BaseException:
            learner.close()
            raise
        print(f"networks from {init[0]} (iteration {init[1].get('iteration')}, {init[1].get('samples')} samples)")
    return learner


COMMAND = TrainingCommand(
    name="supertrack", prog="train-supertrack", config_cls=SuperTrackConfig, description=DESCRIPTION,
    examples=EXAMPLES, make_learner=_make_learner, add_arguments=add_arguments, prepare=_prepare, check=_check,
    info=_info, user_errors=(CollectorError,),
)  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    """The command's argument parser (for ``--help`` and tests)."""
    return COMMAND.parser()


def run(argv: Sequence[str] | None = None) -> EvalResult | None:
    """Parses ``argv``, trains to the configured budget and returns the final evaluation (None on a data-parallel
    run's ranks other than 0)."""
    return train_main(COMMAND, argv)


def main(argv: Sequence[str] | None = None) -> None:
    run(argv)


if __name__ == "__main__":
    main()
