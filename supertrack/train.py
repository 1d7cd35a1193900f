"""``train-supertrack``: train SuperTrack (world model + policy through it) on motion clips.

Example::

    train-supertrack --config configs/supertrack/default.yaml --motions walk --out runs/st-walk
    train-supertrack --out runs/st-walk --resume --max-minutes 120   # continue the same run
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
from common.train.training import Trainer, add_common_arguments, compat_meta, setup
from supertrack.config import SuperTrackConfig
from supertrack.learner import SuperTrackLearner, clip_weights

DEFAULT_CONFIG = "configs/supertrack/default.yaml"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="train-supertrack",
        description=(
            "Train a SuperTrack tracker (Fussell et al. 2021): a world model learns the simulator from the gym's "
            "frames and the policy learns by back-propagating a tracking loss through it. Writes config.yaml, "
            "metrics.jsonl, TensorBoard events and checkpoints into the run directory and evaluates periodically "
            "with the shared evaluator (eval/...); world-model accuracy is logged as world_model/..."
        ),
        epilog=(
            "Config sections (configs/supertrack/*.yaml; any key can be overridden with --set section.key=value): "
            "train (budget, seed, device, logging, eval), gym (characters, physics, termination), world_model and "
            "policy (network sizes, batch, window, learning rate, loss weights; policy also sigma and alpha_deg), "
            "buffer (capacity, held-back characters), collect (gym steps per iteration, warm-up, clip_weights: e.g. "
            "--set 'collect.clip_weights={walk: 10}' oversamples walk), diagnostics "
            "(world-model error horizons). Presets: paper.yaml (the paper's sizes, for a GPU), default.yaml "
            "(a 2-core CPU), debug.yaml (tests)."
        ),
    )
    add_common_arguments(parser, DEFAULT_CONFIG)
    parser.add_argument("--init-from", default=None, metavar="RUN_DIR|CHECKPOINT",
                        help="start the world model and policy (with the normalisers they were trained with) from "
                             "another SuperTrack run's newest checkpoint, or from a checkpoint file; optimisers, "
                             "buffer, gym and counters start fresh: fine-tuning, e.g. a walk run as the start for "
                             "run. The network sizes must match. Recorded in run_info.json; not with "
                             "--resume")  # fmt: skip
    return parser


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
    here = to_dict(cfg)
    for section, key in (("world_model", "hidden"), ("policy", "hidden"), ("policy", "root_offset")):
        theirs = meta.get("config", {}).get(section, {}).get(key)
        if theirs != here[section][key]:
            raise ValueError(f"--init-from {source}: {section}.{key} is {theirs} there and {here[section][key]} here; "
                             "the networks must have the same sizes")  # fmt: skip


def run(argv: Sequence[str] | None = None) -> EvalResult:
    """Parses ``argv``, trains to the configured budget and returns the final evaluation."""
    args = build_parser().parse_args(argv)
    init = None
    if args.init_from is not None:
        if args.resume:
            sys.exit("error: --init-from starts a new run from another run's networks; --resume continues this run's "
                     "own checkpoint: use one or the other")  # fmt: skip
        init = _read_init(args.init_from)

    def check(cfg: SuperTrackConfig, humanoid: Humanoid, library: MotionLibrary) -> None:
        """What only the model and motions can validate, before the run directory is made."""
        clip_weights(cfg, library)
        if init is not None:
            _check_init_fits(*init, cfg, humanoid)

    extra = {} if init is None else {"init_from": str(init[0]), "init_iteration": init[1].get("iteration")}
    cfg, run_dir, humanoid, library = setup(SuperTrackConfig, args, "supertrack", check=check, info=extra)
    rng = np.random.default_rng(cfg.train.seed)
    try:
        learner = SuperTrackLearner(cfg, humanoid, library, rng)
    except CollectorError as e:
        sys.exit(f"error: {e}")
    try:
        if init is not None:
            learner.init_networks(init[1]["learner"])
            print(f"networks from {init[0]} (iteration {init[1].get('iteration')}, {init[1].get('samples')} samples)")
        trainer = Trainer(learner, cfg.train, run_dir, library, humanoid, compat_meta(cfg, humanoid, "supertrack"),
                          "supertrack", rng)  # fmt: skip
        if args.resume:
            try:
                trainer.resume()
            except ValueError as e:
                sys.exit(f"error: {e}")
        result = trainer.run()
    except CollectorError as e:  # the worker's traceback is in the message; the last checkpoint is intact
        sys.exit(f"error: {e}")
    finally:
        learner.close()
    print(result.table())
    return result


def main(argv: Sequence[str] | None = None) -> None:
    run(argv)


if __name__ == "__main__":
    main()
