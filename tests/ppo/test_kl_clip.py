"""benchmarks/ppo_kl_clip.py's Monte Carlo against the closed form: the log-ratio is N(-KL, 2 KL)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.benchmark_module import benchmark_module


def _closed_form(kl: float, eps: float) -> float:
    """P(|exp(X) - 1| > eps) for X ~ N(-kl, 2 kl)."""
    sd = math.sqrt(2.0 * kl)
    cdf = lambda x: 0.5 * (1.0 + math.erf((x + kl) / (sd * math.sqrt(2.0))))  # noqa: E731
    return 1.0 - cdf(math.log(1.0 + eps)) + cdf(math.log(1.0 - eps))


@pytest.mark.parametrize("kl", [0.005, 0.01, 0.05])
def test_clip_fraction_matches_the_closed_form(kl: float) -> None:
    module = benchmark_module("ppo_kl_clip")
    frac, k3 = module.clip_fraction(kl, 28, 0.2, 40_000, np.random.default_rng(0))
    assert frac == pytest.approx(_closed_form(kl, 0.2), abs=0.01)
    assert k3 == pytest.approx(kl, rel=0.05)
    assert module.clip_fraction(kl, 5, 0.2, 40_000, np.random.default_rng(1))[0] == pytest.approx(frac, abs=0.01)
