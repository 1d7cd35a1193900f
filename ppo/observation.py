"""The PPO tracker's observation: :func:`common.features.tracking_observation` flattened, with a named layout."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from common.features import OBSERVATION_KEYS, flatten_observation, tracking_observation
from common.motion_library import CharacterState


def observe(sim: CharacterState, ref_next: CharacterState, phase: np.ndarray) -> np.ndarray:
    """Flat observation of N characters: the simulated state at t and the reference at t + dt.

    Args:
        sim: Simulated state, leading shape (N,).
        ref_next: Reference state one control step ahead, leading shape (N,).
        phase: Clip phase in [0, 1). Shape: (N,).

    Returns:
        Observation in ``OBSERVATION_KEYS`` order. Shape: (N, D_obs).
    """
    return flatten_observation(tracking_observation(sim, ref_next, phase))


def observation_layout(sim: CharacterState, ref_next: CharacterState, phase: np.ndarray) -> dict[str, slice]:
    """Slice of every named feature in the flat observation, measured on a sample observation."""
    named = tracking_observation(sim, ref_next, phase)
    out, start = {}, 0
    for key in OBSERVATION_KEYS:
        width = named[key].shape[-1]
        out[key] = slice(start, start + width)
        start += width
    return out


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
