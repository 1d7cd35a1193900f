"""``train-supertrack``: train SuperTrack (world model + policy through it) on motion clips.

Example::

    train-supertrack --config configs/supertrack/default.yaml --motions walk --out runs/st-walk
    train-supertrack --out runs/st-walk --resume --max-minutes 120   # continue the same run
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

import numpy as np

from common.evaluate import EvalResult
from common.motion_library import MotionLibrary
from common.training import Trainer, add_common_arguments, compat_meta, setup
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
    return parser


def check_motions(cfg: SuperTrackConfig, library: MotionLibrary) -> None:
    """The settings only the motions can validate (raises ValueError naming the key)."""
    clip_weights(cfg, library)


def run(argv: Sequence[str] | None = None) -> EvalResult:
    """Parses ``argv``, trains to the configured budget and returns the final evaluation."""
    args = build_parser().parse_args(argv)
    cfg, run_dir, humanoid, library = setup(SuperTrackConfig, args, "supertrack", check=check_motions)
    rng = np.random.default_rng(cfg.train.seed)
    learner = SuperTrackLearner(cfg, humanoid, library, rng)
    try:
        trainer = Trainer(learner, cfg.train, run_dir, library, humanoid, compat_meta(cfg, humanoid, "supertrack"),
                          "supertrack", rng)  # fmt: skip
        if args.resume:
            try:
                trainer.resume()
            except ValueError as e:
                sys.exit(f"error: {e}")
        result = trainer.run()
    finally:
        learner.close()
    print(result.table())
    return result


def main(argv: Sequence[str] | None = None) -> None:
    run(argv)


if __name__ == "__main__":
    main()
