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
    # The motion-quality measures exist for the open-loop policy, are finite and not zero (it falls; its targets, the
    # reference's angles, change; the clips' feet touch the floor), and show in the table.
    for key in ("accel_err", "vel_err", "foot_slide", "foot_slide_ref", "target_jitter"):
        assert np.all(np.isfinite(a.per_clip[key])) and np.all(a.per_clip[key] > 0), key
        assert f"eval/{key}" in a.as_metrics() and key in a.table()


def test_the_motion_measures_leave_every_other_figure_unchanged(monkeypatch: pytest.MonkeyPatch) -> None:
    h = Humanoid()
    lib = load_motions(["walk"], h)
    cfg = EvalConfig(starts_per_clip=2, max_frames=60, threads=1)
    policy = functools.partial(reference_policy, humanoid=h)
    with_motion = evaluate(policy, lib, h, cfg)
    monkeypatch.setattr(E._MotionTrace, "add", lambda *args: None)  # as before the motion measures existed
    without = evaluate(policy, lib, h, cfg)
    for key in set(METRIC_NAMES) - {*E.DIFF_METRICS, *E.SLIDE_METRICS}:
        np.testing.assert_array_equal(with_motion.per_clip[key], without.per_clip[key])
        assert with_motion.overall[key] == without.overall[key] or np.isnan(without.overall[key])
    np.testing.assert_array_equal(with_motion.episode_length, without.episode_length)


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
    ScriptedGym.t = 0
    full = evaluate(quadratic_targets(2, h.nu), lib, h, EvalConfig(starts_per_clip=2, max_frames=10, threads=1))
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
    # Motion quality over the failed frames too. Velocity: the 9 steps of each episode; character 0 jumps 9 cm
    # (every body) at step 5, otherwise both move as the reference: 90 / 18 = 5 mm/frame. Acceleration: that jump
    # is +9 cm at triple (3, 4, 5) and -9 cm at (4, 5, 6): 180 / 16 = 11.25 mm/frame^2.
    assert full.per_clip["vel_err"][0] == pytest.approx(5.0)
    assert full.per_clip["accel_err"][0] == pytest.approx(11.25)
    # Jitter: character 0's targets 0.01 t^2 (second difference 0.02), character 1's constant: 0.01 rad/frame^2.
    assert full.per_clip["target_jitter"][0] == pytest.approx(0.01)
    # The earlier protocol stops episode 0 at its failure: (5 x 10 + 100 + 10 x 20) / 16 = 21.875 mm, lower than
    # the full horizon's 37.5 mm: failing sooner paid there.
    ScriptedGym.t = 0
    short = evaluate(quadratic_targets(2, h.nu), lib, h,
                     EvalConfig(starts_per_clip=2, max_frames=10, threads=1, full_horizon=False))  # fmt: skip
    assert short.per_clip["mpjpe_g"][0] == pytest.approx(21.875)
    assert short.episode_length.tolist() == [[6, 10]] and short.per_clip["survival"][0] == 0.5
    # Its differences stop at the failure too: episode 0 has 5 steps and 4 triples, episode 1 nine and eight, so
    # the jump at step 5 is scored once (velocity 90 / 14) and its acceleration once (90 / 12).
    assert short.per_clip["vel_err"][0] == pytest.approx(90.0 / 14)
    assert short.per_clip["accel_err"][0] == pytest.approx(90.0 / 12)
    assert short.per_clip["target_jitter"][0] == pytest.approx(4 * 0.02 / 12)


def quadratic_targets(n: int, nu: int) -> E.Policy:
    """A scripted policy: character 0's targets 0.01 t^2 rad at its t-th call (every actuator), the others' zero."""
    calls = iter(range(10**6))

    def policy(result: SimpleNamespace) -> np.ndarray:
        targets = np.zeros((n, nu))
        targets[0] = 0.01 * next(calls) ** 2
        return targets

    return policy


def test_the_sliding_of_feet_that_keep_to_the_reference_is_the_references(scripted) -> None:  # noqa: ANN001
    h, lib = scripted
    # Both characters sit a constant 2 cm off along x: every foot moves and touches the floor as the reference's.
    ScriptedGym.shift = np.full((30, 2), 0.02)
    ScriptedGym.fail_at, ScriptedGym.diverge_at = np.array([-1, -1]), np.array([-1, -1])
    ScriptedGym.t = 0
    res = evaluate(lambda r: np.zeros((2, h.nu)), lib, h, EvalConfig(starts_per_clip=2, max_frames=30, threads=1))
    assert res.per_clip["foot_slide"][0] == pytest.approx(res.per_clip["foot_slide_ref"][0], rel=1e-12)
    assert res.per_clip["vel_err"][0] == pytest.approx(0.0, abs=1e-9)
    assert res.overall["foot_slide_ref"] > 0.0


def test_a_blown_up_episode_is_scored_frozen_not_on_the_reference(scripted) -> None:  # noqa: ANN001
    h, lib = scripted
    # Character 0 blows up at frame 3 and is put back on its reference pose by the gym; it must be scored in its
    # state before that (frame 2: the reference of frame 2, 1 cm off along x) against the moving reference.
    ScriptedGym.shift = np.full((8, 1), 0.01)
    ScriptedGym.fail_at, ScriptedGym.diverge_at = np.array([-1]), np.array([3])
    ScriptedGym.t = 0
    res = evaluate(quadratic_targets(1, h.nu), lib, h, EvalConfig(starts_per_clip=1, max_frames=8, threads=1))
    ref = lib.query(np.zeros(9, dtype=np.int64), np.arange(9) * lib.dt)  # frames 0-8 of the clip from t = 0
    frozen = ref.body_pos[3] + np.array([0.01, 0.0, 0.0])  # the state reached at frame 2 (= reference time 3 dt)
    expected = [10.0] * 3 + [1000 * np.linalg.norm(ref.body_pos[t + 1] - frozen, axis=-1).mean() for t in range(3, 8)]
    assert res.per_clip["mpjpe_g"][0] == pytest.approx(np.mean(expected))
    assert res.per_clip["survival"][0] == 0.0 and res.episode_length.tolist() == [[4]]
    # Frozen, it stands still from frame 3 on: the velocity error of steps 3-7 is the reference's own speed, and
    # nothing before (1 cm off, moving as the reference). Mean over the 7 steps.
    speed = [1000 * np.linalg.norm(ref.body_pos[t + 1] - ref.body_pos[t], axis=-1).mean() for t in range(3, 8)]
    assert res.per_clip["vel_err"][0] == pytest.approx(sum(speed) / 7)
    # Its targets are held from frame 3 on at frame 2's (0.04): the scored targets are 0, 0.01, 0.04, 0.04, ...
    # Second differences: 0.02, then 0.04 - 0.08 + 0.01 = -0.03, then 0: (0.02 + 0.03) / 6 triples.
    assert res.per_clip["target_jitter"][0] == pytest.approx(0.05 / 6)
