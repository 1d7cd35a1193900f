"""PARC's adaptive motion weighting: a failure-rate EMA per clip and sampling weights by failure-rate bucket.

Each finished episode updates its clip's failure rate, rate <- (1 - w) rate + w * failed (w = 0.01; failed = the
episode terminated; a truncated episode counts as a success). The gym draws reset clips with weights by failure-rate
bucket (< 0.1 -> 0.1, < 0.3 -> 0.3, < 0.5 -> 0.5, < 0.7 -> 0.7, else 1.0), never below ``min_weight``, so clips the
policy has mastered keep a share of the resets while the hard ones get most of them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class MotionWeightConfig:
    """PARC's adaptive motion weighting: clips that fail more often are sampled more often at reset.

    Attributes:
        enabled: Feed the weights to the gym (False: uniform clip sampling; failure rates are still tracked).
        ema_weight: w in rate <- (1 - w) rate + w * failed, per finished episode.
        init_failure_rate: Failure rate every clip starts with (1: every clip is presumed hard).
        thresholds: Upper bounds of the failure-rate buckets, increasing.
        bucket_weights: Sampling weight of each bucket; one more than ``thresholds`` (the last is for rates above
            the last threshold).
        min_weight: Lower bound of every weight.
    """

    enabled: bool = True
    ema_weight: float = 0.01
    init_failure_rate: float = 1.0
    thresholds: tuple[float, ...] = (0.1, 0.3, 0.5, 0.7)
    bucket_weights: tuple[float, ...] = (0.1, 0.3, 0.5, 0.7, 1.0)
    min_weight: float = 0.01

    def __post_init__(self) -> None:
        if len(self.bucket_weights) != len(self.thresholds) + 1:
            raise ValueError("bucket_weights needs exactly one entry more than thresholds")
        if list(self.thresholds) != sorted(self.thresholds):
            raise ValueError(f"thresholds must increase, got {self.thresholds}")
        if not 0.0 < self.ema_weight <= 1.0:
            raise ValueError(f"ema_weight must lie in (0, 1], got {self.ema_weight}")
        if self.min_weight <= 0 or min(self.bucket_weights) < 0:
            raise ValueError("min_weight must be positive and bucket_weights non-negative")



def bucket_weights(
    failure_rates: np.ndarray, thresholds: Sequence[float], weights: Sequence[float], min_weight: float
) -> np.ndarray:
    """Sampling weight of every clip from its failure rate.

    Args:
        failure_rates: Failure rate per clip in [0, 1]. Shape: (C,).
        thresholds: Increasing bucket bounds; rate < thresholds[k] (and >= the previous bound) is bucket k.
        weights: Weight of each bucket, len(thresholds) + 1 entries.
        min_weight: Lower bound of every weight.

    Returns:
        Weights. Shape: (C,).
    """
    bucket = np.searchsorted(np.asarray(thresholds, dtype=np.float64), failure_rates, side="right")
    return np.maximum(np.asarray(weights, dtype=np.float64)[bucket], min_weight)


class MotionWeights:
    """Failure-rate EMA of every clip.

    Args:
        num_clips: Clips in the motion library.
        config: EMA weight, initial rate and buckets.
    """

    def __init__(self, num_clips: int, config: MotionWeightConfig) -> None:
        self.config = config
        self.failure_rate = np.full(num_clips, config.init_failure_rate, dtype=np.float64)

    def record(self, clips: np.ndarray, terminated: np.ndarray, truncated: np.ndarray) -> None:
        """Updates the rates with the episodes that ended at one step (in character order).

        Args:
            clips: Clip of each character's episode. Shape: (N,).
            terminated: The episode failed. Shape: (N,).
            truncated: The episode reached its time limit. Shape: (N,).
        """
        w = self.config.ema_weight
        for n in np.flatnonzero(terminated | truncated):
            c = clips[n]
            self.failure_rate[c] = (1.0 - w) * self.failure_rate[c] + w * float(terminated[n])

    def record_block(self, frames: Mapping[str, np.ndarray]) -> None:
        """Updates the rates with the episodes that ended in a collector's block, step by step.

        Args:
            frames: The block's ``clip``, ``terminated`` and ``truncated`` fields. Shape: (T, N) each.
        """
        for t in range(len(frames["clip"])):
            self.record(frames["clip"][t], frames["terminated"][t], frames["truncated"][t])

    def weights(self) -> np.ndarray:
        """Sampling weight of every clip. Shape: (C,)."""
        c = self.config
        return bucket_weights(self.failure_rate, c.thresholds, c.bucket_weights, c.min_weight)

    def gym_weights(self, fixed: np.ndarray | None = None) -> np.ndarray | None:
        """The gym's RSI weight per clip: the adaptive weights (times ``fixed``, a learner's fixed per-clip weights)
        when enabled, else ``fixed`` alone (None: uniform)."""
        if not self.config.enabled:
            return fixed
        return self.weights() if fixed is None else self.weights() * fixed

    def charts(self) -> dict[str, float]:
        """The rates' and weights' extremes, for the training log."""
        rate, weights = self.failure_rate, self.weights()
        return {
            "charts/failure_rate_mean": float(rate.mean()), "charts/failure_rate_max": float(rate.max()),
            "charts/clip_weight_min": float(weights.min()), "charts/clip_weight_max": float(weights.max()),
        }  # fmt: skip

    def clip_charts(self, names: Sequence[str], limit: int = 20) -> dict[str, float]:
        """Failure rate of each clip (of the first ``limit``), by name, for the evaluation log."""
        return {f"charts/failure_rate/{name}": float(self.failure_rate[i]) for i, name in enumerate(names[:limit])}

    def state_dict(self) -> dict[str, Any]:
        return {"failure_rate": self.failure_rate.copy()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        rate = np.asarray(state["failure_rate"], dtype=np.float64)
        if rate.shape != self.failure_rate.shape:
            raise ValueError(f"motion weights saved for {len(rate)} clips, the library has {len(self.failure_rate)}")
        self.failure_rate = rate.copy()
