"""The tracking gym: reset, rewards, termination, determinism, bad input, divergence, and its frames in the buffer."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.character.state import CharacterState
from common.maths.rotations import quat_from_axis_angle, quat_mul
from common.motion.dataset import load_motions
from common.motion.library import MotionLibrary
from common.sim.buffer import CyclicBuffer
from common.sim.gym import GymConfig, TrackingGym
from common.sim.rewards import RewardConfig, TerminationConfig, TrackingReward, termination


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


@pytest.fixture(scope="module")
def library(humanoid: Humanoid) -> MotionLibrary:
    return load_motions(["walk", "kick", "run"], humanoid)


def _gym(library: MotionLibrary, humanoid: Humanoid, **kwargs: object) -> TrackingGym:
    return TrackingGym(GymConfig(num_envs=kwargs.pop("num_envs", 6), threads=1, **kwargs), library, humanoid)


def _copy(s: CharacterState) -> CharacterState:
    return CharacterState(**{k: v.copy() for k, v in vars(s).items()})


def test_contract_reset_step_shapes_no_nan(library: MotionLibrary, humanoid: Humanoid) -> None:
    gym = _gym(library, humanoid)
    res = gym.reset()
    rng = np.random.default_rng(0)
    for _ in range(30):
        res = gym.step(gym.reference_targets() + rng.normal(scale=0.1, size=(6, humanoid.nu)))
        for state in (res.sim, res.ref, res.ref_next, res.final_sim, res.final_ref, res.final_ref_next):
            assert state.body_pos.shape == (6, 15, 3) and state.body_rot.shape == (6, 15, 4)
            for v in vars(state).values():
                assert np.isfinite(v).all()
        assert res.reward.shape == (6,) and np.all((res.reward >= 0) & (res.reward <= 1))
        assert set(res.reward_terms) == set(RewardConfig().weights)
        assert res.terminated.dtype == bool and res.truncated.dtype == bool
        assert np.all((res.phase >= 0) & (res.phase <= 1))
    gym.close()


def test_reset_puts_simulation_exactly_on_reference(library: MotionLibrary, humanoid: Humanoid) -> None:
    gym = _gym(library, humanoid)
    res = gym.reset()
    np.testing.assert_allclose(res.sim.body_pos, res.ref.body_pos, atol=1e-6)
    np.testing.assert_allclose(np.abs(np.sum(res.sim.body_rot * res.ref.body_rot, -1)), 1.0, atol=1e-6)
    np.testing.assert_allclose(res.sim.body_linvel, res.ref.body_linvel, atol=1e-6)
    np.testing.assert_allclose(res.sim.body_angvel, res.ref.body_angvel, atol=1e-6)
    # ref_next is one control step later on the same clip
    again = library.query(res.clip, res.time + gym.dt)
    np.testing.assert_array_equal(res.ref_next.body_pos, again.body_pos)
    gym.close()


def test_reward_is_maximal_when_simulation_equals_reference(library: MotionLibrary, humanoid: Humanoid) -> None:
    states = library.query(np.array([0, 1, 2]), np.array([0.3, 0.5, 0.2]))
    for form in ("sum", "product"):
        reward, terms = TrackingReward(humanoid, RewardConfig(form=form))(states, states)
        np.testing.assert_allclose(reward, 1.0)
        for v in terms.values():
            np.testing.assert_allclose(v, 1.0)
    # Any difference lowers it: the pose term of a 0.5 rad chest error is exp(-2 * w_chest * 0.25).
    off = _copy(states)
    torso = humanoid.body_index("torso")
    bend = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), np.array(0.5))
    off.body_rot[:, torso] = quat_mul(off.body_rot[:, torso], bend)
    reward, terms = TrackingReward(humanoid, RewardConfig())(off, states)
    fn = TrackingReward(humanoid, RewardConfig())
    w = fn.model.body_weights
    np.testing.assert_allclose(terms["pose"], np.exp(-2.0 * (w[torso] + w[3] + w[6] + w[2]) * 0.25))
    assert np.all(reward < 1.0)


def _rule_case(humanoid: Humanoid, library: MotionLibrary, cfg: TerminationConfig, change, frames: int = 60):
    ref = library.query(np.array([0, 0]), np.array([0.2, 0.2]))
    sim = _copy(ref)
    change(sim, 1)  # character 1 breaks the rule, character 0 tracks perfectly
    lowest = np.full((2, humanoid.num_bodies), 0.1)
    if getattr(change, "touch", False):
        lowest[1, humanoid.head_index] = -0.01
    return termination(cfg, humanoid, sim, ref, np.array([frames, frames]), lowest)


@pytest.mark.parametrize(
    ("rule", "cfg", "change"),
    [
        ("head_height", TerminationConfig(), lambda s, i: s.body_pos[i, 2].__setitem__(2, s.body_pos[i, 2, 2] - 0.3)),
        ("root_pos", TerminationConfig(head_height_error=None, root_pos_error=1.0, grace_frames=0),
         lambda s, i: s.body_pos[i, 0].__setitem__(0, s.body_pos[i, 0, 0] + 1.1)),
        ("body_pos", TerminationConfig(head_height_error=None, body_pos_error=0.5, grace_frames=0),
         lambda s, i: s.body_pos[i, 5].__setitem__(1, s.body_pos[i, 5, 1] + 0.6)),
        ("root_height", TerminationConfig(head_height_error=None, min_root_height=0.3, grace_frames=0),
         lambda s, i: s.body_pos[i, 0].__setitem__(2, 0.2)),
        ("root_rot", TerminationConfig(head_height_error=None, root_rot_error=1.5708, grace_frames=0),
         lambda s, i: s.body_rot.__setitem__((i, 0), quat_mul(quat_from_axis_angle(np.array([1.0, 0, 0]),
                                                                                   np.array(2.0)), s.body_rot[i, 0]))),
    ],
)  # fmt: skip
def test_each_termination_rule_fires(humanoid: Humanoid, library: MotionLibrary, rule: str, cfg: TerminationConfig,
                                     change) -> None:  # fmt: skip
    terminated, rules = _rule_case(humanoid, library, cfg, change)
    assert terminated.tolist() == [False, True]
    assert rules[rule].tolist() == [False, True]


def test_fall_contact_and_grace_period(humanoid: Humanoid, library: MotionLibrary) -> None:
    def touch(s: CharacterState, i: int) -> None:
        pass

    touch.touch = True
    cfg = TerminationConfig(head_height_error=None, fall_contact="deepmimic", grace_frames=10)
    terminated, _ = _rule_case(humanoid, library, cfg, touch)
    assert terminated.tolist() == [False, True]
    # Before the grace period is over no failure rule fires (SuperTrack: 48 frames).
    terminated, _ = _rule_case(humanoid, library, cfg, touch, frames=5)
    assert terminated.tolist() == [False, False]


def test_truncation_at_max_frames_and_clip_end(library: MotionLibrary, humanoid: Humanoid) -> None:
    gym = _gym(library, humanoid, num_envs=2, termination=TerminationConfig(max_episode_frames=5,
                                                                            head_height_error=None))  # fmt: skip
    kick = library.clip_index("kick")
    end = library.end_time[kick]
    gym.reset(clips=np.array([0, kick]), times=np.array([0.0, end - 3 * gym.dt]))
    flags = []
    for step in range(5):
        res = gym.step(gym.reference_targets())
        flags.append((res.truncated.tolist(), res.terminated.tolist()))
        if step == 2:  # the kick's episode ended and was reset: final_clip/final_time still say where it was
            assert res.final_clip[1] == kick and res.episode_frame[1] == 0
            np.testing.assert_allclose(res.final_time, [3 * gym.dt, end])
    # The one-shot kick runs out of frames after 3 steps; the walk is cut by the 5-frame limit.
    assert flags[2] == ([False, True], [False, False])
    assert flags[4][0][0] is True
    assert [f[0][0] for f in flags[:4]] == [False] * 4
    gym.close()


def test_fallen_character_terminates(library: MotionLibrary, humanoid: Humanoid) -> None:
    """PD targets of the zero pose (all hinges at 0) while the reference walks on: the character topples."""
    gym = _gym(library, humanoid, num_envs=1)
    res = gym.reset(clips=np.array([0]), times=np.array([0.0]))
    frozen = np.zeros((1, humanoid.nu))
    steps = 0
    while steps < 300 and not res.terminated[0]:
        res = gym.step(frozen)
        steps += 1
    # The head rule is armed from the 48th frame on.
    assert res.terminated[0] and 48 <= steps < 300
    assert res.final_sim.body_pos[0, humanoid.head_index, 2] < res.final_ref.body_pos[0, humanoid.head_index, 2] - 0.25
    gym.close()


def test_same_seed_same_frames(library: MotionLibrary, humanoid: Humanoid) -> None:
    runs = []
    for _ in range(2):
        gym = _gym(library, humanoid, seed=7, termination=TerminationConfig(max_episode_frames=20))
        res = gym.reset()
        rng = np.random.default_rng(3)
        trace = []
        for _ in range(40):
            res = gym.step(gym.reference_targets() + rng.normal(scale=0.2, size=(6, humanoid.nu)))
            trace.append(np.concatenate([res.sim.qpos.ravel(), res.reward, res.clip, res.episode_id]))
        runs.append(np.stack(trace))
        gym.close()
    np.testing.assert_array_equal(runs[0], runs[1])


def test_state_dict_continues_exactly(library: MotionLibrary, humanoid: Humanoid) -> None:
    gym = _gym(library, humanoid, seed=1, termination=TerminationConfig(max_episode_frames=8))
    gym.reset()
    for _ in range(5):
        gym.step(gym.reference_targets())
    saved = gym.state_dict()
    a = [gym.step(gym.reference_targets()).sim.qpos.copy() for _ in range(10)]
    other = _gym(library, humanoid, seed=99, termination=TerminationConfig(max_episode_frames=8))
    other.load_state_dict(saved)
    b = [other.step(other.reference_targets()).sim.qpos.copy() for _ in range(10)]
    np.testing.assert_array_equal(np.stack(a), np.stack(b))


def test_step_agrees_with_its_parts_to_the_bit(library: MotionLibrary, humanoid: Humanoid) -> None:
    """step() prepares the reference while the physics runs on another thread: its numbers are still those of the
    parts computed one after the other, and the same on one rollout thread as on two."""
    cfg = GymConfig(num_envs=5, seed=2, termination=TerminationConfig(max_episode_frames=7, grace_frames=2))
    gyms = [TrackingGym(replace(cfg, threads=t), library, humanoid) for t in (1, 2)]
    results = [g.reset() for g in gyms]
    fn = TrackingReward(humanoid, cfg.reward)
    rng = np.random.default_rng(4)
    resets = 0
    for _ in range(30):
        targets = gyms[0].reference_targets() + rng.normal(scale=0.3, size=(5, humanoid.nu))
        results = [g.step(targets) for g in gyms]
        res = results[0]
        resets += int(res.done.sum())
        reward, terms = fn(res.final_sim, res.final_ref)
        np.testing.assert_array_equal(res.reward, np.where(res.diverged, 0.0, reward))
        for k in terms:
            np.testing.assert_array_equal(res.reward_terms[k], terms[k])
        expected_next = library.query(res.final_clip, res.final_time + gyms[0].dt)
        for a, b in zip(vars(res.final_ref_next).values(), vars(expected_next).values(), strict=True):
            np.testing.assert_array_equal(a, b)
        for f in ("sim", "ref", "ref_next", "final_sim", "final_ref"):
            for a, b in zip(vars(getattr(res, f)).values(), vars(getattr(results[1], f)).values(), strict=True):
                np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(res.reward, results[1].reward)
    assert resets > 0
    for g in gyms:
        g.close()


def test_bad_actions_fail_clearly(library: MotionLibrary, humanoid: Humanoid) -> None:
    gym = _gym(library, humanoid)
    with pytest.raises(RuntimeError, match="reset"):
        gym.step(np.zeros((6, humanoid.nu)))
    gym.reset()
    with pytest.raises(ValueError, match=r"expected shape \(6, 28\), got \(6, 27\)"):
        gym.step(np.zeros((6, 27)))
    bad = gym.reference_targets()
    bad[2, 5] = np.nan
    with pytest.raises(ValueError, match="character 2, actuator 5"):
        gym.step(bad)
    gym.close()


def test_blown_up_simulation_is_reset_and_counted(library: MotionLibrary, humanoid: Humanoid) -> None:
    gym = _gym(library, humanoid, num_envs=3)
    gym.reset()
    gym.sim.qvel[1, 10] = 1e7  # far beyond max_speed
    before = gym.episode_id.copy()
    res = gym.step(gym.reference_targets())
    assert res.info["diverged"] == 1.0
    assert res.terminated.tolist() == [False, True, False] and res.reward[1] == 0.0
    assert res.episode_id[1] != before[1] and res.episode_id[0] == before[0]
    assert np.isfinite(res.sim.qvel).all() and np.abs(res.sim.qvel).max() < 1e3
    gym.close()


def test_gym_frames_form_valid_buffer_windows(library: MotionLibrary, humanoid: Humanoid) -> None:
    """Frames pushed as the learners do: windows hold consecutive times of one clip and one episode."""
    gym = _gym(library, humanoid, num_envs=4, termination=TerminationConfig(max_episode_frames=9))
    buf = CyclicBuffer(4 * 50, 4, {"time": ((), "float64"), "clip": ((), "int64"), "root": ((3,), "float64")})
    res = gym.reset()
    for _ in range(120):  # wraps the 50-row ring twice
        prev = res
        res = gym.step(gym.reference_targets())
        buf.push(time=prev.time, clip=prev.clip, root=prev.sim.body_pos[:, 0], episode_id=prev.episode_id,
                 terminated=res.terminated, truncated=res.truncated)  # fmt: skip
    w = buf.sample_windows(200, 8, np.random.default_rng(0))
    np.testing.assert_allclose(np.diff(w["time"], axis=1), gym.dt, atol=1e-9)
    assert np.all(w["clip"] == w["clip"][:, :1])
    assert np.all(w["episode_id"] == w["episode_id"][:, :1])
    # The root moves continuously inside a window (no teleport of a reset).
    assert np.abs(np.diff(w["root"], axis=1)).max() < 0.2
    gym.close()


def test_library_rate_must_match_gym(humanoid: Humanoid) -> None:
    from common.character.humanoid import PhysicsConfig

    lib30 = load_motions(["walk"], Humanoid(PhysicsConfig(control_hz=30.0)))
    with pytest.raises(ValueError, match="30 Hz"):
        TrackingGym(GymConfig(num_envs=1, threads=1), lib30, humanoid)


def test_num_envs_validated() -> None:
    with pytest.raises(ValueError, match="num_envs"):
        replace(GymConfig(), num_envs=0)
