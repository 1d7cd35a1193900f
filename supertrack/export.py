"""Rebuilds SuperTrack's deterministic policy from a run's checkpoint, for the comparison report.

Only the policy network (with its Local() normaliser, stored as module buffers in the checkpoint) and the actor's
offset scale are needed to act: the world model, optimisers, buffers and the training gym are not rebuilt.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import Policy as EvalPolicy
from common.motion.library import MotionLibrary
from common.run.directory import load_run_checkpoint
from supertrack.actor import Actor
from supertrack.config import SuperTrackConfig
from supertrack.models import Policy
from supertrack.normalizer import Normalizer


def load_eval_policy(run_dir: Path, checkpoint: Path, humanoid: Humanoid, library: MotionLibrary,
                     average: bool | None = None) -> EvalPolicy:  # fmt: skip
    """The deterministic SuperTrack policy stored in ``checkpoint``: the one the trainer evaluated.

    Args:
        run_dir: The run directory (its ``config.yaml`` gives the network sizes and alpha).
        checkpoint: A checkpoint written by the trainer.
        humanoid: The model.
        library: The motions to evaluate on (unused: the normaliser comes from the checkpoint, not from the
            evaluation motions, so the policy sees exactly the features it was trained on).
        average: Which weights: the averaged ones (``policy.average_decay`` > 0), the live ones (False), or
            None: the averaged ones when the run kept an average (what its trainer evaluated), else the live ones.

    Returns:
        A callable from the gym's StepResult to hinge PD targets (N, nu).

    Raises:
        ValueError: If the checkpoint holds no SuperTrack policy (or no averaged one when ``average`` is True) or
            does not fit the config.
    """
    del library
    cfg, learner = load_run_checkpoint(SuperTrackConfig, run_dir, checkpoint, "policy")
    if average is None:
        average = "policy_average" in learner
    if average and "policy_average" not in learner:
        raise ValueError(f"{checkpoint}: no averaged policy in this checkpoint (its run had policy.average_decay 0)")
    weights = learner["policy_average"]["module"] if average else learner["policy"]
    # Placeholder statistics of the right size; load_state_dict overwrites them with the trained ones.
    size = int(weights["local_norm.mean"].shape[0])
    norm = Normalizer(np.zeros(size), np.ones(size))
    net = Policy(len(humanoid.joint_groups), cfg.policy.hidden, norm, cfg.policy.init_scale,
                 root_offset=cfg.policy.root_offset,
                 revolute=torch.tensor([g.kind == "revolute" for g in humanoid.joint_groups]))  # fmt: skip
    if size != 16 * humanoid.num_bodies + 3:
        # Local() is 16 values per body plus 3 (see supertrack.state.BodyState.local): another size, another model.
        raise ValueError(f"{checkpoint}: policy input size {size} does not fit a {humanoid.num_bodies}-body model")
    try:
        net.load_state_dict(weights)
    except RuntimeError as e:
        raise ValueError(f"{checkpoint}: policy weights do not match {run_dir}/config.yaml: {e}") from e
    net.eval()
    return Actor(humanoid, net, cfg.policy.alpha).deterministic
