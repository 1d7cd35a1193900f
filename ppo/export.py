"""Rebuilds the PPO tracker's deterministic policy from a run's checkpoint, for the comparison report.

Acting needs the actor network and the frozen observation normaliser only; the critic, optimiser, clip weights and
training gym are not rebuilt. The policy is the one :meth:`ppo.learner.PPOLearner.policy` returns: PD targets =
next reference hinge angles + action_scale * clip(mean action).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch
from torch import Tensor, nn

from common.character.humanoid import Humanoid
from common.character.state import CharacterState
from common.evaluation.evaluate import Policy
from common.motion.library import MotionLibrary
from common.run.directory import load_run_checkpoint
from common.sim.features import OBSERVATION_KEYS, tracking_observation
from common.sim.gym import StepResult
from common.sim.observation import ObservationConfig, Observer, parc_features, terrain_feature_widths
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
    cfg, actor, normalizer = load_actor(run_dir, checkpoint, humanoid)
    obs_size = normalizer.mean.shape[0]
    hinge_qpos = humanoid.hinge_qpos
    scale, clip = cfg.network.action_scale, cfg.network.action_clip
    observe = Observer(cfg.observation, humanoid, library)

    def act(result: StepResult) -> np.ndarray:
        obs = observe(result)
        if obs.shape[-1] != obs_size:
            # e.g. a run from before the parc observation: its config.yaml has no observation section
            raise ValueError(
                f"{run_dir}/config.yaml: the '{cfg.observation.kind}' observation has {obs.shape[-1]} features, the "
                f"policy in {checkpoint} reads {obs_size} (a run with the previous observation needs "
                f"'observation: {{kind: local}}' in its config.yaml)"
            )
        norm_obs = normalizer.normalize(obs)
        with torch.no_grad():
            mean = actor(torch.as_tensor(norm_obs)).double().numpy()
        if clip is not None:
            mean = np.clip(mean, -clip, clip)
        return result.ref_next.qpos[:, hinge_qpos] + scale * mean

    return act


def load_actor(run_dir: Path, checkpoint: Path,
               humanoid: Humanoid) -> tuple[PPOTrackerConfig, nn.Sequential, RunningNormalizer]:  # fmt: skip
    """The run's config, the policy-mean network of ``checkpoint`` (eval mode) and its frozen observation normaliser:
    what :func:`load_eval_policy` acts with. Arguments and errors as there."""
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
    return cfg, net.actor.eval(), normalizer


class OnnxPolicy(nn.Module):
    """The deterministic policy as one float32 graph: observation -> action mean and PD targets.

    The frozen observation normaliser is folded in (clip((x - mean) / max(std, epsilon), -clip, clip) on the
    normalised entries, the others passed through), then the actor MLP, the action clip and the targets of
    :func:`load_eval_policy`. The observation itself (:mod:`common.sim.observation`) reads future reference frames of
    the clip, so it stays with the caller.

    Inputs (B characters):
        observation: The run's observation (``observation.kind``; layout in the sidecar). Shape: (B, D).
        ref_next_hinges: The reference's hinge angles one control step ahead, actuator order (rad). Shape: (B, A).

    Outputs:
        action: The policy mean, clipped to [-action_clip, action_clip] (action units). Shape: (B, A).
        pd_targets: PD target angles ref_next_hinges + action_scale * action, actuator order (rad). Shape: (B, A).

    Args:
        actor: The policy-mean network, normalised observation (B, D) -> (B, A).
        normalizer: The frozen observation normaliser.
        action_scale: Radians of PD-target offset per action unit.
        action_clip: Bound of the action (None: unclipped).
    """

    def __init__(self, actor: nn.Module, normalizer: RunningNormalizer, action_scale: float,
                 action_clip: float | None) -> None:  # fmt: skip
        super().__init__()
        self.actor, self.action_scale, self.action_clip = actor, action_scale, action_clip
        self.obs_clip = normalizer.clip
        self.register_buffer("obs_mean", torch.as_tensor(normalizer.mean, dtype=torch.float32))
        self.register_buffer("obs_std", torch.as_tensor(np.maximum(normalizer.std, normalizer.epsilon),
                                                        dtype=torch.float32))  # fmt: skip
        self.register_buffer("obs_mask", torch.as_tensor(normalizer.mask))

    def forward(self, observation: Tensor, ref_next_hinges: Tensor) -> tuple[Tensor, Tensor]:
        scaled = ((observation - self.obs_mean) / self.obs_std).clamp(-self.obs_clip, self.obs_clip)
        action = self.actor(torch.where(self.obs_mask, scaled, observation))
        if self.action_clip is not None:
            action = action.clamp(-self.action_clip, self.action_clip)
        return action, ref_next_hinges + self.action_scale * action


def observation_layout(config: ObservationConfig, humanoid: Humanoid) -> dict[str, int]:
    """{feature name: width} of the flat observation, in order (measured on a rest pose: no gym or clips needed)."""
    nb = humanoid.num_bodies
    rest = CharacterState(qpos=np.zeros((1, humanoid.model.nq)), qvel=np.zeros((1, humanoid.model.nv)),
                          body_pos=np.zeros((1, nb, 3)), body_rot=np.tile([1.0, 0.0, 0.0, 0.0], (1, nb, 1)),
                          body_linvel=np.zeros((1, nb, 3)), body_angvel=np.zeros((1, nb, 3)))  # fmt: skip
    if config.kind == "local":
        named = tracking_observation(rest, rest, np.zeros(1))
        named = {k: named[k] for k in OBSERVATION_KEYS}
    else:
        named = parc_features(rest, dict.fromkeys(config.future_frames, rest), humanoid.hinge_qpos, humanoid.hinge_dof)
    return {name: value.shape[-1] for name, value in named.items()} | terrain_feature_widths(config, nb)


def onnx_module(run_dir: Path, checkpoint: Path, humanoid: Humanoid) -> tuple[nn.Module, dict[str, Any]]:
    """The run's deterministic policy for ONNX export (:class:`OnnxPolicy`) and the description of its inputs and
    outputs for the sidecar file.

    Returns:
        The module (float32, eval mode) and {"inputs": [...], "outputs": [...], "policy": {...}}: per tensor its
        name, shape ("batch" first), meaning and, where it has one, the layout of its last axis.

    Raises:
        ValueError: As :func:`load_eval_policy`, and if the run's observation does not have the policy's width.
    """
    cfg, actor, normalizer = load_actor(run_dir, checkpoint, humanoid)
    features = feature_layout(cfg.observation, humanoid, normalizer.mask)
    width = sum(f["width"] for f in features)
    if width != normalizer.size:
        raise ValueError(f"{run_dir}/config.yaml: the '{cfg.observation.kind}' observation has {width} features, "
                         f"the policy in {checkpoint} reads {normalizer.size}")  # fmt: skip
    spec = onnx_spec(cfg.observation, humanoid, features, cfg.network.action_scale, cfg.network.action_clip)
    return OnnxPolicy(actor, normalizer, cfg.network.action_scale, cfg.network.action_clip).eval(), spec


def feature_layout(config: ObservationConfig, humanoid: Humanoid, normalised: np.ndarray) -> list[dict[str, Any]]:
    """The flat observation's features in order, each {"name", "width", "normalised"}.

    Args:
        config: The run's observation.
        humanoid: The model.
        normalised: Whether each entry of the flat observation is normalised. Shape: (D,); a feature counts as
            normalised when all its entries are (entries past D: not).
    """
    start, features = 0, []
    for name, width in observation_layout(config, humanoid).items():
        entries = np.asarray(normalised[start : start + width], dtype=bool)
        features.append({"name": name, "width": width, "normalised": bool(len(entries) == width and entries.all())})
        start += width
    return features


def onnx_spec(config: ObservationConfig, humanoid: Humanoid, features: list[dict[str, Any]], action_scale: float,
              action_clip: float | None) -> dict[str, Any]:  # fmt: skip
    """The sidecar's description of a PPO-style ONNX policy (observation and next reference hinges -> the clipped
    action mean and PD targets): per tensor its name, shape ("batch" first), meaning and, where it has one, the layout
    of its last axis; and the policy's action scale, clip, observation and control rate.

    Args:
        config: The run's observation.
        humanoid: The model.
        features: :func:`feature_layout` of the observation.
        action_scale: Radians of PD-target offset per action unit.
        action_clip: Bound of the action (None: unclipped).
    """
    size = sum(f["width"] for f in features)
    actuators = [mujoco.mj_id2name(humanoid.model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(humanoid.nu)]
    return {
        "inputs": [
            {"name": "observation", "shape": ["batch", size], "layout": {"features": features},
             "meaning": f"the '{config.kind}' tracking observation of common.sim.observation, unnormalised "
                        f"(future frames {list(config.future_frames)} control steps ahead)"},
            {"name": "ref_next_hinges", "shape": ["batch", humanoid.nu], "layout": {"actuators": actuators},
             "meaning": "the reference's hinge angles one control step ahead (rad)"},
        ],
        "outputs": [
            {"name": "action", "shape": ["batch", humanoid.nu], "layout": {"actuators": actuators},
             "meaning": f"the policy mean, clipped to +-{action_clip} (action units)"},
            {"name": "pd_targets", "shape": ["batch", humanoid.nu], "layout": {"actuators": actuators},
             "meaning": f"PD target angles ref_next_hinges + {action_scale} * action (rad)"},
        ],
        "policy": {"action_scale_rad": action_scale, "action_clip": action_clip, "observation": config.kind,
                   "control_hz": humanoid.physics.control_hz},
    }  # fmt: skip
