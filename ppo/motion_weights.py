"""PARC's adaptive motion weighting: a failure-rate EMA per clip and sampling weights by failure-rate bucket.

Each finished episode updates its clip's failure rate, rate <- (1 - w) rate + w * failed (w = 0.01; failed = the
episode terminated; a truncated episode counts as a success). The gym draws reset clips with weights by failure-rate
bucket (< 0.1 -> 0.1, < 0.3 -> 0.3, < 0.5 -> 0.5, < 0.7 -> 0.7, else 1.0), never below ``min_weight``, so clips the
policy has mastered keep a share of the resets while the hard ones get most of them.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ppo.config import MotionWeightConfig


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

    def weights(self) -> np.ndarray:
        """Sampling weight of every clip. Shape: (C,)."""
        c = self.config
        return bucket_weights(self.failure_rate, c.thresholds, c.bucket_weights, c.min_weight)

    def state_dict(self) -> dict[str, Any]:
        return {"failure_rate": self.failure_rate.copy()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        rate = np.asarray(state["failure_rate"], dtype=np.float64)
        if rate.shape != self.failure_rate.shape:
            raise ValueError(f"motion weights saved for {len(rate)} clips, the library has {len(self.failure_rate)}")
        self.failure_rate = rate.copy()
