"""The linear feedback regression and the time index of its policies."""

from __future__ import annotations

import numpy as np

from samcon.feedback import ClipPlan, fit_linear, segment_of


def test_regression_recovers_a_known_linear_map() -> None:
    rng = np.random.default_rng(0)
    gain, bias = rng.normal(size=(28, 16)), rng.normal(size=28)
    s = rng.normal(size=(200, 16)) * rng.uniform(0.01, 2.0, size=16) + rng.normal(size=16)
    m, b = fit_linear(s, s @ gain.T + bias, ridge=0.0)
    np.testing.assert_allclose(m, gain, atol=1e-9)
    np.testing.assert_allclose(b, bias, atol=1e-9)
    # The lectures' formula, on centred data: M = [(S^T S)^-1 S^T A]^T.
    a = s @ gain.T + bias + 0.01 * rng.normal(size=(200, 28))
    sc, ac = s - s.mean(0), a - a.mean(0)
    m, b = fit_linear(s, a, ridge=0.0)
    np.testing.assert_allclose(m, (np.linalg.inv(sc.T @ sc) @ sc.T @ ac).T, atol=1e-9)
    np.testing.assert_allclose(b, a.mean(0) - m @ s.mean(0), atol=1e-12)


def test_ridge_shrinks_and_one_start_state_gives_no_gain() -> None:
    rng = np.random.default_rng(1)
    s = rng.normal(size=(50, 4))
    a = s @ np.diag([1.0, 2.0, 3.0, 4.0])[:2].T
    free, _ = fit_linear(s, a, 0.0)
    shrunk, _ = fit_linear(s, a, 1.0)
    assert np.linalg.norm(shrunk) < np.linalg.norm(free)
    same = np.ones((10, 4))  # every sample from one state: M = 0, b = the mean offset
    m, b = fit_linear(same, np.arange(20.0).reshape(10, 2), 0.1)
    np.testing.assert_allclose(m, 0.0, atol=1e-9)
    np.testing.assert_allclose(b, [9.0, 10.0], atol=1e-9)


def test_segment_of_a_frame() -> None:
    plan = ClipPlan(np.zeros((18, 1)), np.array([0, 6, 12, 18]), np.zeros((3, 1, 1)), np.zeros((3, 1)))
    assert [segment_of(plan, f, None) for f in (0, 5, 6, 17, 30)] == [0, 0, 1, 2, 2]
    # Loop of 12 frames, tracked to 18: frame 20 is frame 8 a cycle earlier, frame 41 frame 17 two cycles earlier.
    assert segment_of(plan, 20, 12) == 1 and segment_of(plan, 41, 12) == 2


def test_a_later_search_joins_the_regression_of_the_segments_it_covers() -> None:
    from types import SimpleNamespace

    from samcon.config import FeedbackConfig
    from samcon.track import fit_samples

    rng = np.random.default_rng(2)
    gain = rng.normal(size=(3, 2, 4))  # a known map per segment of a 3-segment grid from frame 0
    # The search from frame 0 visits too few distinct states to pin segment 1's map down (2 states in 4-D) ...
    s_main = [np.zeros((5, 4)), np.repeat(rng.normal(size=(2, 4)), 5, axis=0), rng.normal(size=(40, 4))]
    main = SimpleNamespace(bounds=np.array([0, 6, 12, 18]), features=s_main,
                           actions=[s @ g.T for s, g in zip(s_main, gain, strict=True)])  # fmt: skip
    # ... a search from frame 6 (segments 1 and 2 of the grid) adds states that do.
    s_later = [rng.normal(size=(40, 4)), rng.normal(size=(40, 4))]
    later = SimpleNamespace(bounds=np.array([6, 12, 18]), features=s_later,
                            actions=[s @ g.T for s, g in zip(s_later, gain[1:], strict=True)])  # fmt: skip
    cfg = FeedbackConfig(ridge=0.0)
    alone, _ = fit_samples(main, FeedbackConfig(ridge=1e-6))
    pooled, _ = fit_samples(main, cfg, [later])
    assert np.abs(alone[1] - gain[1]).max() > 0.1
    np.testing.assert_allclose(pooled[1:], gain[1:], atol=1e-9)


def test_nearest_anchor_follows_the_nearest_searched_path() -> None:
    gain = np.array([[[1.0, 0.0], [0.0, 2.0]]])  # one segment, 2 actuators, 2 features
    # Path 0 starts the segment at s* = (1, 0) with offset (10, 10), path 1 at (0, 0) with (20, 30); path 2 does not
    # cover it (NaN) and must never be chosen, though its features would be nearest.
    feats = np.array([[[1.0, 0.0], [0.0, 0.0], [np.nan, np.nan]]])
    offs = np.array([[[10.0, 10.0], [20.0, 30.0], [np.nan, np.nan]]])
    plan = ClipPlan(np.zeros((6, 2)), np.array([0, 6]), gain, np.zeros((1, 2)), feats, offs, np.array([1.0, 0.1]))
    # s = (0.8, 0.05): scaled squared distances 0.04 + 0.25 to path 0, 0.64 + 0.25 to path 1: path 0,
    # a = (10, 10) + M (-0.2, 0.05) = (9.8, 10.1).
    np.testing.assert_allclose(plan.offset(0, np.array([0.8, 0.05])), [9.8, 10.1])
    # s = (0.4, 0.3): 0.36 + 9 to path 0, 0.16 + 9 to path 1 (feature 2 is scaled by 0.1): path 1,
    # a = (20, 30) + M (0.4, 0.3) = (20.4, 30.6).
    np.testing.assert_allclose(plan.offset(0, np.array([0.4, 0.3])), [20.4, 30.6])
    # With one path, the anchor is the path anchor b = a* - M s*: the same offset for any s.
    one = ClipPlan(plan.targets, plan.bounds, gain, offs[:, 0] - np.einsum("kad,kd->ka", gain, feats[:, 0]),
                   feats[:, :1], offs[:, :1], np.ones(2))  # fmt: skip
    bare = ClipPlan(plan.targets, plan.bounds, gain, one.bias)
    for s in (np.array([0.3, -2.0]), np.array([5.0, 1.0])):
        np.testing.assert_allclose(one.offset(0, s), bare.offset(0, s), atol=1e-12)


def test_path_anchors_put_each_search_on_the_segments_it_covers() -> None:
    from types import SimpleNamespace

    import pytest

    from samcon.track import path_anchors

    rng = np.random.default_rng(3)
    main = SimpleNamespace(clip="walk", bounds=np.array([0, 6, 12, 18]), path_features=rng.normal(size=(3, 2)),
                           offsets=rng.normal(size=(3, 4)), features=[np.array([[0.0, 0.0], [2.0, 4.0]])])  # fmt: skip
    later = SimpleNamespace(clip="walk", bounds=np.array([12, 18]), path_features=rng.normal(size=(1, 2)),
                            offsets=rng.normal(size=(1, 4)), features=[np.array([[1.0, 2.0], [3.0, 6.0]])])  # fmt: skip
    feats, offs, scale = path_anchors(main, [later])
    assert feats.shape == (3, 2, 2) and offs.shape == (3, 2, 4)
    np.testing.assert_array_equal(feats[:, 0], main.path_features)
    np.testing.assert_array_equal(offs[2, 1], later.offsets[0])
    assert np.isnan(feats[:2, 1]).all() and np.isnan(offs[:2, 1]).all()
    # The spread of the pooled regression features (0, 2, 1, 3) and (0, 4, 2, 6): std sqrt(1.25) and sqrt(5).
    np.testing.assert_allclose(scale, [np.sqrt(1.25), np.sqrt(5.0)])
    # A search that ends early covers its own segments only; one from frame 9 (between segment starts) or one
    # running past the grid's end is not on the grid: refused.
    early = SimpleNamespace(**{**vars(later), "bounds": np.array([6, 12])})
    feats, _, _ = path_anchors(main, [early])
    np.testing.assert_array_equal(feats[1, 1], later.path_features[0])
    assert np.isnan(feats[[0, 2], 1]).all()
    past = {"bounds": np.array([12, 18, 24]), "path_features": np.zeros((2, 2)), "offsets": np.zeros((2, 4))}
    for bad in ({"bounds": np.array([9, 18])}, past):
        with pytest.raises(ValueError, match="segment grid"):
            path_anchors(main, [SimpleNamespace(**{**vars(later), **bad})])


def _cycle_paths(rng: np.random.Generator, gain: np.ndarray) -> tuple[object, object]:
    """A search over 2 cycles of 2 segments each (grid 0, 3, 6, 9, 12) and one from frame 6 (segments 2, 3), whose
    samples follow the known map of their phase."""
    from types import SimpleNamespace

    def path(first: int, count: int, states: list[np.ndarray]) -> SimpleNamespace:
        return SimpleNamespace(clip="walk", bounds=np.arange(first, first + count + 1) * 3, features=states,
                               actions=[s @ gain[(first + k) % 2].T for k, s in enumerate(states)],
                               path_features=rng.normal(size=(count, 4)),
                               offsets=rng.normal(size=(count, 3)))  # fmt: skip

    # Phase 0's samples in cycle 0 are 2 distinct states (too few for 4 features); cycle 1's pin its map down.
    main = path(0, 4, [np.repeat(rng.normal(size=(2, 4)), 5, axis=0), rng.normal(size=(3, 4)),
                       rng.normal(size=(20, 4)), rng.normal(size=(20, 4))])  # fmt: skip
    return main, path(2, 2, [rng.normal(size=(20, 4)), rng.normal(size=(20, 4))])


def test_per_phase_fit_pools_every_cycle_of_every_search() -> None:
    from samcon.config import FeedbackConfig
    from samcon.track import fit_samples

    rng = np.random.default_rng(5)
    gain = rng.normal(size=(2, 3, 4))  # a known map per phase (2 segments per cycle), 3 actuators, 4 features
    main, later = _cycle_paths(rng, gain)
    per_time, _ = fit_samples(main, FeedbackConfig(ridge=1e-6))
    assert per_time.shape == (4, 3, 4) and np.abs(per_time[0] - gain[0]).max() > 0.1
    per_phase, bias = fit_samples(main, FeedbackConfig(ridge=0.0), [later], cycle_segments=2)
    assert per_phase.shape == (2, 3, 4) and bias.shape == (2, 3)
    np.testing.assert_allclose(per_phase, gain, atol=1e-9)
    np.testing.assert_allclose(bias, 0.0, atol=1e-9)


def test_per_phase_anchors_hold_every_cycle_of_every_path() -> None:
    from samcon.track import path_anchors

    rng = np.random.default_rng(6)
    main, later = _cycle_paths(rng, rng.normal(size=(2, 3, 4)))
    feats, offs, _ = path_anchors(main, [later], cycle_segments=2)
    # 2 phases; columns p Q + q for path p in cycle q, Q = 2 cycles: main's cycles 0, 1 and the later path's cycle 1.
    assert feats.shape == (2, 4, 4) and offs.shape == (2, 4, 3)
    for phase in (0, 1):
        np.testing.assert_array_equal(feats[phase, 0], main.path_features[phase])
        np.testing.assert_array_equal(feats[phase, 1], main.path_features[2 + phase])
        np.testing.assert_array_equal(offs[phase, 3], later.offsets[phase])
        assert np.isnan(feats[phase, 2]).all() and np.isnan(offs[phase, 2]).all()


def test_extra_starts_take_every_segment_start_of_the_first_cycle_in_turn() -> None:
    from samcon.track import extra_starts

    grid = np.array([0, 6, 12, 18, 23, 29, 35, 41, 47, 53, 58, 64, 70, 76, 82, 88, 94])
    rng = np.random.default_rng(0)
    few = extra_starts(grid, 76, 5, rng)
    assert len(set(few)) == 5 and set(few) <= set(grid[1:13])
    many = extra_starts(grid, 76, 30, rng)  # 12 starts in the cycle: each twice, and 6 more, distinct
    counts = np.array([many.count(int(f)) for f in grid[1:13]])
    assert len(many) == 30 and counts.min() == 2 and (counts == 3).sum() == 6
    # A one-shot clip: every segment start of the tracked range.
    assert extra_starts(np.array([0, 6, 12, 15]), 0, 2, rng) == [6, 12]
