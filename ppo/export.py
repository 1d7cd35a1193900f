"""Rebuilds the PPO tracker's deterministic policy from a run's checkpoint, for the comparison report.

Acting needs the actor network and the frozen observation normaliser only; the critic, optimiser, clip weights and
training gym are not rebuilt. The policy is the one :meth:`ppo.learner.PPOLearner.policy` returns: PD targets =
next reference hinge angles + action_scale * clip(mean action).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import Policy
from common.motion.library import MotionLibrary
from common.run.directory import load_run_checkpoint
from common.sim.gym import StepResult
from common.sim.observation import Observer
from ppo.config import PPOTrackerConfig
from ppo.networks import ActorCritic
from ppo.normalizer import RunningNormalizer


def load_eval_policy(run_dir: Path, checkpoint: Path, humanoid: Humanoid, library: MotionLibrary) -> Policy:
    """The deterministic PPO policy stored in ``checkpoint``.

    Args:
        run_dir: The run directory (its ``config.yaml`` gives the network and normaliser settings).
        checkpoint: A checkpoint written by the trainer.
        humanoid: The model.
        library: The motions to evaluate on (the observation reads their future reference frames).

    Returns:
        A callable from the gym's StepResult to hinge PD targets (N, nu).

    Raises:
        ValueError: If the checkpoint holds no PPO policy or does not fit the config.
    """
    cfg, learner = load_run_checkpoint(PPOTrackerConfig, run_dir, checkpoint, "sizes", "normalizer", "net")
    sizes, norm_state = learner["sizes"], learner["normalizer"]
    if sizes["action"] != humanoid.nu:
        raise ValueError(f"{checkpoint}: {sizes['action']} actions, the model has {humanoid.nu} actuators")
    n = cfg.normalizer
    # The mask is stored with the statistics, so the observation layout needs no gym to recompute it.
    normalizer = RunningNormalizer(np.asarray(norm_state["mask"], dtype=bool), n.clip, n.epsilon, n.max_samples)
    normalizer.load_state_dict(norm_state)
    net = ActorCritic(sizes["obs"], sizes["action"], cfg.network)
    try:
        net.load_state_dict(learner["net"])
    except RuntimeError as e:
        raise ValueError(f"{checkpoint}: network weights do not match {run_dir}/config.yaml: {e}") from e
    actor = net.actor.eval()
    hinge_qpos = humanoid.hinge_qpos
    scale, clip = cfg.network.action_scale, cfg.network.action_clip
    observe = Observer(cfg.observation, humanoid, library)

    def act(result: StepResult) -> np.ndarray:
        obs = observe(result)
        if obs.shape[-1] != sizes["obs"]:
            # e.g. a run from before the parc observation: its config.yaml has no observation section
            raise ValueError(
                f"{run_dir}/config.yaml: the '{cfg.observation.kind}' observation has {obs.shape[-1]} features, the "
                f"policy in {checkpoint} reads {sizes['obs']} (a run with the previous observation needs "
                f"'observation: {{kind: local}}' in its config.yaml)"
            )
        norm_obs = normalizer.normalize(obs)
        with torch.no_grad():
            mean = actor(torch.as_tensor(norm_obs)).double().numpy()
        if clip is not None:
            mean = np.clip(mean, -clip, clip)
        return result.ref_next.qpos[:, hinge_qpos] + scale * mean

    return act
