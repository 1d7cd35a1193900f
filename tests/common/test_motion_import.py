"""Retargeting BVH onto the humanoid, the clean-up options and ``mimic-motions import``."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from common.character.humanoid import DEEPMIMIC_JOINTS, Humanoid
from common.maths.rotations import quat_from_axis_angle, quat_geodesic_angle, quat_mul, quat_rotate
from common.motion.dataset import load_motions, resolve_clips
from common.motion.library import MotionLibrary
from common.motion.motion import Clip, MotionFormatError, read_deepmimic
from common.motion.motion_import import bundled_bvh_dir, cleanup
from common.motion.motion_import.bvh import euler_to_quat, forward_kinematics, quat_to_euler, read_bvh, write_bvh
from common.motion.motion_import.deepmimic import write_deepmimic
from common.motion.motion_import.humanoid_bvh import humanoid_bvh, write_humanoid_bvh
from common.motion.motion_import.joint_map import load_joint_map
from common.motion.motion_import.retarget import Retargeted, RetargetOptions, retarget
from common.tools.motions import main as mimic_motions

TAKE = bundled_bvh_dir() / "131_01.bvh"
CMU_UNIT = 0.056444


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


@pytest.fixture(scope="module")
def take(humanoid: Humanoid) -> Retargeted:
    return retarget(read_bvh(TAKE), humanoid, load_joint_map("cmu", humanoid.body_names))


@pytest.fixture(scope="module")
def grounded(take: Retargeted, humanoid: Humanoid) -> tuple[Clip, MotionLibrary]:
    clip, _ = cleanup.fix_ground(take.clip, humanoid)
    return clip, MotionLibrary.from_clips([clip], humanoid)


def _body_pos_after_round_trip(clip: Clip, humanoid: Humanoid, path: Path, joints=None, motion=None) -> np.ndarray:
    """Writes ``clip`` as humanoid3d BVH (optionally with another hierarchy/motion), imports it, returns body_pos."""
    if joints is None:
        write_humanoid_bvh(path, clip, humanoid)
    else:
        write_bvh(path, joints, float(clip.times[1] - clip.times[0]), motion)
    back = retarget(read_bvh(path), humanoid, load_joint_map("humanoid3d", humanoid.body_names), name=clip.name)
    write_deepmimic(path.with_suffix(".txt"), replace(back.clip, loop=clip.loop))
    return MotionLibrary.from_clips([read_deepmimic(path.with_suffix(".txt"))], humanoid).frames.body_pos


@pytest.mark.parametrize("name", ["walk", "backflip"])
def test_round_trip_through_bvh_keeps_body_positions(tmp_path: Path, humanoid: Humanoid, name: str) -> None:
    clip = resolve_clips([name])[0]
    original = MotionLibrary.from_clips([clip], humanoid).frames.body_pos
    back = _body_pos_after_round_trip(clip, humanoid, tmp_path / f"{name}.bvh")
    assert back.shape == original.shape
    assert np.abs(back - original).max() < 1e-3  # 1 mm at every frame and body (MuJoCo's kinematics)


def test_z_up_source(tmp_path: Path, humanoid: Humanoid) -> None:
    clip = resolve_clips(["walk"])[0]
    write_humanoid_bvh(tmp_path / "z.bvh", clip, humanoid, up="z")
    hmap = load_joint_map("humanoid3d", humanoid.body_names)
    back = retarget(read_bvh(tmp_path / "z.bvh"), humanoid, hmap, RetargetOptions(up="z"))
    np.testing.assert_allclose(back.world, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(back.clip.root_pos, clip.root_pos, atol=1e-6)
    assert np.degrees(quat_geodesic_angle(back.clip.joint_rot, clip.joint_rot)).max() < 1e-3


def test_cmu_map_reads_the_motionbuilder_naming(tmp_path: Path, take: Retargeted, humanoid: Humanoid) -> None:
    # The other CMU release names the same joints differently; there "LeftShoulder" is the collar.
    renames = {"LeftHip": "LeftUpLeg", "LeftKnee": "LeftLeg", "LeftAnkle": "LeftFoot", "LeftToe": "LeftToeBase",
               "LeftCollar": "LeftShoulder", "LeftShoulder": "LeftArm", "LeftElbow": "LeftForeArm",
               "LeftWrist": "LeftHand", "Chest2": "Spine1"}  # fmt: skip
    lines = []
    for line in TAKE.read_text().splitlines():
        words = line.split()
        if len(words) == 2 and words[0] in ("JOINT", "ROOT") and words[1] in renames:
            line = line.replace(words[1], renames[words[1]])
        lines.append(line)
    (tmp_path / "mb.bvh").write_text("\n".join(lines) + "\n")
    other = retarget(read_bvh(tmp_path / "mb.bvh"), humanoid, load_joint_map("cmu", humanoid.body_names))
    assert other.sources["left_upper_arm"] == "LeftArm" and other.sources["left_thigh"] == "LeftUpLeg"
    np.testing.assert_array_equal(other.clip.joint_rot, take.clip.joint_rot)
    np.testing.assert_array_equal(other.clip.root_pos, take.clip.root_pos)


def test_t_pose_source_gives_the_same_motion(tmp_path: Path, humanoid: Humanoid) -> None:
    """The same motion on a skeleton whose rest pose holds the arms out sideways (a T-pose)."""
    clip = resolve_clips(["walk"])[0]
    joints, _, motion = humanoid_bvh(clip, humanoid)
    names = [j.name for j in joints]
    joints, motion = list(joints), motion.copy()
    for side, out in (("right", 1.0), ("left", -1.0)):  # DeepMimic's Y-up frame: the right side is +z
        # Q takes the hanging arm (-y) to the sideways one: a quarter turn about x (sign by side).
        q = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), out * np.pi / 2)
        for b in (f"{side}_lower_arm", f"{side}_hand"):
            j = joints[names.index(b)]
            joints[names.index(b)] = replace(j, offset=quat_rotate(q, j.offset))
        # World pose kept: upper arm L' = L Q^-1, forearm L' = Q L Q^-1.
        for b, pre in ((f"{side}_upper_arm", False), (f"{side}_lower_arm", True)):
            j = joints[names.index(b)]
            cols = slice(j.column, j.column + 3)
            local = euler_to_quat(motion[:, cols], j.rotation_order)
            local = quat_mul(local, q * np.array([1.0, -1.0, -1.0, -1.0]))
            if pre:
                local = quat_mul(q, local)
            motion[:, cols] = quat_to_euler(local, j.rotation_order)
    original = MotionLibrary.from_clips([clip], humanoid).frames.body_pos
    back = _body_pos_after_round_trip(clip, humanoid, tmp_path / "tpose.bvh", tuple(joints), motion)
    assert np.abs(back - original).max() < 1e-3


def test_humanoid_bvh_units_and_axes_by_hand(tmp_path: Path, humanoid: Humanoid) -> None:
    clip = resolve_clips(["walk"])[0]
    write_humanoid_bvh(tmp_path / "walk.bvh", clip, humanoid)
    bvh = read_bvh(tmp_path / "walk.bvh")
    hmap = load_joint_map("humanoid3d", humanoid.body_names)
    inferred = retarget(bvh, humanoid, hmap)
    # Written in centimetres, Y up with the left at -z (DeepMimic's frame): W is DeepMimic's (x, y, z) -> (x, -z, y).
    assert inferred.scale == 0.01 and "inferred: cm" in inferred.scale_note
    np.testing.assert_allclose(inferred.world, [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)
    assert inferred.leg_ratio == pytest.approx(1.0, abs=1e-6)
    # A wrong unit halves the leg ratio but, the root being scaled by leg length, changes nothing else.
    given = retarget(bvh, humanoid, hmap, RetargetOptions(scale=0.02))
    assert given.leg_ratio == pytest.approx(0.5, abs=1e-6)
    np.testing.assert_allclose(given.clip.root_pos, inferred.clip.root_pos, atol=1e-12)


def test_cmu_take_units_axes_and_legs_by_hand(take: Retargeted) -> None:
    assert take.scale == CMU_UNIT and "inferred: cmu" in take.scale_note
    # Y up, facing +z, left at +x (LeftHip's offset is +x): forward z -> x, left x -> y, up y -> z.
    np.testing.assert_allclose(take.world, [[0, 0, 1], [1, 0, 0], [0, 1, 0]], atol=1e-12)
    # Thigh + shin: the file's LeftKnee/LeftAnkle (and right) offsets; the character's 0.421546 + 0.40987 m.
    src = np.mean([math.hypot(2.49329, 6.85026) + math.hypot(2.36770, 6.50520),
                   math.hypot(2.46559, 6.77417) + math.hypot(2.38450, 6.55136)]) * CMU_UNIT  # fmt: skip
    assert take.leg_ratio == pytest.approx((0.421546 + 0.40987) / src, rel=1e-6)
    assert take.sources["left_thigh"] == "LeftHip" and take.sources["left_upper_arm"] == "LeftShoulder"


def test_cmu_elbows_turned_onto_the_hinge(take: Retargeted) -> None:
    # CMU's elbow axis lies 30 deg off the lateral axis; once the arm is turned by that about its bone, nothing is
    # left off the hinge. The knees' axes are already on it.
    for side in ("left", "right"):
        assert take.hinge_twist_deg[f"{side}_elbow"] == pytest.approx(30.0, abs=0.5)
        assert take.hinge_twist_deg[f"{side}_knee"] < 0.5
        for joint in (f"{side}_elbow", f"{side}_knee"):
            assert take.hinge_residual_deg[joint][1] < 0.1


LIMBS = [("right_thigh", "right_shin"), ("right_shin", "right_foot"), ("left_thigh", "left_shin"),
         ("left_shin", "left_foot"), ("right_upper_arm", "right_lower_arm"), ("right_lower_arm", "right_hand"),
         ("left_upper_arm", "left_lower_arm"), ("left_lower_arm", "left_hand")]  # fmt: skip
BONE_BOUND_DEG = 0.5


def test_cmu_bones_point_where_the_source_bones_point(take: Retargeted, grounded, humanoid: Humanoid) -> None:
    """Every limb bone and the feet's and head's tips, at every 60 Hz frame, within 0.5 deg of the source's.

    (The spine is not compared: the source bends it at three joints where the character has one.)
    """
    _, library = grounded
    bvh = read_bvh(TAKE)
    pos, rot = forward_kinematics(bvh)
    frame = np.round(np.arange(library.num_frames[0]) * library.dt / bvh.frame_time).astype(int)
    body = library.frames.body_pos
    names = humanoid.body_names

    def angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        cos = np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
        return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))

    worst = {}
    for parent, child in LIMBS:
        ours = body[:, names.index(child)] - body[:, names.index(parent)]
        src = (pos[frame, bvh.index(take.sources[child])] - pos[frame, bvh.index(take.sources[parent])]) @ take.world.T
        worst[parent] = angle(ours, src).max()
    for foot in ("right_foot", "left_foot"):
        ours = quat_rotate(library.frames.body_rot[:, names.index(foot)], np.array([1.0, 0.0, -0.2]))
        tip = pos[frame, bvh.index(take.sources[f"{foot} tip"])] - pos[frame, bvh.index(take.sources[foot])]
        worst[foot] = angle(ours, tip @ take.world.T).max()
    head = bvh.index("Head")
    ours = quat_rotate(library.frames.body_rot[:, names.index("head")], np.array([0.0, 0.0, 1.0]))
    worst["head"] = angle(ours, quat_rotate(rot[frame, head], bvh.joints[head].end_site) @ take.world.T).max()
    assert max(worst.values()) < BONE_BOUND_DEG, worst


def test_cmu_feet_on_the_floor_in_stance_after_fix_ground(grounded, humanoid: Humanoid) -> None:
    clip, _ = grounded
    feet = cleanup.foot_contact(clip, humanoid)
    stance = feet.height[feet.stance]
    assert 0.3 < feet.stance.mean() < 0.7  # start, walk, stop: each foot rests about half the time
    # The source's own stance feet (lowest of ankle, toe and toe tip) spread over 8-12 cm, its right foot standing
    # lower than its left; one constant shift brings the character's within 3.2 cm of the floor (97 % within 3 cm),
    # 90 of its 497 frames with a stance foot 1 to 3.2 cm under it, and the local lift takes those out (measured:
    # lowest -0.96 cm, highest +3.1 cm, 99.8 % within 3 cm).
    assert stance.min() >= -cleanup.GROUND_TOLERANCE
    assert np.mean(np.abs(stance) < 0.03) > 0.99
    assert np.abs(stance).max() < 0.035


def test_smooth_lift_by_hand() -> None:
    need = np.zeros(13)
    need[6] = 1.0
    # Cone of slope 0.25: 0 0 0 .25 .5 .75 1 .75 .5 .25 0 0 0; its maximum over +-1 frame: 0 0 .25 .5 .75 1 1 1 .75
    # .5 .25 0 0; the Hann window of half-width 1 weighs (.25, .5, .25).
    lift = cleanup.smooth_lift(need, rise=0.25, half=1)
    np.testing.assert_allclose(lift, [0, 0.0625, 0.25, 0.5, 0.75, 0.9375, 1, 0.9375, 0.75, 0.5, 0.25, 0.0625, 0],
                               atol=1e-15)  # fmt: skip
    assert np.all(lift >= need) and np.abs(np.diff(lift)).max() <= 0.25 + 1e-15


def _lowest_stance_foot(clip: Clip, humanoid: Humanoid) -> np.ndarray:
    """Per control frame, the lowest point of the feet in stance (inf where none is). Shape: (T,)."""
    feet = cleanup.foot_contact(clip, humanoid)
    return np.where(feet.stance, feet.height, np.inf).min(axis=-1)


def _root_speed(clip: Clip) -> np.ndarray:
    """Frame-to-frame root speed, m/s. Shape: (M - 1,)."""
    return np.linalg.norm(np.diff(clip.root_pos, axis=0), axis=-1) / np.diff(clip.times)


def test_fix_ground_lifts_a_local_dip_out_smoothly(grounded, humanoid: Humanoid) -> None:
    # The held-back CMU take kept a foot 3 to 5.7 cm under the floor for 18 frames, which one shift of the whole clip
    # leaves. Here: the grounded take (every stance foot within 1 cm of the floor) pushed down 5 cm for 18 control
    # frames (0.3 s) while the right foot stands (control frames 287-313), with 0.1 s raised-cosine ramps.
    clip, _ = grounded
    t0, span, ramp = 291 / 60, 0.3, 0.1
    u = np.clip(np.minimum(clip.times - (t0 - ramp), t0 + span + ramp - clip.times) / ramp, 0.0, 1.0)
    dip = 0.05 * np.sin(0.5 * np.pi * u) ** 2
    dipped = replace(clip, root_pos=clip.root_pos - dip[:, None] * [0.0, 0.0, 1.0])
    assert _lowest_stance_foot(dipped, humanoid).min() < -0.045  # measured -4.8 cm
    fixed, ground = cleanup.fix_ground(dipped, humanoid)
    assert _lowest_stance_foot(fixed, humanoid).min() >= -cleanup.GROUND_TOLERANCE  # measured -0.81 cm
    assert ground.deepest < -0.045 and 0.035 < ground.lift.max() < 0.05  # measured 3.9 cm
    # Smooth: the lift never changes the root's height faster than LIFT_SPEED, and the fastest root speed of the
    # clip stays what it was to 1 cm/s (measured: 2.029 m/s before and after; within 0.5 s of the dip 1.462 m/s in
    # the clean take, 1.471 dipped, 1.507 fixed).
    assert (np.abs(np.diff(ground.lift)) / np.diff(clip.times)).max() <= cleanup.LIFT_SPEED + 1e-9
    assert _root_speed(fixed).max() <= _root_speed(clip).max() + 0.01
    # Only the dip and its ramps move (up to 0.35 s either side of it, at LIFT_SPEED); the rest is as it was, but
    # for the shift of the whole clip by the median stance height, which the dip moves by 0.1 cm.
    away = (clip.times < t0 - ramp - 0.35) | (clip.times > t0 + span + ramp + 0.35)
    assert np.all(ground.lift[away] == 0.0) and abs(ground.shift) < 0.002
    np.testing.assert_allclose(fixed.root_pos[away], dipped.root_pos[away] + [0.0, 0.0, ground.shift], atol=1e-12)


def test_fix_ground_leaves_the_shipped_take_as_it_was_away_from_its_dips(take: Retargeted, humanoid: Humanoid) -> None:
    shifted, shift = cleanup.shift_to_ground(take.clip, humanoid)
    fixed, ground = cleanup.fix_ground(take.clip, humanoid)
    assert ground.shift == shift
    low = _lowest_stance_foot(shifted, humanoid)
    dips = np.flatnonzero(low < -cleanup.GROUND_TOLERANCE) / 60.0  # control frames with a stance foot below -1 cm
    assert len(dips) == 90 and low.min() == pytest.approx(-0.0322, abs=1e-4)
    # A dip of depth d needs ramps of (d - LIFT_TO) / LIFT_SPEED, rounded over LIFT_SMOOTHING either side, and one
    # control frame of interpolation: keyframes farther than that from every dip are not moved at all.
    reach = (-low.min() - cleanup.LIFT_TO) / cleanup.LIFT_SPEED + 2 * cleanup.LIFT_SMOOTHING + 2 / 60
    away = np.min(np.abs(take.clip.times[:, None] - dips[None]), axis=1) > reach
    assert away.sum() > 400  # measured 413 of 994 keyframes
    np.testing.assert_allclose(fixed.root_pos[away], shifted.root_pos[away], rtol=0.0, atol=1e-9)
    for field in ("root_rot", "joint_rot", "times"):
        np.testing.assert_array_equal(getattr(fixed, field), getattr(take.clip, field))


JUMP_BOUND_DEG = 20.0  # per 120 Hz frame; the take's fastest source joint (RightShoulder) turns 16.6 deg in one


def test_cmu_joints_never_jump(take: Retargeted) -> None:
    clip = take.clip
    step = np.degrees(quat_geodesic_angle(clip.joint_rot[1:], clip.joint_rot[:-1]))
    names = [n for n, _, _ in DEEPMIMIC_JOINTS]
    assert step.max() < JUMP_BOUND_DEG, dict(zip(names, step.max(0).round(1), strict=True))
    assert np.degrees(quat_geodesic_angle(clip.root_rot[1:], clip.root_rot[:-1])).max() < JUMP_BOUND_DEG
    assert np.linalg.norm(np.diff(clip.root_pos, axis=0), axis=-1).max() < 0.05  # 6 m/s


def test_mirror_twice_is_the_identity(take: Retargeted) -> None:
    twice = cleanup.mirror(cleanup.mirror(take.clip))
    for field in ("root_pos", "root_rot", "joint_rot"):
        np.testing.assert_array_equal(getattr(twice, field), getattr(take.clip, field))


def test_mirror_reflects_bodies_and_swaps_sides(humanoid: Humanoid) -> None:
    clip = resolve_clips(["kick"])[0]
    a = MotionLibrary.from_clips([clip], humanoid).frames
    b = MotionLibrary.from_clips([cleanup.mirror(clip)], humanoid).frames
    names = humanoid.body_names
    twin = [names.index(n.replace("left_", "@").replace("right_", "left_").replace("@", "right_")) for n in names]
    # Body b of the mirror is the reflection (y -> -y) of body twin(b) of the original, by MuJoCo's kinematics.
    np.testing.assert_allclose(b.body_pos, a.body_pos[:, twin] * [1.0, -1.0, 1.0], atol=1e-9)


def test_mirror_hand_worked() -> None:
    j = len(DEEPMIMIC_JOINTS)
    rot = np.tile([1.0, 0.0, 0.0, 0.0], (2, j, 1))
    right_hip = [n for n, _, _ in DEEPMIMIC_JOINTS].index("right_hip")
    left_hip = [n for n, _, _ in DEEPMIMIC_JOINTS].index("left_hip")
    rot[:, right_hip] = [math.cos(0.15), math.sin(0.15), 0.0, 0.0]  # 0.3 rad about +x: the leg out to the right
    yaw = [math.cos(0.1), 0.0, 0.0, math.sin(0.1)]  # 0.2 rad left of +x
    clip = Clip("c", "c", False, np.array([0.0, 0.1]), np.array([[1.0, 0.5, 0.9]] * 2), np.array([yaw] * 2), rot)
    m = cleanup.mirror(clip)
    np.testing.assert_allclose(m.root_pos[0], [1.0, -0.5, 0.9])
    np.testing.assert_allclose(m.root_rot[0], [math.cos(0.1), 0.0, 0.0, -math.sin(0.1)])  # 0.2 rad right
    np.testing.assert_allclose(m.joint_rot[0, left_hip], [math.cos(0.15), -math.sin(0.15), 0.0, 0.0])  # out left
    np.testing.assert_allclose(m.joint_rot[0, right_hip], [1.0, 0.0, 0.0, 0.0])


def test_fix_ground_undoes_a_lift(humanoid: Humanoid) -> None:
    walk = resolve_clips(["walk"])[0]
    lifted = replace(walk, root_pos=walk.root_pos + [0.0, 0.0, 0.12])
    fixed, ground = cleanup.fix_ground(lifted, humanoid)
    # The walk's own stance feet sit at -0.5 .. +1.4 cm: the shift is the lift back, to within their spread (measured
    # -12.64 cm). It leaves a stance foot 1.17 cm under the floor at control frames 2 and 40 (one per step): lifted to
    # -0.8 cm, by 3.7 mm, the lift running out at LIFT_SPEED (0.2 m/s) in 0.02 s, rounded over +-0.05 s.
    assert ground.shift == pytest.approx(-0.12, abs=0.015)
    assert ground.deepest == pytest.approx(-0.0117, abs=1e-4)
    assert ground.lift.max() == pytest.approx(-ground.deepest - cleanup.LIFT_TO, abs=1e-5)
    near = (np.abs(walk.times - 2 / 60) < 0.15) | (np.abs(walk.times - 40 / 60) < 0.15)
    assert np.all(ground.lift[~near] == 0.0) and near.mean() < 0.5
    np.testing.assert_allclose(fixed.root_pos[:, 2], lifted.root_pos[:, 2] + ground.shift + ground.lift)


def test_trim_keeps_the_span_and_restarts_time(take: Retargeted) -> None:
    clip = cleanup.trim(take.clip, 1.0, 2.0)
    dt = take.clip.times[1]
    assert clip.times[0] == 0.0 and clip.duration == pytest.approx(1.0, abs=2 * dt)
    first = int(np.ceil(1.0 / dt - 1e-6))
    np.testing.assert_array_equal(clip.joint_rot[0], take.clip.joint_rot[first])
    with pytest.raises(ValueError, match="keeps 0 keyframes"):
        cleanup.trim(take.clip, 20.0, 30.0)


def test_joint_map_errors_name_the_problem(tmp_path: Path, humanoid: Humanoid) -> None:
    with pytest.raises(MotionFormatError, match="no such joint map preset"):
        load_joint_map("nope", humanoid.body_names)
    bad = tmp_path / "map.yaml"
    bad.write_text("up: y\nbodies: {pelvis: Hips, tail: Tail}\n")
    with pytest.raises(MotionFormatError, match=r"map.yaml: 'tail' is not a body"):
        load_joint_map(bad, humanoid.body_names)
    bad.write_text("up: x\nbodies: {pelvis: Hips}\n")
    with pytest.raises(MotionFormatError, match="'up' must be one of"):
        load_joint_map(bad, humanoid.body_names)
    humanoid_map = load_joint_map("humanoid3d", humanoid.body_names)
    with pytest.raises(MotionFormatError, match=r"131_01.bvh: joint map humanoid3d: none of \['pelvis'\]"):
        retarget(read_bvh(TAKE), humanoid, humanoid_map)


def test_given_scale_and_source_root(humanoid: Humanoid) -> None:
    bvh = read_bvh(TAKE)
    cmu = load_joint_map("cmu", humanoid.body_names)
    legs = retarget(bvh, humanoid, cmu, RetargetOptions(scale=0.05))
    source = retarget(bvh, humanoid, cmu, RetargetOptions(scale=0.05, root="source"))
    assert legs.scale_note == "given"
    # The pelvis path is the hips' midpoint times the scale (times the leg ratio for "legs").
    travel = np.diff(source.clip.root_pos[[0, -1], :2], axis=0)
    np.testing.assert_allclose(np.diff(legs.clip.root_pos[[0, -1], :2], axis=0), travel * legs.leg_ratio, rtol=1e-9)


def test_import_command_writes_a_clip_every_command_loads(
    tmp_path: Path, humanoid: Humanoid, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "take.txt"
    assert mimic_motions(["import", str(TAKE), "--fix-ground", "--trim", "0", "4", "--out", str(out)]) == 0
    assert "ground fixed" in capsys.readouterr().out
    library = load_motions([str(out)], humanoid)
    assert library.names == ["take"] and library.duration[0] == pytest.approx(4.0, abs=0.01)  # named by the file
    h5 = tmp_path / "take.h5"
    args = ["import", str(out), "--mirror", "--loop", "wrap", "--name", "mirrored", "--out", str(h5)]
    assert mimic_motions(args) == 0
    again = load_motions([str(h5)], humanoid)
    assert again.names == ["mirrored"] and bool(again.loop[0])
    assert mimic_motions(["summary", str(out)]) == 0
    assert "take" in capsys.readouterr().out


def test_import_of_a_bad_file_fails_in_one_line_and_keeps_the_old_output(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.bvh"
    bad.write_text(TAKE.read_text().replace("Frame Time: .0083333", "Frame Time: 0"))
    out = tmp_path / "kept.txt"
    out.write_text("precious")
    assert mimic_motions(["import", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: {bad}: line 187: frame time must be positive, got 0"
    assert out.read_text() == "precious"
