"""Actor-critic: separate policy and value MLPs and a diagonal Gaussian over PD-target offsets.

The policy's mean is an offset from the reference in action units (targets = reference hinge angles of the next
frame + action_scale * action); the last layer starts near zero, so the untrained policy plays the reference back
open loop plus exploration noise. The log-std is one vector (state independent), fixed or learned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from ppo.config import NetworkConfig

_ACTIVATIONS: dict[str, type[nn.Module]] = {"relu": nn.ReLU, "elu": nn.ELU, "tanh": nn.Tanh}


def mlp(sizes: list[int], activation: str, output_gain: float) -> nn.Sequential:
    """MLP with orthogonal init: gain sqrt(2) on hidden layers, ``output_gain`` on the last, zero biases.

    Args:
        sizes: Input width, hidden widths, output width.
        activation: Hidden activation name.
        output_gain: Gain of the last layer's init.
    """
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        linear = nn.Linear(sizes[i], sizes[i + 1])
        last = i == len(sizes) - 2
        nn.init.orthogonal_(linear.weight, gain=output_gain if last else math.sqrt(2.0))
        nn.init.zeros_(linear.bias)
        layers.append(linear)
        if not last:
            layers.append(_ACTIVATIONS[activation]())
    return nn.Sequential(*layers)


def gaussian_log_prob(actions: torch.Tensor, mean: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """Log-density of a diagonal Gaussian, summed over action dims. (B, A) -> (B,)."""
    z = (actions - mean) * torch.exp(-log_std)
    return (-0.5 * z.pow(2) - log_std - 0.5 * math.log(2.0 * math.pi)).sum(dim=-1)


def gaussian_entropy(log_std: torch.Tensor, batch: int) -> torch.Tensor:
    """Entropy of a diagonal Gaussian, sum over dims of log_std + 0.5 log(2 pi e). Shape: (batch,)."""
    return (log_std + 0.5 * math.log(2.0 * math.pi * math.e)).sum(dim=-1).expand(batch)


@dataclass
class ActOutput:
    """What the policy returns for a batch of observations; the runner writes it to storage.

    Attributes:
        action: Sampled action (or the mean when deterministic). Shape: (N, A).
        mean: Policy mean. Shape: (N, A).
        log_prob: log pi(action | obs). Shape: (N,).
        value: V(obs). Shape: (N,).
    """

    action: torch.Tensor
    mean: torch.Tensor
    log_prob: torch.Tensor
    value: torch.Tensor


class ActorCritic(nn.Module):
    """Policy and value networks on normalised observations.

    Args:
        obs_size: Observation width D.
        action_size: Action width A (the humanoid's actuated hinges).
        config: Layer sizes, activation and the log-std setting.
    """

    def __init__(self, obs_size: int, action_size: int, config: NetworkConfig) -> None:
        super().__init__()
        self.actor = mlp([obs_size, *config.actor_hidden, action_size], config.activation, config.init_output_gain)
        self.critic = mlp([obs_size, *config.critic_hidden, 1], config.activation, 1.0)
        self.log_std = nn.Parameter(torch.full((action_size,), float(config.log_std_init)),
                                    requires_grad=config.learn_std)  # fmt: skip

    def actor_parameters(self) -> list[nn.Parameter]:
        """Policy mean and log-std parameters (the actor's optimiser group)."""
        return [*self.actor.parameters(), self.log_std]

    def value(self, obs: torch.Tensor) -> torch.Tensor:
        """V(obs). (B, D) -> (B,)."""
        return self.critic(obs).squeeze(-1)

    def act(self, obs: torch.Tensor, noise: torch.Tensor | None) -> ActOutput:
        """Action, log-probability and value for a batch.

        Args:
            obs: Normalised observations. Shape: (N, D).
            noise: Standard normal draws (N, A) for the exploration; None: the deterministic mean action.
        """
        mean = self.actor(obs)
        action = mean if noise is None else mean + torch.exp(self.log_std) * noise
        return ActOutput(action, mean, gaussian_log_prob(action, mean, self.log_std), self.value(obs))

    def evaluate(self, obs: torch.Tensor, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """log pi(actions | obs) (B,), entropy (B,) and the policy mean (B, A), differentiable."""
        mean = self.actor(obs)
        return gaussian_log_prob(actions, mean, self.log_std), gaussian_entropy(self.log_std, len(obs)), mean
