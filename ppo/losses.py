"""PPO's losses as pure functions of tensors, each returning ``(loss, metrics)`` (metrics are detached scalars).

Shapes: B samples of a minibatch, A action dims.
"""

from __future__ import annotations

import torch

from ppo.config import PPOConfig

Metrics = dict[str, torch.Tensor]


def surrogate_loss(
    log_prob: torch.Tensor, old_log_prob: torch.Tensor, advantages: torch.Tensor, clip_ratio: float
) -> tuple[torch.Tensor, Metrics]:
    """Clipped surrogate: -mean(min(rho A, clip(rho, 1 - eps, 1 + eps) A)), rho = exp(log_prob - old_log_prob).

    Args:
        log_prob: log pi(a | s) under the current policy. Shape: (B,).
        old_log_prob: log pi_old(a | s) stored at collection. Shape: (B,).
        advantages: Advantage estimates. Shape: (B,).
        clip_ratio: eps.

    Returns:
        The loss and ``clip_frac`` (share of samples with |rho - 1| > eps) and ``approx_kl`` (the k3 estimator
        mean(rho - 1 - log rho) of KL(pi_old || pi)).
    """
    log_ratio = log_prob - old_log_prob
    ratio = torch.exp(log_ratio)
    unclipped = ratio * advantages
    clipped = torch.clamp(ratio, 1.0 - clip_ratio, 1.0 + clip_ratio) * advantages
    loss = -torch.min(unclipped, clipped).mean()
    with torch.no_grad():
        metrics = {
            "clip_frac": ((ratio - 1.0).abs() > clip_ratio).float().mean(),
            "approx_kl": ((ratio - 1.0) - log_ratio).mean(),
        }
    return loss, metrics


def value_loss(
    values: torch.Tensor, returns: torch.Tensor, old_values: torch.Tensor, value_clip: float | None
) -> tuple[torch.Tensor, Metrics]:
    """0.5 mean((V - R)^2); with ``value_clip`` c, 0.5 mean(max((V - R)^2, (V_old + clip(V - V_old, -c, c) - R)^2)).

    Args:
        values: Current V(s). Shape: (B,).
        returns: Value targets. Shape: (B,).
        old_values: V(s) stored at collection. Shape: (B,).
        value_clip: c, or None for the plain squared error.
    """
    error = (values - returns).pow(2)
    if value_clip is not None:
        clipped = old_values + torch.clamp(values - old_values, -value_clip, value_clip)
        error = torch.max(error, (clipped - returns).pow(2))
    loss = 0.5 * error.mean()
    return loss, {"value_error": error.detach().mean()}


def bound_loss(mean: torch.Tensor, bound: float) -> tuple[torch.Tensor, Metrics]:
    """Penalty on policy means beyond +- bound: mean over B of sum over A of relu(|mu| - bound)^2. mean: (B, A)."""
    excess = torch.relu(mean.abs() - bound)
    loss = excess.pow(2).sum(dim=-1).mean()
    return loss, {"out_of_bound": (excess > 0).float().mean().detach()}


def ppo_loss(
    log_prob: torch.Tensor,
    entropy: torch.Tensor,
    mean: torch.Tensor,
    values: torch.Tensor,
    old_log_prob: torch.Tensor,
    old_values: torch.Tensor,
    advantages: torch.Tensor,
    returns: torch.Tensor,
    config: PPOConfig,
) -> tuple[torch.Tensor, Metrics]:
    """Total loss = surrogate + value_coef value - entropy_coef entropy + bound_coef bound.

    Args:
        log_prob: Current log pi(a | s). Shape: (B,).
        entropy: Current policy entropy. Shape: (B,).
        mean: Current policy mean. Shape: (B, A).
        values: Current V(s). Shape: (B,).
        old_log_prob: Stored log pi_old(a | s). Shape: (B,).
        old_values: Stored V_old(s). Shape: (B,).
        advantages: Advantages (already normalised and clipped as configured). Shape: (B,).
        returns: Value targets. Shape: (B,).
        config: Coefficients.

    Returns:
        The loss and its parts ``policy``, ``value``, ``entropy``, ``bound`` plus the parts' own metrics.
    """
    policy, policy_metrics = surrogate_loss(log_prob, old_log_prob, advantages, config.clip_ratio)
    value, value_metrics = value_loss(values, returns, old_values, config.value_clip)
    bound, bound_metrics = bound_loss(mean, config.action_bound)
    entropy_mean = entropy.mean()
    total = policy + config.value_coef * value - config.entropy_coef * entropy_mean + config.bound_coef * bound
    metrics = {
        "policy": policy.detach(), "value": value.detach(), "entropy": entropy_mean.detach(), "bound": bound.detach(),
        **policy_metrics, **value_metrics, **bound_metrics,
    }  # fmt: skip
    return total, metrics


def gaussian_kl(
    old_mean: torch.Tensor, old_log_std: torch.Tensor, mean: torch.Tensor, log_std: torch.Tensor
) -> torch.Tensor:
    """KL(N(old_mean, old_std) || N(mean, std)) of diagonal Gaussians, summed over the A action dims:
    sum(log(std / old_std) + (old_std^2 + (old_mean - mean)^2) / (2 std^2) - 1/2). Means (B, A), log-stds (A,) or
    (B, A). Shape: (B,)."""
    var, old_var = torch.exp(2.0 * log_std), torch.exp(2.0 * old_log_std)
    return (log_std - old_log_std + (old_var + (old_mean - mean).pow(2)) / (2.0 * var) - 0.5).sum(dim=-1)


def adapted_learning_rate(lr: float, kl: float, config: PPOConfig) -> float:
    """rsl_rl's KL-adaptive rule for one minibatch: ``lr / lr_factor`` when ``kl`` > 2 ``desired_kl``, ``lr x
    lr_factor`` when 0 < ``kl`` < ``desired_kl`` / 2, else ``lr``; kept in [min_lr, max_lr]."""
    if kl > 2.0 * config.desired_kl:
        return max(config.min_lr, lr / config.lr_factor)
    if 0.0 < kl < 0.5 * config.desired_kl:
        return min(config.max_lr, lr * config.lr_factor)
    return lr
