"""A SAMCON run's policies for the comparison report (``compare-trackers``), read from its ``samcon.h5``.

``load_eval_policy`` gives the feedback policy (judged under the standard protocol like the learners): the
time-varying LQR of the clips the run stabilised (``lqr.enabled``), the regressed linear feedback of the others;
``load_oracle`` gives the open-loop trajectories (judged from each clip's start) and the minutes each clip took.
"""

from __future__ import annotations

from pathlib import Path

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import Policy
from common.motion.library import MotionLibrary
from samcon import store
from samcon.feedback import open_loop_policy
from samcon.lqr import evaluation_policy


def load_eval_policy(run_dir: Path, checkpoint: Path, humanoid: Humanoid, library: MotionLibrary) -> Policy:
    """The time-indexed feedback policy of every clip the run tracked (others: the reference's angles)."""
    del run_dir
    plans, _ = store.load_plans(checkpoint, humanoid.physics.control_hz)
    return evaluation_policy(plans, library, humanoid)


def load_oracle(run_dir: Path, checkpoint: Path, humanoid: Humanoid,
                library: MotionLibrary) -> tuple[Policy, dict[str, float]]:  # fmt: skip
    """The open-loop trajectories as a policy for episodes starting at t = 0, and {clip: minutes of search}."""
    del run_dir
    plans, info = store.load_plans(checkpoint, humanoid.physics.control_hz)
    return open_loop_policy(plans, library, humanoid), {k: v["seconds"] / 60.0 for k, v in info.items()}
