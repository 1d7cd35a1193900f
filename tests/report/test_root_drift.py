"""benchmarks/root_drift.py: the split of the root's offset into along / cross / down / heading, by hand."""

from __future__ import annotations

import numpy as np
import pytest

from tests.benchmark_module import benchmark_module


def _module():
    return benchmark_module("root_drift")


def test_offsets_split_along_the_direction_of_travel() -> None:
    split = _module().split
    T, N = 40, 2
    t = np.arange(T)[:, None, None] / 60.0
    # Episode 0: the reference walks +y at 1 m/s; the character is 0.2 m ahead, 0.1 m to +x (the right of +y travel)
    # and 5 cm low, turned +0.1 rad against -0.05. Episode 1: the reference runs -x at 3 m/s; the character lags
    # 0.3 m, stands 0.4 m to -y (the left of -x travel: facing -x, +y is on the right) and is turned across the +-pi
    # seam (3.1 vs -3.1 rad).
    ref_vel = np.zeros((T, N, 3))
    ref_vel[:, 0, 1], ref_vel[:, 1, 0] = 1.0, -3.0
    ref_pos = t * ref_vel + np.array([0.0, 0.0, 0.9])
    sim_pos = ref_pos + np.array([[0.1, 0.2, -0.05], [0.3, -0.4, 0.0]])
    d = {"ref_vel": ref_vel, "ref_pos": ref_pos, "sim_pos": sim_pos,
         "sim_yaw": np.tile([0.1, 3.1], (T, 1)), "ref_yaw": np.tile([-0.05, -3.1], (T, 1))}  # fmt: skip
    parts = split(d, smooth=3)
    mid = T // 2
    assert parts["along"][mid] == pytest.approx([0.2, -0.3])
    assert parts["cross"][mid] == pytest.approx([-0.1, 0.4])
    assert parts["down"][mid] == pytest.approx([0.05, 0.0])
    assert parts["distance"][mid] == pytest.approx([np.hypot(0.1, 0.2), 0.5])
    assert parts["heading"][mid] == pytest.approx([np.degrees(0.15), np.degrees(6.2 - 2 * np.pi)])
    assert parts["speed_ratio"] == pytest.approx([1.0, 1.0])


def test_a_standing_reference_has_no_direction_and_lag_rate_fits_a_line() -> None:
    module = _module()
    T = 30
    zeros = np.zeros((T, 1, 3))
    d = {"ref_vel": zeros, "ref_pos": zeros, "sim_pos": zeros + 0.1, "sim_yaw": np.zeros((T, 1)),
         "ref_yaw": np.zeros((T, 1))}  # fmt: skip
    parts = module.split(d, smooth=2)
    assert np.isnan(parts["along"]).all() and np.isnan(parts["cross"]).all()
    along = (np.arange(T) / 60.0 * -0.25)[:, None]  # falling behind at 25 cm/s
    assert module.lag_rate(along, 1 / 60.0) == pytest.approx(-25.0)


def test_episode_rows_by_hand() -> None:
    rows = _module().episode_rows
    # Two episodes of 4 frames; the second ends after 2 (its later frames are past its horizon and do not count).
    distance = np.array([[0.0, 0.1], [0.2, 0.3], [0.4, 9.0], [0.2, 9.0]])
    got = rows(distance, np.array([4, 2]), [1, 3])
    assert got[0]["at"] == pytest.approx([0.2, 0.2]) and got[0]["mean"] == pytest.approx(0.2)
    assert got[0]["max"] == pytest.approx(0.4)
    assert got[1]["at"][0] == pytest.approx(0.3) and np.isnan(got[1]["at"][1])
    assert got[1]["mean"] == pytest.approx(0.2) and got[1]["max"] == pytest.approx(0.3)
    assert got[0]["share"] == pytest.approx(0.5) and got[1]["share"] == pytest.approx(0.5)
