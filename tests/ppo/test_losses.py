"""PPO losses against hand-computed numbers."""

from __future__ import annotations

import math

import pytest
import torch

from ppo.config import PPOConfig
from ppo.losses import adapted_learning_rate, bound_loss, gaussian_kl, ppo_loss, surrogate_loss, value_loss
from ppo.networks import gaussian_entropy, gaussian_log_prob

RATIOS = torch.tensor([0.5, 1.0, 1.5, 1.1], dtype=torch.float64)
ADVANTAGES = torch.tensor([1.0, -1.0, 2.0, -2.0], dtype=torch.float64)


def test_clipped_surrogate_hand_computed() -> None:
    # eps = 0.2. min(rho A, clip(rho) A) per sample:
    #   rho 0.5, A  1: min(0.5, 0.8 * 1)   =  0.5   (clipped from below, but the pessimistic unclipped term wins)
    #   rho 1.0, A -1: min(-1, -1)          = -1.0
    #   rho 1.5, A  2: min(3.0, 1.2 * 2)    =  2.4   (clipped)
    #   rho 1.1, A -2: min(-2.2, -2.2)      = -2.2
    # loss = -(0.5 - 1 + 2.4 - 2.2) / 4 = 0.075; clip_frac = 2/4;
    # approx_kl = mean(rho - 1 - ln rho) = (0.193147 + 0 + 0.094535 + 0.004690) / 4 = 0.073093
    old = torch.zeros(4, dtype=torch.float64)
    log_prob = torch.log(RATIOS).requires_grad_(True)
    loss, metrics = surrogate_loss(log_prob, old, ADVANTAGES, clip_ratio=0.2)
    assert loss.item() == pytest.approx(0.075)
    assert metrics["clip_frac"].item() == pytest.approx(0.5)
    assert metrics["approx_kl"].item() == pytest.approx(0.0730929, abs=1e-6)
    # d loss / d log_prob_i = -rho_i A_i / 4 where the unclipped term is active, 0 where the clip holds it (sample 2).
    loss.backward()
    torch.testing.assert_close(log_prob.grad, torch.tensor([-0.125, 0.25, 0.0, 0.55], dtype=torch.float64))


def test_value_loss_plain_and_clipped() -> None:
    values, returns = torch.tensor([1.0, 2.0]), torch.tensor([0.0, 4.0])
    # 0.5 * mean(1^2, 2^2) = 1.25
    loss, _ = value_loss(values, returns, values, value_clip=None)
    assert loss.item() == pytest.approx(1.25)
    # old values 0.5, 1.0 with c = 0.5: clipped V = 1.0, 1.5 -> errors 1.0, 6.25; max with 1, 4 -> 0.5 * 3.625
    loss, _ = value_loss(values, returns, torch.tensor([0.5, 1.0]), value_clip=0.5)
    assert loss.item() == pytest.approx(1.8125)


def test_bound_loss_penalises_only_means_beyond_the_bound() -> None:
    # bound 2: excess [[0, 1], [0.5, 0]] -> squared sums 1 and 0.25 -> mean 0.625
    loss, metrics = bound_loss(torch.tensor([[0.5, -3.0], [2.5, 0.0]]), bound=2.0)
    assert loss.item() == pytest.approx(0.625)
    assert metrics["out_of_bound"].item() == pytest.approx(0.5)


def test_ppo_loss_combines_the_parts_with_their_coefficients() -> None:
    cfg = PPOConfig(value_coef=0.5, entropy_coef=0.1, bound_coef=10.0, action_bound=2.0, clip_ratio=0.2)
    log_prob = torch.log(RATIOS)
    entropy = torch.full((4,), 2.0, dtype=torch.float64)
    mean = torch.tensor([[0.0], [3.0], [0.0], [0.0]], dtype=torch.float64)  # bound: 1^2 / 4 = 0.25
    values = torch.tensor([1.0, 2.0, 0.0, 0.0], dtype=torch.float64)
    returns = torch.tensor([0.0, 4.0, 0.0, 0.0], dtype=torch.float64)  # value: 0.5 * (1 + 4) / 4 = 0.625
    total, m = ppo_loss(log_prob, entropy, mean, values, torch.zeros(4, dtype=torch.float64), values, ADVANTAGES,
                        returns, cfg)  # fmt: skip
    # 0.075 + 0.5 * 0.625 - 0.1 * 2.0 + 10 * 0.25 = 2.6875
    assert total.item() == pytest.approx(2.6875)
    assert m["policy"].item() == pytest.approx(0.075) and m["value"].item() == pytest.approx(0.625)
    assert m["bound"].item() == pytest.approx(0.25) and m["entropy"].item() == pytest.approx(2.0)


def test_gaussian_log_prob_and_entropy_hand_computed() -> None:
    # One dim, sigma = e^0 = 1, a - mu = 1: -0.5 - 0 - 0.5 ln(2 pi); two dims sum. Entropy: 0.5 ln(2 pi e) per dim.
    half_log_2pi = 0.5 * math.log(2 * math.pi)
    lp = gaussian_log_prob(torch.tensor([[1.0, 0.0]]), torch.zeros(1, 2), torch.zeros(2))
    assert lp.item() == pytest.approx(-0.5 - 2 * half_log_2pi)
    # sigma = 2 (log 2), a - mu = 2: z = 1 -> -0.5 - ln 2 - 0.5 ln(2 pi)
    lp = gaussian_log_prob(torch.tensor([[2.0]]), torch.zeros(1, 1), torch.tensor([math.log(2.0)]))
    assert lp.item() == pytest.approx(-0.5 - math.log(2.0) - half_log_2pi)
    ent = gaussian_entropy(torch.zeros(3), batch=5)
    assert ent.shape == (5,)
    assert ent[0].item() == pytest.approx(3 * 0.5 * math.log(2 * math.pi * math.e))


def test_gaussian_kl_hand_computed() -> None:
    # One dim: old N(0, 1), new N(0.5, 2): log 2 + (1 + 0.25) / 8 - 0.5 = 0.693147 + 0.15625 - 0.5 = 0.349397.
    # A second dim equal in both adds 0; the same Gaussian twice gives 0.
    old_mean, mean = torch.tensor([[0.0, 0.3]]), torch.tensor([[0.5, 0.3]])
    old_log_std, log_std = torch.tensor([0.0, -1.0]), torch.tensor([math.log(2.0), -1.0])
    assert gaussian_kl(old_mean, old_log_std, mean, log_std).item() == pytest.approx(math.log(2.0) + 1.25 / 8 - 0.5)
    assert gaussian_kl(mean, log_std, mean, log_std).item() == pytest.approx(0.0, abs=1e-7)
    # Fixed std sigma: the KL is sum (delta mu)^2 / (2 sigma^2): 28 dims moved by 0.02 at sigma 0.2 -> 0.14
    moved = gaussian_kl(torch.zeros(1, 28), torch.full((28,), math.log(0.2)), torch.full((1, 28), 0.02),
                        torch.full((28,), math.log(0.2)))  # fmt: skip
    assert moved.item() == pytest.approx(28 * 0.02**2 / (2 * 0.04))


def test_adaptive_learning_rate_rule_of_rsl_rl() -> None:
    cfg = PPOConfig(schedule="adaptive", desired_kl=0.01, lr_factor=1.5, min_lr=1e-5, max_lr=1e-2)
    assert adapted_learning_rate(1e-3, 0.021, cfg) == pytest.approx(1e-3 / 1.5)  # above 2 x desired: down
    assert adapted_learning_rate(1e-3, 0.02, cfg) == 1e-3  # at 2 x desired: kept
    assert adapted_learning_rate(1e-3, 0.01, cfg) == 1e-3  # in the band: kept
    assert adapted_learning_rate(1e-3, 0.004, cfg) == pytest.approx(1.5e-3)  # below desired / 2: up
    assert adapted_learning_rate(1e-3, 0.0, cfg) == 1e-3  # no change of the policy yet (first minibatch): kept
    assert adapted_learning_rate(1.2e-5, 1.0, cfg) == 1e-5  # floor
    assert adapted_learning_rate(9e-3, 1e-4, cfg) == 1e-2  # ceiling
    with pytest.raises(ValueError, match="adaptive schedule"):
        PPOConfig(lr_factor=1.0)
