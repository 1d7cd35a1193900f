"""The shared evaluator: deterministic, per-clip table of every metric, episode bookkeeping."""

from __future__ import annotations

import functools

import numpy as np

from common.evaluate import EvalConfig, evaluate, reference_policy
from common.humanoid import Humanoid
from common.metrics import METRIC_NAMES
from common.motion_dataset import load_motions


def test_evaluator_is_deterministic_and_complete() -> None:
    h = Humanoid()
    lib = load_motions(["walk", "kick"], h)
    cfg = EvalConfig(starts_per_clip=2, max_frames=60, threads=1)
    policy = functools.partial(reference_policy, humanoid=h)
    a = evaluate(policy, lib, h, cfg)
    b = evaluate(policy, lib, h, cfg)
    for key in METRIC_NAMES:
        np.testing.assert_array_equal(a.per_clip[key], b.per_clip[key])
        assert np.isfinite(a.per_clip[key]).all()
    assert a.clips == ["walk", "kick"]
    # Kick is one-shot: its second start has fewer than 60 frames left; walk episodes may run the full 60.
    assert a.episode_max[0].tolist() == [60, 60] and a.episode_max[1, 1] < 60
    assert np.all(a.episode_length <= a.episode_max)
    # Open loop falls over within about a second of walking (gym calibration: ~47 frames).
    assert a.per_clip["survival"][0] == 0.0 and a.per_clip["success"][0] == 0.0
    assert 40 <= a.episode_length[0, 0] <= 55
    assert a.overall["mpjpe_g"] == np.mean(a.per_clip["mpjpe_g"])
    assert "eval/mpjpe_g" in a.as_metrics() and "walk" in a.table()
