"""What clip fraction a diagonal-Gaussian policy's update must show at a given KL, whatever its std or batch.

For pi_old = N(mu, sigma^2 I) and pi = N(mu + sigma delta, sigma^2 I) (the same fixed std, the mean moved by delta in
units of sigma), the log-ratio of an action a = mu + sigma z drawn by pi_old is delta . z - |delta|^2 / 2: normal with
standard deviation |delta| = sqrt(2 KL). The share of samples with |ratio - 1| > eps (PPO's clip fraction) is then a
function of the KL alone, not of the action dimension, the std or the minibatch. This prints it by Monte Carlo, with
the k3 estimate of the KL beside the exact one, for PPO's clip range 0.2 and the humanoid's 28 actions; docs/ppo.md
reads the clip fraction of its runs through it.

    python benchmarks/ppo_kl_clip.py
"""

from __future__ import annotations

import argparse

import numpy as np


def clip_fraction(kl: float, dims: int, eps: float, samples: int, rng: np.random.Generator) -> tuple[float, float]:
    """(clip fraction, k3 KL estimate) of an update that moved every mean so that KL(pi_old || pi) = ``kl``."""
    delta = rng.normal(size=dims)
    delta *= np.sqrt(2.0 * kl) / np.linalg.norm(delta)
    z = rng.normal(size=(samples, dims))
    log_ratio = z @ delta - kl  # mean -|delta|^2 / 2 = -KL
    ratio = np.exp(log_ratio)
    return float(np.mean(np.abs(ratio - 1.0) > eps)), float(np.mean(ratio - 1.0 - log_ratio))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dims", type=int, default=28, help="action dimensions (the humanoid's hinges)")
    parser.add_argument("--eps", type=float, default=0.2, help="PPO's clip range")
    parser.add_argument("--samples", type=int, default=200_000, help="Monte Carlo actions per KL")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    print(f"{'KL':>8} {'clip fraction':>14} {'k3 estimate':>12}")
    for kl in (0.0025, 0.005, 0.01, 0.013, 0.02, 0.03, 0.05, 0.1, 0.13):
        frac, k3 = clip_fraction(kl, args.dims, args.eps, args.samples, rng)
        print(f"{kl:8.4f} {frac:14.3f} {k3:12.4f}")


if __name__ == "__main__":
    main()
