"""PARC's adaptive motion weighting: the failure-rate EMA and the bucket weights."""

from __future__ import annotations

import numpy as np
import pytest

from common.config import ConfigError, from_dict
from common.sim.motion_weights import MotionWeightConfig, MotionWeights, bucket_weights

THRESHOLDS, WEIGHTS = (0.1, 0.3, 0.5, 0.7), (0.1, 0.3, 0.5, 0.7, 1.0)


def test_failure_rate_buckets_hand_computed() -> None:
    rates = np.array([0.0, 0.05, 0.1, 0.29, 0.3, 0.5, 0.69, 0.7, 1.0])
    expected = [0.1, 0.1, 0.3, 0.3, 0.5, 0.7, 0.7, 1.0, 1.0]  # "< 0.1 -> 0.1, < 0.3 -> 0.3, ..., else 1.0"
    np.testing.assert_allclose(bucket_weights(rates, THRESHOLDS, WEIGHTS, 0.01), expected)


def test_min_weight_is_a_floor() -> None:
    np.testing.assert_allclose(bucket_weights(np.array([0.0, 0.9]), (0.5,), (0.0, 1.0), 0.01), [0.01, 1.0])


def test_failure_rate_ema_hand_computed() -> None:
    mw = MotionWeights(2, MotionWeightConfig())
    np.testing.assert_allclose(mw.failure_rate, [1.0, 1.0])  # every clip starts as presumed hard
    # Character 0 (clip 0) succeeds (truncated), character 1 (clip 1) is still running, character 2 (clip 1) fails.
    mw.record(np.array([0, 1, 1]), terminated=np.array([False, False, True]), truncated=np.array([True, False, False]))
    np.testing.assert_allclose(mw.failure_rate, [0.99, 1.0])  # 0.99 * 1 + 0.01 * 0;  0.99 * 1 + 0.01 * 1
    mw.record(np.array([0]), terminated=np.array([True]), truncated=np.array([False]))
    np.testing.assert_allclose(mw.failure_rate, [0.9901, 1.0])  # 0.99 * 0.99 + 0.01
    np.testing.assert_allclose(mw.weights(), [1.0, 1.0])


def test_many_successes_lower_the_weight() -> None:
    mw = MotionWeights(1, MotionWeightConfig())
    for _ in range(230):  # 0.99^230 = 0.0991 < 0.1
        mw.record(np.array([0]), np.array([False]), np.array([True]))
    assert mw.failure_rate[0] == pytest.approx(0.99**230)
    np.testing.assert_allclose(mw.weights(), [0.1])


def test_state_round_trip_and_clip_count_check() -> None:
    mw = MotionWeights(2, MotionWeightConfig())
    mw.failure_rate[:] = [0.2, 0.8]
    other = MotionWeights(2, MotionWeightConfig())
    other.load_state_dict(mw.state_dict())
    np.testing.assert_allclose(other.weights(), [0.3, 1.0])
    with pytest.raises(ValueError, match="saved for 2 clips, the library has 3"):
        MotionWeights(3, MotionWeightConfig()).load_state_dict(mw.state_dict())


def test_config_checks_the_buckets() -> None:
    with pytest.raises(ConfigError, match="one entry more than thresholds"):
        from_dict(MotionWeightConfig, {"thresholds": [0.1], "bucket_weights": [0.1]})
    with pytest.raises(ConfigError, match="thresholds must increase"):
        from_dict(MotionWeightConfig, {"thresholds": [0.5, 0.1], "bucket_weights": [0.1, 0.2, 0.3]})


def test_gym_weights_multiply_a_learners_fixed_weights_and_follow_enabled() -> None:
    mw = MotionWeights(3, MotionWeightConfig())
    mw.failure_rate[:] = [0.05, 0.4, 0.9]  # buckets 0.1, 0.5, 1.0
    np.testing.assert_allclose(mw.gym_weights(), [0.1, 0.5, 1.0])
    np.testing.assert_allclose(mw.gym_weights(np.array([10.0, 1.0, 2.0])), [1.0, 0.5, 2.0])
    off = MotionWeights(3, MotionWeightConfig(enabled=False))
    assert off.gym_weights() is None
    np.testing.assert_allclose(off.gym_weights(np.array([10.0, 1.0, 2.0])), [10.0, 1.0, 2.0])


def test_a_block_is_recorded_step_by_step_in_character_order() -> None:
    """Two steps of three characters; the same clip ending twice in one step is two EMA updates, in order."""
    mw = MotionWeights(2, MotionWeightConfig(ema_weight=0.5))
    frames = {"clip": np.array([[0, 0, 1], [0, 1, 1]]),
              "terminated": np.array([[True, False, False], [False, False, True]]),
              "truncated": np.array([[False, True, False], [False, False, False]])}  # fmt: skip
    mw.record_block(frames)
    # Step 0: clip 0 fails (1.0), then succeeds (0.5). Step 1: clip 1 fails (1.0). Weights: 0.5 is not < 0.5, so 0.7.
    np.testing.assert_allclose(mw.failure_rate, [0.5, 1.0])
    assert mw.charts() == {"charts/failure_rate_mean": 0.75, "charts/failure_rate_max": 1.0,
                           "charts/clip_weight_min": 0.7, "charts/clip_weight_max": 1.0}  # fmt: skip
    assert mw.clip_charts(["walk", "run"], limit=1) == {"charts/failure_rate/walk": 0.5}
