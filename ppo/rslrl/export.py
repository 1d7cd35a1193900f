"""Rebuilds the deterministic policy of a ``train-rsl-rl`` run from a checkpoint, for the report, ``watch-policy`` and
``export-policy`` (registered in :mod:`report.learners`).

Acting needs rsl_rl's actor only (its empirical observation normaliser, MLP and the Gaussian's mean): PD targets =
the reference's hinge angles one frame ahead + scale * clip(mean action), as :meth:`ppo.rslrl.learner.RslRlLearner.
policy` acts. The actor is rebuilt with rsl_rl's own ``MLPModel`` from the run's config, so reading a run needs
rsl-rl-lib (a ValueError says how to install it).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import Policy
from common.motion.library import MotionLibrary
from common.run.directory import load_run_checkpoint
from common.sim.observation import Observer
from ppo.config import NetworkConfig
from ppo.export import feature_layout, onnx_spec
from ppo.rslrl import INSTALL_HINT
from ppo.rslrl.config import OBS_GROUP, RslRlConfig, runner_config


def load_actor(run_dir: Path, checkpoint: Path, humanoid: Humanoid) -> tuple[RslRlConfig, nn.Module, int]:
    """The run's config, the deterministic actor of ``checkpoint`` (rsl_rl's ``as_jit()`` copy: flat observation
    (B, D) -> mean action (B, A), eval mode) and the observation width D.

    Raises:
        ValueError: If rsl-rl-lib is not installed, the checkpoint holds no rsl_rl policy, or it does not fit the
            config or the model.
    """
    try:
        from rsl_rl.utils import resolve_class
        from tensordict import TensorDict
    except ModuleNotFoundError:
        raise ValueError(f"{run_dir}: {INSTALL_HINT}") from None
    cfg, learner = load_run_checkpoint(RslRlConfig, run_dir, checkpoint, "sizes", "actor")
    sizes = learner["sizes"]
    if sizes["action"] != humanoid.nu:
        raise ValueError(f"{checkpoint}: {sizes['action']} actions, the model has {humanoid.nu} actuators")
    model_class, model_cfg = resolve_class(runner_config(cfg)["actor"])
    obs = TensorDict({OBS_GROUP: torch.zeros(1, sizes["obs"])}, batch_size=[1])
    actor = model_class(obs, {"actor": [OBS_GROUP]}, "actor", sizes["action"], **model_cfg)
    try:
        actor.load_state_dict(learner["actor"])
    except RuntimeError as e:
        raise ValueError(f"{checkpoint}: actor weights do not match {run_dir}/config.yaml: {e}") from e
    return cfg, actor.as_jit().eval(), int(sizes["obs"])


def _targets(cfg: RslRlConfig) -> NetworkConfig:
    """The action scale and clip as :func:`ppo.actor.pd_targets` reads them."""
    return NetworkConfig(action_scale=cfg.actions.scale, action_clip=cfg.actions.clip)


def load_eval_policy(run_dir: Path, checkpoint: Path, humanoid: Humanoid, library: MotionLibrary) -> Policy:
    """The deterministic rsl_rl policy stored in ``checkpoint``.

    Args:
        run_dir: The run directory (its ``config.yaml`` gives the networks, observation and action settings).
        checkpoint: A checkpoint written by the trainer.
        humanoid: The model.
        library: The motions to evaluate on (the observation reads their future reference frames).

    Returns:
        A callable from the gym's StepResult to hinge PD targets (N, nu).

    Raises:
        ValueError: As :func:`load_actor`.
    """
    from ppo.rslrl.learner import actor_policy  # needs rsl_rl, which load_actor has checked

    cfg, actor, _ = load_actor(run_dir, checkpoint, humanoid)
    return actor_policy(actor, Observer(cfg.observation, humanoid, library), humanoid, _targets(cfg))


class OnnxPolicy(nn.Module):
    """The deterministic policy as one float32 graph: observation -> action mean and PD targets.

    rsl_rl's actor copy (its normaliser (x - mean) / (std + eps) and MLP) gives the mean action; then the action
    clip and the targets of :func:`load_eval_policy`. Inputs and outputs as :class:`ppo.export.OnnxPolicy`'s.

    Args:
        actor: Flat observation (B, D) -> mean action (B, A).
        action_scale: Radians of PD-target offset per action unit.
        action_clip: Bound of the action (None: unclipped).
    """

    def __init__(self, actor: nn.Module, action_scale: float, action_clip: float | None) -> None:
        super().__init__()
        self.actor, self.action_scale, self.action_clip = actor, action_scale, action_clip

    def forward(self, observation: Tensor, ref_next_hinges: Tensor) -> tuple[Tensor, Tensor]:
        action = self.actor(observation)
        if self.action_clip is not None:
            action = action.clamp(-self.action_clip, self.action_clip)
        return action, ref_next_hinges + self.action_scale * action


def onnx_module(run_dir: Path, checkpoint: Path, humanoid: Humanoid) -> tuple[nn.Module, dict[str, Any]]:
    """The run's deterministic policy for ONNX export (:class:`OnnxPolicy`) and the sidecar's description of its
    inputs and outputs (:func:`ppo.export.onnx_spec`; every feature is normalised inside the graph when
    ``actor.obs_normalization`` is on).

    Raises:
        ValueError: As :func:`load_actor`, and if the run's observation does not have the policy's width.
    """
    cfg, actor, size = load_actor(run_dir, checkpoint, humanoid)
    features = feature_layout(cfg.observation, humanoid, np.full(size, cfg.actor.obs_normalization))
    width = sum(f["width"] for f in features)
    if width != size:
        raise ValueError(f"{run_dir}/config.yaml: the '{cfg.observation.kind}' observation has {width} features, "
                         f"the policy in {checkpoint} reads {size}")  # fmt: skip
    spec = onnx_spec(cfg.observation, humanoid, features, cfg.actions.scale, cfg.actions.clip)
    return OnnxPolicy(actor, cfg.actions.scale, cfg.actions.clip).eval(), spec
