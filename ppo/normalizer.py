"""Running mean and standard deviation of observations (parallel Welford / Chan et al. update), in float64.

``normalize`` maps x to clip((x - mean) / max(std, epsilon), -clip, clip) on the masked entries and leaves the
others (already bounded features such as the phase's sin/cos) as they are. Statistics change only through
:meth:`RunningNormalizer.update`, which the learner calls on rollout observations only: evaluation reads them frozen.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np


class RunningNormalizer:
    """Observation normaliser with running statistics.

    Args:
        mask: Entries to normalise. Shape: (D,).
        clip: Bound of the normalised values.
        epsilon: Floor of the standard deviation.
        max_samples: Stop updating after this many samples (None: never stop).
    """

    def __init__(self, mask: np.ndarray, clip: float = 5.0, epsilon: float = 1e-2, max_samples: int | None = None):
        self.mask = np.asarray(mask, dtype=bool)
        self.clip, self.epsilon, self.max_samples = float(clip), float(epsilon), max_samples
        size = self.mask.shape[0]
        self.count = 0
        self.mean = np.zeros(size)
        self.var = np.ones(size)

    @property
    def size(self) -> int:
        return self.mask.shape[0]

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(self.var)

    @property
    def frozen(self) -> bool:
        return self.max_samples is not None and self.count >= self.max_samples

    def update(self, x: np.ndarray) -> None:
        """Adds a batch of samples to the statistics (no-op once ``max_samples`` is reached).

        Args:
            x: Samples. Shape: (B, D).
        """
        if x.ndim != 2 or x.shape[1] != self.size:
            raise ValueError(f"normalizer: expected shape (B, {self.size}), got {x.shape}")
        if self.frozen or len(x) == 0:
            return
        x = x.astype(np.float64)
        m = len(x)
        batch_mean, batch_var = x.mean(axis=0), x.var(axis=0)
        if self.count == 0:
            self.mean, self.var = batch_mean, batch_var
        else:
            # Chan et al.: M2 = M2_a + M2_b + delta^2 n m / (n + m), with M2 = var * count.
            n, total = self.count, self.count + m
            delta = batch_mean - self.mean
            self.mean = self.mean + delta * (m / total)
            self.var = (self.var * n + batch_var * m + delta**2 * (n * m / total)) / total
        self.count += m

    def normalize(self, x: np.ndarray) -> np.ndarray:
        """Normalised copy of ``x`` as float32. Shape: (..., D) -> (..., D)."""
        scaled = np.clip((x - self.mean) / np.maximum(self.std, self.epsilon), -self.clip, self.clip)
        return np.where(self.mask, scaled, x).astype(np.float32)

    def state_dict(self) -> dict[str, Any]:
        return {"count": self.count, "mean": self.mean.copy(), "var": self.var.copy(), "mask": self.mask.copy()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        mask = np.asarray(state["mask"], dtype=bool)
        if mask.shape != self.mask.shape or not np.array_equal(mask, self.mask):
            raise ValueError(
                f"normalizer state is for {mask.shape[0]} observation entries ({int(mask.sum())} normalised), "
                f"this one has {self.size} ({int(self.mask.sum())}): the checkpoint does not match this observation"
            )
        self.count = int(state["count"])
        self.mean = np.asarray(state["mean"], dtype=np.float64).copy()
        self.var = np.asarray(state["var"], dtype=np.float64).copy()


def normalized_mask(layout: dict[str, slice], exclude: Iterable[str]) -> np.ndarray:
    """True for the observation entries the normaliser standardises (all but the ``exclude`` features).

    Raises:
        ValueError: If ``exclude`` names an unknown feature.
    """
    exclude = tuple(exclude)
    unknown = sorted(set(exclude) - set(layout))
    if unknown:
        raise ValueError(f"normalizer.exclude: unknown observation features {unknown} (known: {list(layout)})")
    size = max(s.stop for s in layout.values())
    mask = np.ones(size, dtype=bool)
    for key in exclude:
        mask[layout[key]] = False
    return mask
