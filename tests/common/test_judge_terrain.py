"""The judge on terrain (issue 59, item 4): the termination rules, the evaluator's foot contacts and sliding, and
pushes measure heights above the clip's terrain under the point; a flat clip is judged as before, to the bit."""

from __future__ import annotations

import functools
from dataclasses import replace

import mujoco
import numpy as np
import pytest

from common.character.humanoid import BodyGeometry, Humanoid
from common.character.state import CharacterState
from common.evaluation import evaluate as E
from common.evaluation.evaluate import EvalConfig, evaluate, reference_policy
from common.evaluation.metrics import METRIC_NAMES
from common.maths.rotations import quat_from_axis_angle, quat_mul, quat_rotate
from common.motion.dataset import resolve_clips
from common.motion.library import MotionLibrary
from common.motion.motion import Clip
from common.motion.terrain import Terrain, check_terrain
from common.motion.terrain_generator import rough, slope, stairs
from common.sim.gym import GymConfig, StepResult, TrackingGym
from common.sim.pushes import PushConfig, impulse_velocity_change
from common.sim.rewards import TerminationConfig, termination
from common.sim.terrain import ClipTerrains, ground_clearance, support_clearance, terrain_model

# Steps of 12 cm rise and 50 cm tread: step 1's tread is x in [0, 0.5) at 0.12 m, step 2's [0.5, 1.0) at 0.24 m.
STAIRS = stairs("up", steps=4, step_height=0.12, step_depth=0.5, seed=0)
BOX_TOP = 0.3


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


def _box() -> Terrain:
    """Flat ground at 0 with a raised box of 2 x 2 m, its top at :data:`BOX_TOP`, over x, y in [-1, 1]."""
    heights = np.zeros((81, 81))  # 5 cm cells over [-2, 2]^2
    heights[20:61, 20:61] = BOX_TOP
    return check_terrain(heights, 0.05, np.array([-2.0, -2.0]), "box")


def _standing(humanoid: Humanoid, name: str, x: float, floor: float, terrain: Terrain | None) -> Clip:
    """Two seconds of the zero pose (straight, feet flat) at (x, 0.005), its lowest point at height ``floor``."""
    times = np.array([0.0, 2.0])
    rot = np.tile([1.0, 0.0, 0.0, 0.0], (2, 1))
    clip = Clip(name, name, False, times, np.array([[x, 0.005, 1.0]] * 2), rot, np.tile(rot[:, None], (1, 12, 1)))
    ref = MotionLibrary.from_clips([clip], humanoid).query(np.array([0]), np.array([0.0]))
    lowest = BodyGeometry(humanoid).lowest_points(ref.body_pos, ref.body_rot).min()
    return replace(clip, root_pos=clip.root_pos + [0.0, 0.0, floor - lowest], terrain=terrain)


def _pose(humanoid: Humanoid, x: float, floor: float) -> CharacterState:
    """The zero pose standing at (x, 0.005) with its lowest point at height ``floor``, one character."""
    clip = _standing(humanoid, "pose", x, floor, None)
    return MotionLibrary.from_clips([clip], humanoid).query(np.array([0]), np.array([0.0]))


def _moved(state: CharacterState, dz: float = 0.0, dx: float = 0.0) -> CharacterState:
    out = CharacterState(**{k: v.copy() for k, v in vars(state).items()})
    out.body_pos[..., 2] += dz
    out.body_pos[..., 0] += dx
    return out


def _stack(*states: CharacterState) -> CharacterState:
    return CharacterState(**{k: np.concatenate([getattr(s, k) for s in states]) for k in vars(states[0])})


def _ground(terrain: Terrain | None, n: int):  # noqa: ANN202
    """The termination rules' ``ground`` for n characters on ``terrain``, as the gym builds it."""
    terrains = ClipTerrains([terrain])
    return functools.partial(terrains.height, np.zeros(n, dtype=np.int64)) if terrains.any else None


# -- foot contacts and sliding -------------------------------------------------------------------------------------


def test_a_foot_on_a_step_touches_it_and_the_same_height_over_the_lower_step_does_not(humanoid: Humanoid) -> None:
    on_step = _pose(humanoid, 0.75, 0.24)  # resting on step 2
    over_lower = _moved(on_step, dx=-0.5)  # the same absolute height, over step 1: 12 cm above its tread
    both = _stack(on_step, over_lower)
    terrains = ClipTerrains([STAIRS])
    geometry, feet = BodyGeometry(humanoid), humanoid.foot_indices
    clearance = ground_clearance(terrains, np.zeros(2, dtype=np.int64), geometry, both.body_pos, both.body_rot)[:, feet]
    np.testing.assert_allclose(clearance, [[0.0, 0.0], [0.12, 0.12]], atol=1e-9)
    # The flat floor's measure puts both 24 cm up: neither touches.
    np.testing.assert_allclose(geometry.lowest_points(both.body_pos, both.body_rot)[:, feet], 0.24, atol=1e-9)
    # The evaluator's measure over three frames: at rest on the step both feet touch and slide by 0; sliding 3 mm
    # along y per frame on it, both slide by 3 mm/frame; over the lower step neither touches.
    trace = E._MotionTrace(humanoid, 3, 3, terrains, np.zeros(3, dtype=np.int64))
    for t in range(3):
        sliding = _moved(on_step)
        sliding.body_pos[..., 1] += 0.003 * t
        frame = _stack(on_step, sliding, over_lower)
        trace.add(t, frame, frame, np.zeros((3, humanoid.nu)), np.zeros(3, dtype=bool))
    for key in E.SLIDE_METRICS:
        np.testing.assert_allclose(trace.contacts[key][1:], [[2, 2, 0]] * 2)
        np.testing.assert_allclose(trace.slide[key][1:], [[0.0, 6.0, 0.0]] * 2, atol=1e-9)


def test_a_character_standing_on_a_step_touches_it_and_does_not_slide(humanoid: Humanoid) -> None:
    """End to end through the evaluator: the reference stands on step 2, fitted to it; the other floats at the same
    absolute height over step 1 (the simulated character drops 12 cm onto it and stands)."""
    library = MotionLibrary.from_clips([_standing(humanoid, "on_step", 0.75, 0.24, STAIRS),
                                        _standing(humanoid, "over_lower", 0.25, 0.24, STAIRS)], humanoid)  # fmt: skip
    result = evaluate(functools.partial(reference_policy, humanoid=humanoid), library, humanoid,
                      EvalConfig(starts_per_clip=1, max_frames=60, threads=1))  # fmt: skip
    on_step, over_lower = 0, 1
    assert result.per_clip["foot_slide_ref"][on_step] == 0.0  # in contact at every frame, never moving
    assert result.per_clip["foot_slide"][on_step] < 0.2  # mm/frame: the simulated feet settle and stay
    assert np.isnan(result.per_clip["foot_slide_ref"][over_lower])  # the reference's feet never touch
    assert np.isfinite(result.per_clip["foot_slide"][over_lower])  # the simulated ones landed on step 1
    assert result.per_clip["survival"][on_step] == 1.0


# -- termination -------------------------------------------------------------------------------------------------


def test_head_and_root_rules_on_a_box_measure_from_its_top(humanoid: Humanoid) -> None:
    cfg = TerminationConfig(grace_frames=0, head_height_error=0.25, min_root_height=0.3, root_height_error=0.25)
    ref = _pose(humanoid, 0.0, BOX_TOP)  # the reference stands on the box
    on_box = ref  # standing on it at the reference's height
    floor_heights = _moved(ref, dz=-BOX_TOP)  # over the box at the heights of standing on the flat floor
    fallen = _moved(ref, dz=BOX_TOP + 0.15 - ref.body_pos[0, humanoid.root_index, 2])  # root 15 cm above the top
    sim = _stack(on_box, floor_heights, fallen)
    refs = _stack(ref, ref, ref)
    frames = np.ones(3, dtype=np.int64)
    _, rules = termination(cfg, humanoid, sim, refs, frames, None, None, _ground(_box(), 3))
    assert rules["head_height"].tolist() == [False, True, True]
    assert rules["root_below_ref"].tolist() == [False, True, True]
    assert rules["root_height"].tolist() == [False, False, True]
    # The flat floor's rule takes the fallen root, 0.45 m up, for one above its 0.3 m.
    _, flat = termination(cfg, humanoid, sim, refs, frames, None, None, None)
    assert flat["root_height"].tolist() == [False, False, False]


def test_head_and_root_rules_compare_heights_above_the_ground_under_each(humanoid: Humanoid) -> None:
    """On stairs a character upright two steps below its reference (24 cm) is not off its reference's height above
    the ground; by absolute heights it was. One that has sunk 30 cm below its reference over the same step is."""
    cfg = TerminationConfig(grace_frames=0, head_height_error=0.2, root_height_error=0.2)
    ref = _pose(humanoid, 1.25, 0.36)  # on step 3 (x in [1.0, 1.5), 0.36 m)
    behind = _pose(humanoid, 0.25, 0.12)  # upright on step 1
    sunk = _moved(ref, dz=-0.3)
    sim, refs = _stack(behind, sunk), _stack(ref, ref)
    frames = np.ones(2, dtype=np.int64)
    terminated, rules = termination(cfg, humanoid, sim, refs, frames, None, None, _ground(STAIRS, 2))
    assert terminated.tolist() == [False, True]
    assert rules["head_height"].tolist() == rules["root_below_ref"].tolist() == [False, True]
    assert termination(cfg, humanoid, sim, refs, frames, None, None, None)[0].tolist() == [True, True]


def _lying(humanoid: Humanoid, floor: float) -> CharacterState:
    """The zero pose turned onto its back (-90 deg about y: face up, head towards -x), the lowest point of its pelvis,
    torso and head at height ``floor``, its root at x, y = 0."""
    pose = _pose(humanoid, 0.0, 1.0)
    q = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), -np.pi / 2)
    root = pose.body_pos[:, humanoid.root_index : humanoid.root_index + 1]
    pose.body_pos[:] = root + quat_rotate(q, pose.body_pos - root)
    pose.body_rot[:] = quat_mul(q, pose.body_rot)
    lowest = BodyGeometry(humanoid).lowest_points(pose.body_pos, pose.body_rot)[:, humanoid.fall_contact_indices].min()
    return _moved(pose, dz=floor - lowest)


def test_fall_contact_measures_from_the_terrain_under_each_body(humanoid: Humanoid) -> None:
    cfg = TerminationConfig(grace_frames=0, head_height_error=None, fall_contact="deepmimic", contact_clearance=0.1)
    geometry = BodyGeometry(humanoid)
    on_box = _lying(humanoid, BOX_TOP + 0.001)  # lying on the box, 1 mm above its top
    standing = _pose(humanoid, 0.0, BOX_TOP)
    sim, refs = _stack(on_box, on_box), _stack(standing, on_box)
    terrains, clips = ClipTerrains([_box()]), np.zeros(2, dtype=np.int64)
    lowest = ground_clearance(terrains, clips, geometry, sim.body_pos, sim.body_rot)
    ref_lowest = ground_clearance(terrains, clips, geometry, refs.body_pos, refs.body_rot)
    assert lowest[:, humanoid.fall_contact_indices].min() == pytest.approx(0.001, abs=1e-9)
    frames = np.ones(2, dtype=np.int64)
    # Lying on the box where the reference stands on it ends the episode; where the reference lies there too, not.
    _, rules = termination(cfg, humanoid, sim, refs, frames, lowest, ref_lowest, _ground(_box(), 2))
    assert rules["fall_contact"].tolist() == [True, False]
    # Measured from z = 0 the lying character is 30 cm up: no contact.
    flat = geometry.lowest_points(sim.body_pos, sim.body_rot)
    assert not termination(cfg, humanoid, sim, refs, frames, flat, flat, None)[1]["fall_contact"].any()


def test_ground_clearance_is_the_flat_measure_on_flat_clips_and_the_contact_labels_on_terrain(
    humanoid: Humanoid,
) -> None:
    library = MotionLibrary.from_clips(resolve_clips(["walk"]), humanoid)
    frames = library.frames[np.arange(0, 40, 4)]
    geometry = BodyGeometry(humanoid)
    flat = geometry.lowest_points(frames.body_pos, frames.body_rot)
    none = ClipTerrains([None])
    zeros = np.zeros(10, dtype=np.int64)
    assert np.array_equal(ground_clearance(none, zeros, geometry, frames.body_pos, frames.body_rot), flat)
    mixed = ClipTerrains([None, rough(seed=0)])
    clips = np.arange(10) % 2
    out = ground_clearance(mixed, clips, geometry, frames.body_pos, frames.body_rot)
    assert np.array_equal(out[clips == 0], flat[clips == 0])  # bit for bit: the flat judge's arithmetic
    labels = support_clearance(mixed, clips, geometry, frames.body_pos, frames.body_rot)
    assert np.array_equal(out[clips == 1], labels[clips == 1])
    assert not np.allclose(out[clips == 1], flat[clips == 1], atol=1e-3)  # the bumps count


# -- the gym and the evaluator -------------------------------------------------------------------------------------


def test_gym_judges_a_character_below_zero_on_its_terrain(humanoid: Humanoid) -> None:
    """A character standing at the foot of a flight of stairs down (60 cm below 0) is judged upright by every rule,
    where the flat floor's rules (root below 0.5 m, bodies below 0.5 cm touching) would end its episode."""
    down = stairs("down", steps=4, step_height=0.15, step_depth=0.3, seed=0)
    clip = _standing(humanoid, "below", 1.7, -0.6, down)
    library = MotionLibrary.from_clips([clip], humanoid)
    cfg = TerminationConfig(grace_frames=0, min_root_height=0.5, root_height_error=0.3, fall_contact="non_foot",
                            contact_clearance=0.1)  # fmt: skip
    gym = TrackingGym(GymConfig(num_envs=2, threads=1, termination=cfg), library, humanoid)
    gym.reset(clips=np.zeros(2, dtype=np.int64), times=np.zeros(2))
    results: list[StepResult] = [gym.step(gym.reference_targets(), autoreset=False) for _ in range(30)]
    gym.close()
    assert not any(r.terminated.any() for r in results)
    last = results[-1]
    np.testing.assert_allclose(last.sim.body_pos[:, 0], last.ref.body_pos[:, 0], atol=0.02)  # standing on it
    geometry = BodyGeometry(humanoid)
    flat = geometry.lowest_points(last.sim.body_pos, last.sim.body_rot)
    ref_flat = geometry.lowest_points(last.ref.body_pos, last.ref.body_rot)
    assert termination(cfg, humanoid, last.sim, last.ref, np.ones(2), flat, ref_flat)[0].all()


def test_a_flat_clip_is_judged_the_same_beside_a_terrain_clip(humanoid: Humanoid) -> None:
    """Every rule on, noisy targets, resets: the flat clip's characters step and end exactly as in a library without
    terrain; and the evaluator's figures of a flat clip are the same to the bit."""
    walk = resolve_clips(["walk"])[0]
    flat = MotionLibrary.from_clips([walk], humanoid)
    mixed = MotionLibrary.from_clips([walk, replace(walk, name="walk_up", terrain=STAIRS)], humanoid)
    cfg = TerminationConfig(max_episode_frames=40, grace_frames=5, head_height_error=0.2, body_pos_error=0.5,
                            min_root_height=0.6, root_height_error=0.2, fall_contact="non_foot",
                            contact_clearance=0.1)  # fmt: skip
    steps = []
    for library in (flat, mixed):
        gym = TrackingGym(GymConfig(num_envs=4, threads=1, termination=cfg), library, humanoid)
        gym.reset(clips=np.array([0, 0, 0, len(library.names) - 1]), times=np.array([0.0, 0.3, 0.6, 0.0]))
        rng = np.random.default_rng(0)
        run = []
        for _ in range(60):
            r = gym.step(gym.reference_targets() + rng.normal(0.0, 0.4, (4, humanoid.nu)), autoreset=False)
            run.append((r.sim.qpos[:3].copy(), r.reward[:3], r.terminated[:3], r.truncated[:3]))
            ended = np.flatnonzero(r.done[:3])
            if len(ended):
                gym.reset(ended, clips=np.zeros(len(ended), dtype=np.int64), times=np.full(len(ended), 0.1))
        gym.close()
        steps.append(run)
    assert sum(s[2].sum() for s in steps[0]) > 0  # some rule fired
    for a, b in zip(*steps, strict=True):
        for x, y in zip(a, b, strict=True):
            assert np.array_equal(x, y)
    eval_cfg = EvalConfig(
        starts_per_clip=2, max_frames=60, threads=1, termination=replace(cfg, max_episode_frames=None)
    )
    policy = functools.partial(reference_policy, humanoid=humanoid)
    alone, beside = evaluate(policy, flat, humanoid, eval_cfg), evaluate(policy, mixed, humanoid, eval_cfg)
    for key in METRIC_NAMES:
        np.testing.assert_array_equal(alone.per_clip[key][0], beside.per_clip[key][0], err_msg=key)


def test_evaluation_with_pushes_runs_on_generated_terrain_clips(humanoid: Humanoid) -> None:
    walk = resolve_clips(["walk"])[0]
    clips = [replace(walk, name=f"walk_{kind}", terrain=terrain) for kind, terrain in
             (("up", stairs("up", steps=4, step_height=0.08, seed=0)), ("slope", slope(angle_deg=6.0)),
              ("rough", rough(seed=0)))]  # fmt: skip
    library = MotionLibrary.from_clips([walk, *clips], humanoid)
    cfg = EvalConfig(starts_per_clip=1, max_frames=40, threads=1, rsi_lift=True,
                     pushes=PushConfig(first_frame=10, interval=15))  # fmt: skip
    result = evaluate(functools.partial(reference_policy, humanoid=humanoid), library, humanoid, cfg)
    assert result.clips == ["walk", "walk_up", "walk_slope", "walk_rough"]
    for key in METRIC_NAMES:
        values = result.per_clip[key]
        assert np.isfinite(values).all() or key.endswith("_succ"), (key, values)
    assert result.frames == 40 and "walk_rough" in result.table()


def test_a_push_changes_the_velocities_as_on_the_flat_floor(humanoid: Humanoid) -> None:
    """The gym computes a push in the character's own model: on its clip's terrain model the change is the same."""
    pose = _pose(humanoid, 0.75, 0.24)
    on_stairs = terrain_model(humanoid, STAIRS)
    rng = np.random.default_rng(0)
    qpos, qvel = pose.qpos[0], rng.normal(0.0, 0.5, humanoid.nv)
    impulse = np.array([20.0, -10.0, 0.0])
    own = impulse_velocity_change(humanoid.model, mujoco.MjData(humanoid.model), qpos, qvel, 1, impulse)
    terrain = impulse_velocity_change(on_stairs, mujoco.MjData(on_stairs), qpos, qvel, 1, impulse)
    np.testing.assert_allclose(own, terrain, rtol=0, atol=1e-12)
    assert np.abs(own).max() > 0.1
