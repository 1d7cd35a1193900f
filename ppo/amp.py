"""An adversarial motion prior for PPO (Peng et al. 2021): a discriminator over state transitions, its losses, its
reward, and :class:`AMP`, which trains it beside the PPO update.

The discriminator (rsl_rl's AMPNet) is an MLP over a transition [s, s'] (the normalised features of
:mod:`ppo.amp_data`, one normaliser for both halves and both sides) to one raw score x; its output activation is tanh
(score tanh(x) in [-1, 1], hinge loss) or sigmoid (score sigmoid(x) in [0, 1], binary cross-entropy on the logit x).
With label smoothing ls the expert label is 1 - ls and the policy's -1 + ls (tanh) or ls (sigmoid).

Losses (B transitions per side, means over the batch):
- expert / policy: hinge mean max(0, 1 - tanh(x) y), or BCE -mean(y log sigmoid(x) + (1 - y) log(1 - sigmoid(x)));
- gradient penalty on expert inputs: GP = mean_b ||d x_b / d input_b||^2 (the raw score's gradient, towards 0, as
  rsl_rl and MimicKit do);
- MimicKit's logit regularisation ||W_out||^2 and weight decay sum_l ||W_l||^2 (added to the loss, as there);
- L = 0.5 (L_expert + L_policy) + lambda_gp GP + logit_reg ||W_out||^2 + weight_decay sum_l ||W_l||^2. The issue names
  the terms without their sum; 0.5 on the classification terms is what both anchors do (rsl_rl's AMP_for_hardware
  lineage and MimicKit's amp_agent), so that the weights of their configs mean the same here.

Reward of a policy transition (no gradient):
- ``rsl_rl`` (the saturated cross-entropy): r = max(-log(max(e - score - ls, epsilon)) - reward_shift, reward_min),
  e = 1 the expert's score, "predicted_score" the activated score tanh(x) or sigmoid(x) (rsl_rl's
  ``amp_reward`` applies the activation before the formula), epsilon 1e-4, shift 0.45, min -0.1. With tanh, r > -0.1
  only once tanh(x) > 1 - exp(-0.35) = 0.295 (towards the expert side), and at most -log(1e-4) - 0.45 = 8.76.
- ``mimickit``: r = -log(max(1 - sigmoid(x), 1e-4)) * reward_scale (scale 2).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from common.motion.library import MotionLibrary
from common.train.training import NanGuard
from ppo.amp_data import AMPFeatures, ExpertSampler, TransitionReplay
from ppo.config import AMPConfig
from ppo.networks import mlp
from ppo.normalizer import RunningNormalizer

AMP_SEED = 43  # the AMP generator's seed is [train.seed, AMP_SEED]: its draws leave PPO's generator alone


class Discriminator(nn.Module):
    """rsl_rl's AMPNet: an MLP over [s, s'] (normalised, each of width D) to one raw score.

    Args:
        state_size: D, the features of one state.
        hidden: Hidden layer widths.
        activation: Hidden activation.
    """

    def __init__(self, state_size: int, hidden: tuple[int, ...], activation: str) -> None:
        super().__init__()
        self.state_size = state_size
        self.net = mlp([2 * state_size, *hidden, 1], activation, output_gain=1.0)

    def forward(self, state: torch.Tensor, next_state: torch.Tensor) -> torch.Tensor:
        """Raw scores x of transitions. (B, D), (B, D) -> (B,)."""
        return self.net(torch.cat([state, next_state], dim=-1)).squeeze(-1)

    def weights(self) -> list[torch.Tensor]:
        """The weight matrices of every layer, the output layer's last."""
        return [m.weight for m in self.net if isinstance(m, nn.Linear)]


# ----------------------------------------------------------------------------------------------- pure functions
def classification_loss(raw: torch.Tensor, expert: bool, output: str, label_smoothing: float) -> torch.Tensor:
    """Mean loss of raw scores (B,) labelled expert or policy: hinge on tanh(x) or BCE on the logit x."""
    if output == "tanh":
        label = (1.0 - label_smoothing) if expert else (-1.0 + label_smoothing)
        return torch.relu(1.0 - torch.tanh(raw) * label).mean()
    target = (1.0 - label_smoothing) if expert else label_smoothing
    return F.binary_cross_entropy_with_logits(raw, torch.full_like(raw, target))


def gradient_penalty(raw: torch.Tensor, inputs: torch.Tensor) -> torch.Tensor:
    """GP = mean_b ||d raw_b / d inputs_b||^2, differentiable (for the discriminator's step).

    Args:
        raw: Raw scores (B,) computed from ``inputs``, each row's from its row only.
        inputs: The expert inputs (B, K), with ``requires_grad``.
    """
    (grad,) = torch.autograd.grad(raw.sum(), inputs, create_graph=True)
    return grad.pow(2).sum(dim=-1).mean()


def accuracy(raw: torch.Tensor, expert: bool) -> torch.Tensor:
    """Share of raw scores on their side of the boundary (tanh(x) = 0 or sigmoid(x) = 0.5, both x = 0)."""
    return (raw > 0).float().mean() if expert else (raw < 0).float().mean()


def amp_reward(raw: torch.Tensor, config: AMPConfig) -> torch.Tensor:
    """The AMP reward of transitions with raw scores (B,) in the config's form (module docstring). Shape: (B,)."""
    if config.reward == "mimickit":
        return -torch.log(torch.clamp(1.0 - torch.sigmoid(raw), min=config.reward_epsilon)) * config.reward_scale
    score = torch.tanh(raw) if config.output == "tanh" else torch.sigmoid(raw)
    r = -torch.log(torch.clamp(1.0 - score - config.label_smoothing, min=config.reward_epsilon)) - config.reward_shift
    return torch.clamp(r, min=config.reward_min)


def discriminator_loss(
    expert_raw: torch.Tensor,
    policy_raw: torch.Tensor,
    penalty: torch.Tensor,
    weights: list[torch.Tensor],
    config: AMPConfig,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """L = 0.5 (L_expert + L_policy) + lambda_gp GP + logit_reg ||W_out||^2 + weight_decay sum_l ||W_l||^2.

    Args:
        expert_raw: Raw scores of expert transitions. Shape: (B_e,).
        policy_raw: Raw scores of policy transitions. Shape: (B_p,).
        penalty: The gradient penalty on the expert inputs (:func:`gradient_penalty`).
        weights: The discriminator's weight matrices, the output layer's last.
        config: The weights of the terms.

    Returns:
        The loss and its terms (detached): expert_loss, policy_loss, grad_penalty, expert_accuracy,
        policy_accuracy, logit_reg, weight_decay.
    """
    expert = classification_loss(expert_raw, True, config.output, config.label_smoothing)
    policy = classification_loss(policy_raw, False, config.output, config.label_smoothing)
    logit = weights[-1].pow(2).sum()
    decay = sum(w.pow(2).sum() for w in weights)
    loss = 0.5 * (expert + policy) + config.lambda_gp * penalty + config.logit_reg * logit + config.weight_decay * decay
    metrics = {"expert_loss": expert, "policy_loss": policy, "grad_penalty": penalty,
               "expert_accuracy": accuracy(expert_raw, True), "policy_accuracy": accuracy(policy_raw, False),
               "logit_reg": logit, "weight_decay": decay}  # fmt: skip
    return loss, {k: v.detach() for k, v in metrics.items()}


# ----------------------------------------------------------------------------------------------- training
class AMP:
    """The discriminator, its optimiser, the feature normaliser, the replay buffer and the expert sampler.

    Per iteration: :meth:`add_rollout` (the rollout's policy transitions and this iteration's expert batches into the
    normaliser's statistics; a turnover of the rollout into the replay buffer), :meth:`reward` of the rollout under
    the discriminator as it stands (before GAE), then, after PPO's update, :meth:`update`: ``updates_per_iteration``
    Adam steps, each on ``expert_batch`` expert transitions and ``batch_size`` policy transitions (half from the
    rollout, half from the replay buffer). Its draws come from its own generator, saved with it.

    Args:
        config: The AMP section.
        features: The feature function.
        library: The clips (expert transitions).
        normalizer_clip: Normalised features are clipped to +- this.
        normalizer_epsilon: Floor of the features' standard deviation.
        device: Where the discriminator runs.
        seed: The run's seed.
    """

    def __init__(self, config: AMPConfig, features: AMPFeatures, library: MotionLibrary, normalizer_clip: float,
                 normalizer_epsilon: float, device: torch.device, seed: int) -> None:  # fmt: skip
        self.config, self.device = config, device
        self.size = features.size
        self.disc = Discriminator(self.size, config.hidden, config.activation).to(device)
        self.optimizer = torch.optim.Adam(self.disc.parameters(), lr=config.lr)
        self.normalizer = RunningNormalizer(np.ones(self.size, dtype=bool), normalizer_clip, normalizer_epsilon)
        self.replay = TransitionReplay(config.buffer_size, 2 * self.size)
        self.expert = ExpertSampler(library, features)
        self.active = self._active_features(library, features, config.still_std)
        self.rng = np.random.default_rng([seed, AMP_SEED])
        self.nan_guard = NanGuard({"disc": self.disc, "optimizer": self.optimizer})
        self._rollout: np.ndarray | None = None
        self._expert: tuple[np.ndarray, np.ndarray] | None = None

    @staticmethod
    def _active_features(library: MotionLibrary, features: AMPFeatures, still_std: float) -> np.ndarray:
        """1 for every feature that varies over the library's frames (std >= ``still_std``), 0 for the still ones.
        Shape: (D,). A function of the library alone, so a resumed run rebuilds the same mask."""
        clips = np.repeat(np.arange(library.num_clips), library.num_frames)
        times = np.concatenate([np.arange(n) * library.dt for n in library.num_frames])
        std = features(library.query(clips, times)).std(axis=0)
        return (std >= still_std).astype(np.float64)

    def _tensor(self, x: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(x, dtype=torch.float32, device=self.device)

    def _normalized(self, states: np.ndarray) -> torch.Tensor:
        """Normalised features (..., D) as a tensor, the still ones zeroed (see ``amp.still_std``); s and s' alike."""
        return self._tensor(self.normalizer.normalize(states) * self.active)

    def add_rollout(self, state: np.ndarray, next_state: np.ndarray) -> None:
        """Takes a rollout's policy transitions (M, D) each, and draws this iteration's expert transitions.

        The normaliser adds the policy's states s and the expert batches' states s; the replay buffer takes its
        turnover of the rollout.
        """
        c = self.config
        expert = self.expert.sample(c.updates_per_iteration * c.expert_batch, self.rng)
        self.normalizer.update(np.concatenate([state, expert[0]]).astype(np.float64))
        rows = np.concatenate([state, next_state], axis=-1).astype(np.float32)
        self.replay.add(rows, c.replay_samples, self.rng)
        self._rollout, self._expert = rows, expert

    @torch.no_grad()
    def reward(self, state: np.ndarray, next_state: np.ndarray) -> np.ndarray:
        """AMP reward of transitions (M, D) each under the current discriminator and statistics. Shape: (M,)."""
        raw = self.disc(self._normalized(state), self._normalized(next_state))
        return amp_reward(raw, self.config).double().cpu().numpy()

    def update(self) -> dict[str, float]:
        """The discriminator's steps of the iteration (after :meth:`add_rollout`); returns ``amp/...`` means."""
        if self._rollout is None or self._expert is None:
            raise RuntimeError("AMP.update needs a rollout (add_rollout) first")
        c, d = self.config, self.size
        half = c.batch_size // 2
        sums: dict[str, float] = {}
        steps = 0
        for u in range(c.updates_per_iteration):
            rows = slice(u * c.expert_batch, (u + 1) * c.expert_batch)
            expert = torch.cat([self._normalized(self._expert[0][rows]), self._normalized(self._expert[1][rows])], -1)
            expert.requires_grad_(True)
            policy = np.concatenate([self._rollout[self.rng.integers(0, len(self._rollout), size=half)],
                                     self.replay.sample(c.batch_size - half, self.rng)])  # fmt: skip
            expert_raw = self.disc(expert[:, :d], expert[:, d:])
            policy_raw = self.disc(self._normalized(policy[:, :d]), self._normalized(policy[:, d:]))
            penalty = gradient_penalty(expert_raw, expert)
            loss, metrics = discriminator_loss(expert_raw, policy_raw, penalty, self.disc.weights(), c)
            if not self.nan_guard.check({"amp": loss}):
                continue
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.optimizer.step()
            metrics["loss"] = loss.detach()
            for k, v in metrics.items():
                sums[k] = sums.get(k, 0.0) + float(v)
            steps += 1
        self._rollout = self._expert = None
        out = {f"amp/{k}": v / max(steps, 1) for k, v in sums.items()}
        out["amp/steps"] = float(steps)
        out["amp/replay_size"] = float(self.replay.size)
        return out

    def state_dict(self) -> dict[str, Any]:
        """Discriminator, optimiser, normaliser, replay buffer and generator: all needed to continue exactly."""
        return {"disc": self.disc.state_dict(), "optimizer": self.optimizer.state_dict(),
                "normalizer": self.normalizer.state_dict(), "replay": self.replay.state_dict(),
                "rng": self.rng.bit_generator.state}  # fmt: skip

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restores :meth:`state_dict` (ValueError where it does not fit this config)."""
        try:
            self.disc.load_state_dict(state["disc"])
            self.optimizer.load_state_dict(state["optimizer"])
        except (RuntimeError, ValueError, KeyError) as e:
            raise ValueError(f"checkpoint discriminator does not match this config: {e}") from e
        self.normalizer.load_state_dict(state["normalizer"])
        self.replay.load_state_dict(state["replay"])
        self.rng.bit_generator.state = state["rng"]
        self.nan_guard = NanGuard({"disc": self.disc, "optimizer": self.optimizer})
        self._rollout = self._expert = None
