"""The learner registry: every method the project trains or judges, in the one table every command reads.

A learner is added here and nowhere else: ``compare-trackers``, ``watch-policy`` and ``export-policy`` find its
evaluation policy through :attr:`LearnerSpec.export`, ``python -m report.bundle_policy`` cuts its checkpoints to
:attr:`LearnerSpec.policy_keys`, and ``benchmarks/compare_trackers.py`` trains it with :attr:`LearnerSpec.train` and
the bundled configs of :attr:`LearnerSpec.configs`. A name read from a run directory (``run_info.json``'s
``learner``) is looked up here and nowhere else, so a run directory cannot choose what is imported. Nothing here
imports a learner: reading the table is free.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass


@dataclass(frozen=True)
class LearnerSpec:
    """One learner as the commands see it.

    Attributes:
        name: The name run directories and checkpoints carry (``run_info.json``'s ``learner``, the training command's
            :attr:`common.train.command.TrainingCommand.name`).
        display: The name in messages and reports (``SuperTrack``).
        export: The module whose ``load_eval_policy(run_dir, checkpoint, humanoid, library)`` rebuilds the run's
            deterministic policy (and, for a network policy, ``onnx_module(run_dir, checkpoint, humanoid)``).
        policy_keys: The entries of a checkpoint's learner state that ``load_eval_policy`` reads: what a bundled
            policy keeps (``pretrained/``); empty: no network policy to bundle.
        train: The module ``python -m`` runs to train it with the shared training options (``--config``, ``--out``,
            ``--seed``, ``--max-minutes``, ``--motions``, ``--set``); None: the suite does not train it.
        command: The console script that trains (or runs) it.
        configs: Its bundled config folder, ``configs/<configs>``.
        suite_default: Trained by ``benchmarks/compare_trackers.py`` when ``--learners`` is not given.
        extra: The optional dependencies (``pip install -e ".[extra]"``) its export module needs, as (extra, its
            top-level modules); a command reading such a run without them says so in one line.
    """

    name: str
    display: str
    export: str
    policy_keys: tuple[str, ...] = ()
    train: str | None = None
    command: str | None = None
    configs: str | None = None
    suite_default: bool = False
    extra: tuple[str, tuple[str, ...]] | None = None


LEARNERS: dict[str, LearnerSpec] = {spec.name: spec for spec in (
    LearnerSpec("supertrack", "SuperTrack", "supertrack.export", ("policy", "policy_average"), "supertrack.train",
                "train-supertrack", "supertrack", suite_default=True),
    LearnerSpec("ppo", "PPO", "ppo.export", ("sizes", "normalizer", "net"), "ppo.train", "train-ppo", "ppo",
                suite_default=True),
    # rsl_rl's PPO (rsl-rl-lib, an optional extra) on the shared gym: docs/rsl-rl.md.
    LearnerSpec("rsl_rl", "rsl_rl PPO", "ppo.rslrl.export", ("sizes", "actor"), "ppo.rslrl.train", "train-rsl-rl",
                "rsl_rl", extra=("rsl_rl", ("rsl_rl", "tensordict"))),
    # A search, not a trained network: its run directory names its policy file (run_info.json's policy_file).
    LearnerSpec("samcon", "SAMCON", "samcon.export", command="track-samcon", configs="samcon"),
)}  # fmt: skip


def known() -> str:
    """The registered names, for messages: ``supertrack, ppo, ...``."""
    return ", ".join(LEARNERS)


def trainable() -> list[str]:
    """The learners the suite can train (those with a :attr:`LearnerSpec.train` module), in registry order."""
    return [name for name, spec in LEARNERS.items() if spec.train is not None]


def missing_extra(name: str) -> str | None:
    """What a registered learner's export module lacks, as one line (``rsl_rl PPO runs need rsl_rl: pip install -e
    ".[rsl_rl]"``); None when its optional dependencies are installed (or it has none)."""
    spec = LEARNERS[name]
    if spec.extra is None:
        return None
    extra, modules = spec.extra
    missing = [m for m in modules if not _installed(m)]
    if not missing:
        return None
    return f'{spec.display} runs need {", ".join(missing)}: pip install -e ".[{extra}]"'


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ValueError:  # a module set to None in sys.modules (blocked), or without a spec
        return False
