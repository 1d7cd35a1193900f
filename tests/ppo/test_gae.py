"""GAE against hand-computed numbers: no episode end, a terminated and a truncated episode."""

from __future__ import annotations

import numpy as np
import pytest

from ppo.gae import gae

GAMMA, LAM = 0.9, 0.8  # gamma * lambda = 0.72
REWARDS = np.array([[1.0], [2.0], [3.0]])
VALUES = np.array([[0.5], [1.0], [1.5]])
LAST = np.array([2.0])
NO = np.zeros((3, 1), dtype=bool)


def _gae(terminated: np.ndarray = NO, truncated: np.ndarray = NO, bootstrap: np.ndarray | None = None):
    boot = np.zeros((3, 1)) if bootstrap is None else bootstrap
    return gae(REWARDS, VALUES, LAST, terminated, truncated, boot, GAMMA, LAM)


def test_gae_returns_hand_computed() -> None:
    # delta_2 = 3 + 0.9 * 2.0 - 1.5 = 3.3;  delta_1 = 2 + 0.9 * 1.5 - 1.0 = 2.35;  delta_0 = 1 + 0.9 * 1.0 - 0.5 = 1.4
    # A_2 = 3.3;  A_1 = 2.35 + 0.72 * 3.3 = 4.726;  A_0 = 1.4 + 0.72 * 4.726 = 4.80272
    adv, ret = _gae()
    np.testing.assert_allclose(adv[:, 0], [4.80272, 4.726, 3.3])
    np.testing.assert_allclose(ret[:, 0], [5.30272, 5.726, 4.8])


def test_gae_terminal_state_cuts_bootstrap() -> None:
    # The episode fails at step 1: nothing follows it.  delta_1 = 2 + 0 - 1.0 = 1.0 and A_1 = 1.0 (no carry from the
    # next episode);  A_0 = 1.4 + 0.72 * 1.0 = 2.12;  step 2 starts a new episode: A_2 = 3.3.
    terminated = np.array([[False], [True], [False]])
    adv, ret = _gae(terminated=terminated, bootstrap=np.full((3, 1), 99.0))
    np.testing.assert_allclose(adv[:, 0], [2.12, 1.0, 3.3])
    np.testing.assert_allclose(ret[:, 0], [2.62, 2.0, 4.8])


def test_gae_truncated_episode_bootstraps_from_its_last_state() -> None:
    # Time limit at step 1, V(last state) = 4.0:  delta_1 = 2 + 0.9 * 4.0 - 1.0 = 4.6 = A_1;
    # A_0 = 1.4 + 0.72 * 4.6 = 4.712;  A_2 = 3.3 (the next episode, bootstrapped from last_values).
    truncated = np.array([[False], [True], [False]])
    bootstrap = np.array([[99.0], [4.0], [99.0]])
    adv, ret = _gae(truncated=truncated, bootstrap=bootstrap)
    np.testing.assert_allclose(adv[:, 0], [4.712, 4.6, 3.3])
    np.testing.assert_allclose(ret[:, 0], [5.212, 5.6, 4.8])


def test_gae_terminated_wins_over_truncated_and_columns_are_independent() -> None:
    rewards = np.concatenate([REWARDS, REWARDS], axis=1)
    values = np.concatenate([VALUES, VALUES], axis=1)
    terminated = np.array([[False, False], [True, False], [False, False]])
    truncated = np.array([[False, False], [True, False], [False, False]])
    adv, _ = gae(rewards, values, np.array([2.0, 2.0]), terminated, truncated, np.full((3, 2), 4.0), GAMMA, LAM)
    np.testing.assert_allclose(adv[:, 0], [2.12, 1.0, 3.3])
    np.testing.assert_allclose(adv[:, 1], [4.80272, 4.726, 3.3])


def test_gae_rejects_mismatched_shapes() -> None:
    with pytest.raises(ValueError, match="last_values has shape"):
        gae(REWARDS, VALUES, np.zeros(2), NO, NO, np.zeros((3, 1)), GAMMA, LAM)
    with pytest.raises(ValueError, match="values has shape"):
        gae(REWARDS, VALUES[:2], LAST, NO, NO, np.zeros((3, 1)), GAMMA, LAM)
