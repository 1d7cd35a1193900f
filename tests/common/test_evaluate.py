"""The shared evaluator: deterministic, per-clip table of every metric, episode bookkeeping."""

from __future__ import annotations

import functools
from types import SimpleNamespace

import numpy as np
import pytest

import common.evaluation.evaluate as E
from common.character.humanoid import Humanoid
from common.character.state import CharacterState
from common.evaluation.evaluate import EvalConfig, evaluate, reference_policy
from common.evaluation.metrics import METRIC_NAMES
from common.motion.dataset import load_motions


def test_evaluator_is_deterministic_and_complete() -> None:
    h = Humanoid()
    lib = load_motions(["walk", "kick"], h)
    cfg = EvalConfig(starts_per_clip=2, max_frames=60, threads=1)
    policy = functools.partial(reference_policy, humanoid=h)
    a = evaluate(policy, lib, h, cfg)
    b = evaluate(policy, lib, h, cfg)
    for key in METRIC_NAMES:
        np.testing.assert_array_equal(a.per_clip[key], b.per_clip[key])
        # The success-only figures have no episode to average where none succeeded.
        finite = a.per_clip["success"] > 0 if key.endswith("_succ") else np.ones(2, dtype=bool)
        assert np.isfinite(a.per_clip[key][finite]).all() and np.isnan(a.per_clip[key][~finite]).all()
    assert a.clips == ["walk", "kick"]
    # Kick is one-shot: its second start has fewer than 60 frames left; walk episodes may run the full 60.
    assert a.episode_max[0].tolist() == [60, 60] and a.episode_max[1, 1] < 60
    assert np.all(a.episode_length <= a.episode_max)
    # Open loop falls over within about a second of walking (gym calibration: ~47 frames).
    assert a.per_clip["survival"][0] == 0.0 and a.per_clip["success"][0] == 0.0
    assert 40 <= a.episode_length[0, 0] <= 55
    assert a.overall["mpjpe_g"] == np.mean(a.per_clip["mpjpe_g"])
    assert "eval/mpjpe_g" in a.as_metrics() and "walk" in a.table()


class ScriptedGym:
    """Stands in for TrackingGym: character i sits ``shift[t, i]`` metres off its reference along x at frame t (every
    body alike), fails at ``fail_at[i]`` and blows up at ``diverge_at[i]`` (put back on its reference, as the gym
    does). The reference is the real clip's."""

    shift: np.ndarray
    fail_at: np.ndarray
    diverge_at: np.ndarray

    def __init__(self, config, library, humanoid) -> None:  # noqa: ANN001 (TrackingGym's signature)
        self.library, self.t = library, 0

    def _state(self, t: int) -> tuple[CharacterState, CharacterState]:
        ref = self.library.query(self.clips, self.times + t * self.library.dt)
        sim = CharacterState(**{k: v.copy() for k, v in vars(ref).items()})
        sim.body_pos[..., 0] += self.shift[t - 1][:, None] if t else 0.0
        return sim, ref

    def _result(self, t: int, terminated: np.ndarray, diverged: np.ndarray) -> SimpleNamespace:
        sim, ref = self._state(t)
        if diverged.any():
            sim = CharacterState(**{k: np.where(diverged.reshape(-1, *[1] * (v.ndim - 1)), getattr(ref, k), v)
                                    for k, v in vars(sim).items()})  # fmt: skip
        return SimpleNamespace(sim=sim, final_sim=sim, final_ref=ref, terminated=terminated, diverged=diverged)

    def reset(self, clips: np.ndarray, times: np.ndarray) -> SimpleNamespace:
        self.clips, self.times = clips, times
        none = np.zeros(len(clips), dtype=bool)
        return self._result(0, none, none)

    def step(self, targets: np.ndarray, autoreset: bool) -> SimpleNamespace:
        assert not autoreset
        self.t += 1
        diverged = self.diverge_at == self.t - 1
        return self._result(self.t, (self.fail_at == self.t - 1) | diverged, diverged)

    def close(self) -> None:
        pass


@pytest.fixture
def scripted(monkeypatch: pytest.MonkeyPatch):  # noqa: ANN201
    h = Humanoid()
    lib = load_motions(["walk"], h)
    monkeypatch.setattr(E, "TrackingGym", ScriptedGym)
    return h, lib


def test_full_horizon_charges_a_fall_for_every_frame_after_it(scripted) -> None:  # noqa: ANN001
    h, lib = scripted
    # Character 0 tracks 1 cm off for frames 0-4, fails at frame 5 and lies 10 cm off from then on; character 1
    # stays 2 cm off for all 10 frames and never fails.
    ScriptedGym.shift = np.array([[0.01, 0.02]] * 5 + [[0.10, 0.02]] * 5)
    ScriptedGym.fail_at, ScriptedGym.diverge_at = np.array([5, -1]), np.array([-1, -1])
    full = evaluate(lambda r: np.zeros((2, h.nu)), lib, h, EvalConfig(starts_per_clip=2, max_frames=10, threads=1))
    # Every body moved alike: MPJPE-g is the shift, MPJPE-l zero. Frame-weighted over both episodes' 20 frames:
    # (5 x 10 + 5 x 100 + 10 x 20) / 20 = 37.5 mm.
    assert full.per_clip["mpjpe_g"][0] == pytest.approx(37.5)
    assert full.per_clip["mpjpe_l"][0] == pytest.approx(0.0, abs=1e-9)
    assert full.per_clip["survival"][0] == 0.5 and full.per_clip["success"][0] == 0.5
    # Episode 0 played 6 of 10 frames before failing (the failing frame counts), episode 1 all 10.
    assert full.episode_length.tolist() == [[6, 10]]
    assert full.per_clip["episode_len_ratio"][0] == pytest.approx((0.6 + 1.0) / 2)
    # Success-only (PHC/UHC): episode 1 alone, 20 mm.
    assert full.per_clip["mpjpe_g_succ"][0] == pytest.approx(20.0)
    # The earlier protocol stops episode 0 at its failure: (5 x 10 + 100 + 10 x 20) / 16 = 21.875 mm, lower than
    # the full horizon's 37.5 mm: failing sooner paid there.
    ScriptedGym.t = 0
    short = evaluate(lambda r: np.zeros((2, h.nu)), lib, h,
                     EvalConfig(starts_per_clip=2, max_frames=10, threads=1, full_horizon=False))  # fmt: skip
    assert short.per_clip["mpjpe_g"][0] == pytest.approx(21.875)
    assert short.episode_length.tolist() == [[6, 10]] and short.per_clip["survival"][0] == 0.5


def test_a_blown_up_episode_is_scored_frozen_not_on_the_reference(scripted) -> None:  # noqa: ANN001
    h, lib = scripted
    # Character 0 blows up at frame 3 and is put back on its reference pose by the gym; it must be scored in its
    # state before that (frame 2: the reference of frame 2, 1 cm off along x) against the moving reference.
    ScriptedGym.shift = np.full((8, 1), 0.01)
    ScriptedGym.fail_at, ScriptedGym.diverge_at = np.array([-1]), np.array([3])
    ScriptedGym.t = 0
    res = evaluate(lambda r: np.zeros((1, h.nu)), lib, h, EvalConfig(starts_per_clip=1, max_frames=8, threads=1))
    ref = lib.query(np.zeros(9, dtype=np.int64), np.arange(9) * lib.dt)  # frames 0-8 of the clip from t = 0
    frozen = ref.body_pos[3] + np.array([0.01, 0.0, 0.0])  # the state reached at frame 2 (= reference time 3 dt)
    expected = [10.0] * 3 + [1000 * np.linalg.norm(ref.body_pos[t + 1] - frozen, axis=-1).mean() for t in range(3, 8)]
    assert res.per_clip["mpjpe_g"][0] == pytest.approx(np.mean(expected))
    assert res.per_clip["survival"][0] == 0.0 and res.episode_length.tolist() == [[4]]
