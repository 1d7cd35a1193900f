"""Running mean and standard deviation of observations (parallel Welford / Chan et al. update), in float64.

``normalize`` maps x to clip((x - mean) / max(std, epsilon), -clip, clip) on the masked entries and leaves the
others (already bounded features such as the phase's sin/cos) as they are. Statistics change only through
:meth:`RunningNormalizer.update` (or :meth:`RunningNormalizer.merge` of a batch's moments), on rollout observations
only: evaluation reads them frozen.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from common.sim.observation import is_raw_feature

Moments = tuple[int, np.ndarray, np.ndarray]
"""A batch's sample count, mean (D,) and (biased) variance (D,)."""


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
        self.merge(moments(x))

    def merge(self, batch: Moments) -> None:
        """Adds a batch given by its moments (no-op once ``max_samples`` is reached); for the batch's samples,
        the same numbers as :meth:`update`."""
        if self.frozen or batch[0] == 0:
            return
        self.count, self.mean, self.var = _chan((self.count, self.mean, self.var), batch)

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


def moments(x: np.ndarray) -> Moments:
    """Count, mean and variance of samples (B, D), in float64."""
    x = x.astype(np.float64)
    return len(x), x.mean(axis=0), x.var(axis=0)


def combine_moments(parts: Sequence[Moments]) -> Moments:
    """The moments of the union of several batches, merged in order; one batch's are returned as they are."""
    out = parts[0]
    for part in parts[1:]:
        out = _chan(out, part)
    return out


def _chan(a: Moments, b: Moments) -> Moments:
    """Moments of two batches together (Chan et al.): M2 = M2_a + M2_b + delta^2 n m / (n + m), M2 = var * count."""
    n, mean, var = a
    m, batch_mean, batch_var = b
    if m == 0:
        return a
    if n == 0:
        return b
    total = n + m
    delta = batch_mean - mean
    return total, mean + delta * (m / total), (var * n + batch_var * m + delta**2 * (n * m / total)) / total


def normalized_mask(layout: dict[str, slice], exclude: Iterable[str]) -> np.ndarray:
    """True for the observation entries the normaliser standardises: all but the ``exclude`` features and the terrain
    features (heightmap, contact labels: :func:`common.sim.observation.is_raw_feature`), which PARC leaves raw.

    Raises:
        ValueError: If ``exclude`` names an unknown feature.
    """
    exclude = tuple(exclude)
    unknown = sorted(set(exclude) - set(layout))
    if unknown:
        raise ValueError(f"normalizer.exclude: unknown observation features {unknown} (known: {list(layout)})")
    size = max(s.stop for s in layout.values())
    mask = np.ones(size, dtype=bool)
    for key in exclude + tuple(k for k in layout if is_raw_feature(k)):
        mask[layout[key]] = False
    return mask
