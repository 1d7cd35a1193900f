"""Pushes of the robustness protocol: the schedule by hand, the impulse's exact momentum change, the evaluator."""

from __future__ import annotations

import functools

import mujoco
import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import EvalConfig, evaluate, reference_policy
from common.motion.dataset import load_motions
from common.sim.gym import GymConfig, TrackingGym
from common.sim.pushes import PushConfig, impulse_velocity_change, push_schedule


def test_schedule_by_hand_and_seeded() -> None:
    cfg = PushConfig(impulse=30.0, first_frame=60, interval=120, seed=3)
    frames, impulses = push_schedule(cfg, num_episodes=5, horizon=512)
    assert frames.tolist() == [60, 180, 300, 420]
    assert impulses.shape == (4, 5, 3)
    np.testing.assert_allclose(np.linalg.norm(impulses, axis=-1), 30.0)
    np.testing.assert_array_equal(impulses[..., 2], 0.0)  # horizontal
    again = push_schedule(cfg, num_episodes=5, horizon=512)[1]
    np.testing.assert_array_equal(impulses, again)
    other = push_schedule(PushConfig(seed=4), num_episodes=5, horizon=512)[1]
    assert not np.allclose(impulses, other)
    with pytest.raises(ValueError, match="impulse"):
        PushConfig(impulse=-1.0)


def test_impulse_changes_total_momentum_by_exactly_the_impulse() -> None:
    h = Humanoid()
    m = h.model
    d = mujoco.MjData(m)
    lib = load_motions(["walk"], h)
    qpos = lib.query(np.array([0]), np.array([0.3])).qpos[0].copy()
    qpos[2] += 5.0  # in the air: no contact, so nothing but the impulse changes the momentum
    qvel = np.zeros(m.nv)
    qvel[0] = 1.0
    p = np.array([12.0, -5.0, 3.0])
    dq = impulse_velocity_change(m, d, qpos, qvel, 1, p)

    def momentum(v: np.ndarray) -> np.ndarray:
        d.qpos[:], d.qvel[:] = qpos, v
        mujoco.mj_forward(m, d)
        mujoco.mj_subtreeVel(m, d)
        return m.body_subtreemass[1] * d.subtree_linvel[1]

    np.testing.assert_allclose(momentum(qvel + dq) - momentum(qvel), p, atol=1e-9)


def test_gym_push_updates_the_state_the_policy_sees() -> None:
    h = Humanoid()
    lib = load_motions(["walk"], h)
    gym = TrackingGym(GymConfig(num_envs=2, threads=1), lib, h)
    try:
        res = gym.reset(clips=np.zeros(2, dtype=np.int64), times=np.array([0.2, 0.2]))
        before = res.sim.body_linvel[:, h.root_index].copy()
        gym.push(np.array([1]), np.array([[30.0, 0.0, 0.0]]))
        after = res.sim.body_linvel[:, h.root_index]
        np.testing.assert_array_equal(after[0], before[0])  # not pushed
        # The pelvis, pushed at its own origin, moves faster along +x than the whole body's 30 / 45 kg.
        assert after[1, 0] - before[1, 0] > 30.0 / float(h.body_mass.sum())
    finally:
        gym.close()


def test_evaluation_with_pushes_is_deterministic_and_zero_pushes_change_nothing() -> None:
    h = Humanoid()
    lib = load_motions(["walk"], h)
    policy = functools.partial(reference_policy, humanoid=h)
    base = EvalConfig(starts_per_clip=2, max_frames=40, threads=1)
    plain = evaluate(policy, lib, h, base)
    zero_cfg = EvalConfig(starts_per_clip=2, max_frames=40, threads=1,
                          pushes=PushConfig(impulse=0.0, first_frame=10, interval=10))  # fmt: skip
    zero = evaluate(policy, lib, h, zero_cfg)
    np.testing.assert_array_equal(plain.per_clip["mpjpe_g"], zero.per_clip["mpjpe_g"])
    pushed_cfg = EvalConfig(starts_per_clip=2, max_frames=40, threads=1,
                            pushes=PushConfig(impulse=60.0, first_frame=10, interval=10))  # fmt: skip
    a, b = evaluate(policy, lib, h, pushed_cfg), evaluate(policy, lib, h, pushed_cfg)
    np.testing.assert_array_equal(a.per_clip["mpjpe_g"], b.per_clip["mpjpe_g"])
    assert a.per_clip["mpjpe_g"][0] != plain.per_clip["mpjpe_g"][0]
