"""The running observation normaliser: statistics, clipping, excluded features, freezing and its state."""

from __future__ import annotations

import numpy as np
import pytest

from ppo.normalizer import RunningNormalizer, combine_moments, moments, normalized_mask


def test_running_statistics_hand_computed() -> None:
    # Feature 0 sees 1, 3 then 5, 7, 9: mean 5, var (16 + 4 + 0 + 4 + 16) / 5 = 8.
    # Feature 1 sees 2, 2 then 2, 2, 12: mean 4, var (4 * 4 + 64) / 5 = 16.
    norm = RunningNormalizer(np.ones(2, dtype=bool))
    norm.update(np.array([[1.0, 2.0], [3.0, 2.0]]))
    np.testing.assert_allclose(norm.mean, [2.0, 2.0])
    np.testing.assert_allclose(norm.var, [1.0, 0.0])
    norm.update(np.array([[5.0, 2.0], [7.0, 2.0], [9.0, 12.0]]))
    assert norm.count == 5
    np.testing.assert_allclose(norm.mean, [5.0, 4.0])
    np.testing.assert_allclose(norm.var, [8.0, 16.0])


def test_running_statistics_match_the_whole_data_set() -> None:
    x = np.random.default_rng(0).normal(3.0, 2.0, size=(1000, 4))
    norm = RunningNormalizer(np.ones(4, dtype=bool))
    for chunk in np.array_split(x, 7):
        norm.update(chunk)
    np.testing.assert_allclose(norm.mean, x.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(norm.var, x.var(axis=0), rtol=1e-10)


def test_merged_moments_give_the_numbers_of_update() -> None:
    """The collector's actor reports each step's moments; the learner merges them: bit for bit ``update``."""
    x = np.random.default_rng(1).normal(3.0, 2.0, size=(3, 8, 4))
    by_update, by_merge = RunningNormalizer(np.ones(4, dtype=bool)), RunningNormalizer(np.ones(4, dtype=bool))
    for step in x:
        by_update.update(step)
        by_merge.merge(moments(step))
    assert by_merge.count == by_update.count == 24
    assert np.array_equal(by_merge.mean, by_update.mean) and np.array_equal(by_merge.var, by_update.var)


def test_combined_moments_hand_computed() -> None:
    # Batches {1, 3} and {5, 7, 9}: together mean 5, var (16 + 4 + 0 + 4 + 16) / 5 = 8; one batch stays as it is.
    a, b = moments(np.array([[1.0], [3.0]])), moments(np.array([[5.0], [7.0], [9.0]]))
    count, mean, var = combine_moments([a, b])
    assert count == 5
    np.testing.assert_allclose(mean, [5.0])
    np.testing.assert_allclose(var, [8.0])
    assert combine_moments([a]) is a
    empty = (0, np.zeros(1), np.zeros(1))  # a process without characters left: adds nothing
    assert combine_moments([empty, a]) is a and combine_moments([a, empty]) is a


def test_normalize_clips_floors_the_std_and_skips_excluded_entries() -> None:
    norm = RunningNormalizer(np.array([True, True, False]), clip=5.0, epsilon=0.01)
    norm.update(np.array([[0.0, 1.0, 0.5], [2.0, 1.0, -0.5]]))  # mean 1, 1, 0; std 1, 0, 0.5
    out = norm.normalize(np.array([[3.0, 1.02, 0.7], [100.0, 0.0, -0.7]]))
    assert out.dtype == np.float32
    # (3 - 1) / 1 = 2; (1.02 - 1) / max(0, 0.01) = 2; excluded entries pass through; 99 and -100 clip to +-5.
    np.testing.assert_allclose(out, [[2.0, 2.0, 0.7], [5.0, -5.0, -0.7]], rtol=1e-6)


def test_max_samples_freezes_the_statistics() -> None:
    norm = RunningNormalizer(np.ones(1, dtype=bool), max_samples=2)
    norm.update(np.array([[1.0], [3.0]]))
    norm.update(np.array([[100.0]]))
    assert norm.frozen and norm.count == 2 and norm.mean[0] == 2.0


def test_state_dict_round_trip_and_mismatch() -> None:
    norm = RunningNormalizer(np.array([True, False]))
    norm.update(np.array([[1.0, 2.0], [3.0, 4.0]]))
    other = RunningNormalizer(np.array([True, False]))
    other.load_state_dict(norm.state_dict())
    assert other.count == 2 and np.array_equal(other.mean, norm.mean) and np.array_equal(other.var, norm.var)
    with pytest.raises(ValueError, match="does not match this observation"):
        RunningNormalizer(np.ones(3, dtype=bool)).load_state_dict(norm.state_dict())


def test_normalized_mask_excludes_named_features() -> None:
    layout = {"a": slice(0, 2), "phase": slice(2, 4)}
    np.testing.assert_array_equal(normalized_mask(layout, ["phase"]), [True, True, False, False])
    with pytest.raises(ValueError, match="unknown observation features \\['phse'\\]"):
        normalized_mask(layout, ["phse"])
