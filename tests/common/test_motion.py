"""Motion import, the motion library and the HDF5 motion dataset."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest

from common.character.humanoid import BodyGeometry, Humanoid
from common.maths.rotations import angular_velocity, quat_geodesic_angle, quat_rotate, quat_yaw
from common.motion.dataset import bundled_motion_dir, load_dataset, resolve_clips, save_dataset
from common.motion.library import MotionLibrary
from common.motion.motion import (
    Clip,
    MotionFormatError,
    read_clip_pack,
    read_deepmimic,
    y_up_to_z_up_pos,
    y_up_to_z_up_quat,
)

DT = 1.0 / 60.0


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


@pytest.fixture(scope="module")
def walk_lib(humanoid: Humanoid) -> MotionLibrary:
    return MotionLibrary.from_clips(resolve_clips(["walk"]), humanoid)


@pytest.fixture(scope="module")
def lib3(humanoid: Humanoid) -> MotionLibrary:
    return MotionLibrary.from_clips(resolve_clips(["walk", "run", "kick"]), humanoid)


def _row(dur: float = 1 / 30, knee: float = 0.0) -> list[float]:
    ident = [1.0, 0.0, 0.0, 0.0]
    row = [dur, 0.0, 0.85, 0.0, *ident]
    for kind in ("s", "s", "s", "r", "s", "s", "r", "s", "r", "s", "s", "r"):
        row += ident if kind == "s" else [knee]
    assert len(row) == 44
    return row


def _write(tmp_path: Path, frames: object, loop: str = "none", name: str = "clip.txt") -> Path:
    p = tmp_path / name
    p.write_text(json.dumps({"Loop": loop, "Frames": frames}))
    return p


def test_y_up_to_z_up_by_hand() -> None:
    np.testing.assert_allclose(y_up_to_z_up_pos(np.array([1.0, 2.0, 3.0])), [1.0, -3.0, 2.0])
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    # 90 deg about Y (DeepMimic's vertical) is 90 deg about Z (ours); 90 deg about Y-up's Z is 90 deg about -Y.
    np.testing.assert_allclose(y_up_to_z_up_quat(np.array([c, 0, s, 0])), [c, 0, 0, s], atol=1e-12)
    np.testing.assert_allclose(y_up_to_z_up_quat(np.array([c, 0, 0, s])), [c, 0, -s, 0], atol=1e-12)


def test_knee_angle_is_negated_onto_plus_y(tmp_path: Path, humanoid: Humanoid) -> None:
    clip = read_deepmimic(_write(tmp_path, [_row(knee=-0.5), _row(knee=-0.5)]))
    lib = MotionLibrary.from_clips([clip], humanoid)
    knee = next(g for g in humanoid.joint_groups if g.name == "right_knee")
    np.testing.assert_allclose(lib.frames.qpos[:, knee.qpos[0]], 0.5, atol=1e-12)
    # Flexing the knee moves the ankle backwards (-x) for a character facing +x.
    ankle_x = lib.frames.body_pos[0, humanoid.body_index("right_foot"), 0]
    assert ankle_x == pytest.approx(-0.40987 * math.sin(0.5), abs=1e-9)


def test_resampling_hits_source_keyframes(walk_lib: MotionLibrary) -> None:
    src = resolve_clips(["walk"])[0]  # 30 fps source: every second 60 Hz frame is a keyframe
    assert src.source_fps == pytest.approx(30.0, rel=1e-3)
    # The wrap clip is time-scaled to a whole number of frames per cycle: 38 x 0.033332 s -> 76 frames of 1/60 s.
    assert walk_lib.num_frames[0] == 77 and walk_lib.duration[0] == pytest.approx(76 * DT)
    scale = walk_lib.duration[0] / src.duration
    assert abs(scale - 1.0) < 1e-4
    k = np.arange(0, 30)
    got = walk_lib.query(np.zeros(len(k), dtype=int), src.times[k] * scale).qpos[:, :2]
    np.testing.assert_allclose(got, src.root_pos[k, :2], atol=1e-9)


def test_walk_feet_stay_near_ground(walk_lib: MotionLibrary, humanoid: Humanoid) -> None:
    low = BodyGeometry(humanoid).lowest_points(walk_lib.frames.body_pos, walk_lib.frames.body_rot)
    low = low[:, humanoid.foot_indices].min(axis=-1)
    assert -0.01 < low.min() < 0.0 and 0.0 < low.max() < 0.02  # data README: -0.005 .. +0.014 m


def test_velocities_match_finite_differences(lib3: MotionLibrary) -> None:
    f = lib3.frames
    for c in range(lib3.num_clips):
        s = slice(lib3.start[c] + 1, lib3.start[c] + lib3.num_frames[c] - 1)
        prev = slice(s.start - 1, s.stop - 1)
        nxt = slice(s.start + 1, s.stop + 1)
        fd_lin = (f.body_pos[nxt] - f.body_pos[prev]) / (2 * DT)
        fd_ang = angular_velocity(f.body_rot[prev], f.body_rot[nxt], 2 * DT)
        # Central differences of a smooth motion agree to a small fraction of the speed.
        scale = np.abs(f.body_linvel[s]).max()
        assert np.abs(fd_lin - f.body_linvel[s]).mean() < 0.02 * scale, lib3.names[c]
        assert np.abs(fd_ang - f.body_angvel[s]).mean() < 0.02 * np.abs(f.body_angvel[s]).max(), lib3.names[c]
        fd_q = (f.qpos[nxt, 7:] - f.qpos[prev, 7:]) / (2 * DT)
        np.testing.assert_allclose(f.qvel[s, 6:], fd_q, atol=1e-9)


def test_wrap_clip_continuous_across_loop(walk_lib: MotionLibrary) -> None:
    dur = walk_lib.duration[0]
    eps = 1e-7
    for cycle in (1, 2, 5):
        before = walk_lib.query(np.array([0]), np.array([cycle * dur - eps]))
        after = walk_lib.query(np.array([0]), np.array([cycle * dur + eps]))
        np.testing.assert_allclose(before.qpos[:, :3], after.qpos[:, :3], atol=1e-5)
        assert quat_yaw(before.qpos[0, 3:7]) == pytest.approx(quat_yaw(after.qpos[0, 3:7]), abs=1e-5)
        assert np.abs(before.body_pos - after.body_pos).max() < 1e-4
        assert np.abs(before.body_linvel - after.body_linvel).max() < 0.05
    # The character keeps walking forward: one cycle later it is one cycle's displacement further along.
    start = walk_lib.query(np.array([0, 0]), np.array([0.1, 0.1 + 3 * dur]))
    step = walk_lib.cycle_shift[0, 0]
    assert step > 0.5
    assert start.qpos[1, 0] - start.qpos[0, 0] == pytest.approx(3 * step, rel=0.05)


def test_hinge_angles_run_on_across_a_seam_where_the_cycle_winds_a_whole_turn(humanoid: Humanoid) -> None:
    """dance_a's shoulders' x and z Euler angles end the cycle 2 pi from where they began (the same rotation): the
    hinge angles, which the gym uses as PD targets, must not jump back by 2 pi at a seam, and the angles of later
    cycles must still pose the character where the library says its bodies are (MuJoCo's own kinematics)."""
    from common.motion.library import body_states

    lib = MotionLibrary.from_clips(resolve_clips(["dance_a", "walk"]), humanoid)
    dur = lib.duration[0]
    wind = lib.cycle_wind[0, humanoid.hinge_qpos]
    names = [humanoid.model.actuator(a).name for a in range(humanoid.nu)]
    wound = sorted(names[a] for a in np.flatnonzero(wind))
    assert wound == ["left_shoulder_x", "left_shoulder_z", "right_shoulder_x", "right_shoulder_z"]
    np.testing.assert_allclose(wind[np.flatnonzero(wind)], -2 * np.pi, atol=1e-12)
    assert not lib.cycle_wind[1].any()  # walk closes its cycle without a turn
    for cycle in (1, 2):
        t = cycle * dur + np.array([-2 * DT, -DT, 0.0, DT])
        state = lib.query(np.zeros(4, dtype=np.int64), t)
        assert np.abs(np.diff(state.qpos[:, humanoid.hinge_qpos], axis=0)).max() < 0.5
        posed = body_states(humanoid, state.qpos, state.qvel)
        np.testing.assert_allclose(posed.body_pos, state.body_pos, atol=1e-6)


def test_loop_bend_keeps_the_recorded_ground_clearance(humanoid: Humanoid) -> None:
    # The jump's first and last keyframes differ by 15-20 deg at the hips and knees. Bending them closed moves the
    # feet; without the root-height correction the looped jump had its feet 7.9 cm in the floor after the landing,
    # where the recorded clip (played one-shot, no bend) has them at most 1.8 cm below it.
    clip = resolve_clips(["jump"])[0]
    assert clip.loop
    geometry = BodyGeometry(humanoid)
    looped = MotionLibrary.from_clips([clip], humanoid)
    recorded = MotionLibrary.from_clips([replace(clip, loop=False)], humanoid)
    low_loop = geometry.lowest_points(looped.frames.body_pos, looped.frames.body_rot).min(axis=-1)
    low_rec = geometry.lowest_points(recorded.frames.body_pos, recorded.frames.body_rot).min(axis=-1)
    assert low_rec.min() == pytest.approx(-0.018, abs=0.002)
    assert low_loop.min() > -0.03
    # Frame by frame: the recorded clearance, minus the seam's own clearance mismatch taken out by a smoothstep over the
    # last 0.5 s (the wrap grid is time-scaled by < 1 %, so the frames are compared within 1.5 cm, not exactly).
    # On the frames that touch the floor (in flight the root follows its recorded parabola instead: next test).
    n = min(len(low_loop), len(low_rec))
    u = np.clip((np.arange(n) * DT - (looped.duration[0] - 0.5)) / 0.5, 0.0, 1.0)
    expected = low_rec[:n] - u * u * (3 - 2 * u) * (low_rec[-1] - low_rec[0])
    touching = low_rec[:n] < 0.02
    assert touching.sum() > n / 2
    assert np.abs(low_loop[:n] - expected)[touching].max() < 0.015
    # The correction is zero at both ends: the loop stays closed.
    dur = looped.duration[0]
    before = looped.query(np.array([0]), np.array([dur - 1e-7]))
    after = looped.query(np.array([0]), np.array([dur + 1e-7]))
    assert np.abs(before.body_pos - after.body_pos).max() < 1e-4


def test_loop_bend_keeps_the_recorded_flight_parabola(humanoid: Humanoid) -> None:
    """run: in flight (the recorded lowest point more than 3 cm above the floor) the root-height shift of the bend is
    linear in time, so the root's vertical acceleration there is the recorded one (a shift that followed each flight
    keyframe's foot moved the root by up to 13 cm in the air); on the keyframes that touch, it keeps the clearance."""
    from common.motion.library import FLIGHT_CLEARANCE, _bend_loop, _lowest_point

    clip = resolve_clips(["run"])[0]
    root_pos, root_rot, joint_rot = _bend_loop(clip, humanoid)
    shift = root_pos[:, 2] - clip.root_pos[:, 2]
    recorded = _lowest_point(humanoid, clip.root_pos, clip.root_rot, clip.joint_rot)
    bent = _lowest_point(humanoid, root_pos, root_rot, joint_rot)
    flight = recorded > FLIGHT_CLEARANCE
    assert 0.2 < flight.mean() < 0.5  # run's keyframes: about a third in the air
    t = clip.times
    # Second differences of the shift at keyframes whose neighbours are in flight too: zero (linear in time).
    inner = np.flatnonzero(flight[1:-1] & flight[:-2] & flight[2:]) + 1
    assert len(inner) >= 2
    slope = np.diff(shift) / np.diff(t)
    np.testing.assert_allclose(slope[inner], slope[inner - 1], atol=1e-9)
    # The bend itself is not zero there (else the check would be empty): the old per-keyframe rule would have moved
    # the root by the change of the bent pose's clearance.
    assert np.abs((recorded - bent)[flight] - (recorded - bent)[flight].mean()).max() > 0.01
    # Touching keyframes before the seam's blend (the last 0.5 s) keep the recorded clearance exactly.
    touch = ~flight & (t < clip.duration - 0.5)
    assert touch.sum() >= 3
    np.testing.assert_allclose(bent[touch], recorded[touch], atol=1e-9)


def _bridge_case(humanoid: Humanoid) -> tuple[Clip, np.ndarray, np.ndarray, np.ndarray]:
    """A closed wrap clip at 10 Hz over 1 s whose velocities jump at the seam: root x = t^2 (the cycle transform
    moves the next cycle 1 m along x: its root starts at 0 m/s where this one ends at 2 m/s) and the neck turned
    about z by t (1 - t) rad (1 rad/s at the start, -1 rad/s at the end), 2 m up (no foot near the floor)."""
    t = np.linspace(0.0, 1.0, 11)
    root_pos = np.stack([t**2, np.zeros_like(t), np.full_like(t, 2.0)], axis=1)
    root_rot = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))
    joint_rot = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 12, 1))
    half = 0.5 * t * (1.0 - t)
    joint_rot[:, 1] = np.stack([np.cos(half), 0 * t, 0 * t, np.sin(half)], axis=1)  # 1: the neck
    clip = Clip("bridge", "bridge.txt", True, t, root_pos, root_rot, joint_rot)
    return clip, root_pos, root_rot, joint_rot


def test_loop_seam_bridge_by_hand(humanoid: Humanoid) -> None:
    """At 10 Hz the bridge replaces 2 keyframes either side of the seam by the cubic Hermite curve from t = 0.8
    (x = 0.64, v = 1.6) to the next cycle's t = 0.2 (x = 1.04, v = 0.4) over 0.4 s; at the seam it is
    0.32 + 0.125 * 0.4 * 1.6 + 0.52 - 0.125 * 0.4 * 0.4 = 0.90, at t = 0.9 0.785 (weights 0.84375, 0.140625,
    0.15625, -0.046875). The neck angle: from 0.16 (v = -0.6) to 0.16 (v = 0.6), 0.10 at the seam."""
    from common.motion.library import _bridge_seam

    clip, root_pos, root_rot, joint_rot = _bridge_case(humanoid)
    pos, rot, jrot = _bridge_seam(clip, humanoid, root_pos, root_rot, joint_rot, width=0.1)
    np.testing.assert_allclose(pos[[9, 10, 0, 1], 0], [0.785, 0.90, -0.10, 0.785 - 1.0 + 0.2], atol=1e-12)
    # t = 0.1 in the next cycle is u = 0.75: the mirror weights of u = 0.25 on the swapped ends.
    x_11 = 0.15625 * 0.64 + 0.046875 * 0.4 * 1.6 + 0.84375 * 1.04 - 0.140625 * 0.4 * 0.4
    assert pos[1, 0] == pytest.approx(x_11 - 1.0, abs=1e-12)
    neck = 2.0 * np.arctan2(jrot[:, 1, 3], jrot[:, 1, 0])
    assert neck[10] == pytest.approx(0.10, abs=1e-12) and neck[0] == pytest.approx(0.10, abs=1e-12)
    # Outside the window nothing moves; the rest of the pose is untouched; the loop stays closed.
    keep = np.arange(2, 9)
    np.testing.assert_array_equal(pos[keep], root_pos[keep])
    np.testing.assert_allclose(neck[keep], 2.0 * np.arctan2(joint_rot[keep, 1, 3], joint_rot[keep, 1, 0]), atol=1e-15)
    np.testing.assert_allclose(pos[:, 1:], root_pos[:, 1:], atol=1e-12)
    np.testing.assert_allclose(rot, root_rot, atol=1e-12)
    others = np.delete(np.arange(12), 1)
    np.testing.assert_allclose(jrot[:, others], joint_rot[:, others], atol=1e-12)
    # The width 0 leaves the clip as it was.
    same = _bridge_seam(clip, humanoid, root_pos, root_rot, joint_rot, width=0.0)
    assert all(a is b for a, b in zip(same, (root_pos, root_rot, joint_rot), strict=True))


def test_loop_seam_is_continuous_in_velocity(humanoid: Humanoid) -> None:
    """zombie_walk's root velocity jumps at every seam (its last keyframes rise 1.5 cm in 1/60 s); bridged (opt-in),
    the frame-to-frame change of the reference's root velocity at the seams is well below the largest inside the
    cycle. The default library leaves the seam as it was."""
    from common.motion.library import SEAM_BRIDGE

    clips = resolve_clips(["zombie_walk"])
    for bridge in (0.0, SEAM_BRIDGE):
        lib = MotionLibrary.from_clips(clips, humanoid, seam_bridge=bridge)
        n = lib.num_frames[0] - 1
        t = np.arange(0, 3 * n + 1) * lib.dt
        vel = lib.query(np.zeros(len(t), dtype=int), t).qvel[:, :3]
        change = np.linalg.norm(np.diff(vel, axis=0), axis=-1)  # change[i]: frame i -> i + 1
        seams = np.concatenate([np.arange(s - 3, s + 3) for s in (n, 2 * n)])
        inside = np.setdiff1d(np.arange(len(change)), seams)
        # Unbridged, 0.54 m/s at the seams, the largest change of the whole motion; bridged 0.12, inside up to 0.38.
        if bridge:
            assert change[seams].max() < 0.5 * change[inside].max()
        else:
            assert change[seams].max() >= change[inside].max()
    default = MotionLibrary.from_clips(clips, humanoid)
    np.testing.assert_array_equal(default.frames.qpos, MotionLibrary.from_clips(clips, humanoid, 0.0).frames.qpos)
    with pytest.raises(ValueError, match="zombie_walk.*seam_bridge must be >= 0 s"):
        MotionLibrary.from_clips(clips, humanoid, seam_bridge=-0.1)


def test_loop_seam_bridge_lifts_a_foot_that_lands_in_the_window(humanoid: Humanoid) -> None:
    """dance_a's foot lands just before the seam: the cubic would take it 1.6 cm into the floor, which the bridge's
    lift takes out (no bridged keyframe lower than the floor or the window's ends)."""
    from common.motion.library import _bend_loop, _bridge_seam, _lowest_point

    clip = resolve_clips(["dance_a"])[0]
    bent = _bend_loop(clip, humanoid)
    pos, rot, jrot = _bridge_seam(clip, humanoid, *bent, width=0.1)
    low = _lowest_point(humanoid, pos, rot, jrot)
    window = np.r_[0:6, len(low) - 6 : len(low)]
    assert low[window].min() > -1e-9
    lifted = pos[window, 2] - bent[0][window, 2]
    assert lifted.max() > 0.005  # the lift did something (else the check above would be empty)


def test_one_shot_clip_holds_last_frame(lib3: MotionLibrary) -> None:
    kick = lib3.clip_index("kick")
    end = lib3.end_time[kick]
    assert np.isfinite(end) and not lib3.loop[kick]
    a = lib3.query(np.array([kick]), np.array([end]))
    b = lib3.query(np.array([kick]), np.array([end + 10.0]))
    np.testing.assert_allclose(a.qpos, b.qpos)


def test_vectorised_query_equals_single_queries(lib3: MotionLibrary) -> None:
    rng = np.random.default_rng(0)
    clips = rng.integers(0, lib3.num_clips, size=40)
    times = rng.random(40) * 5.0
    batch = lib3.query(clips, times)
    for i in range(40):
        one = lib3.query(clips[i : i + 1], times[i : i + 1])
        for field in ("qpos", "qvel", "body_pos", "body_rot", "body_linvel", "body_angvel"):
            np.testing.assert_array_equal(getattr(batch, field)[i], getattr(one, field)[0])


def test_query_between_frames_interpolates(walk_lib: MotionLibrary) -> None:
    a = walk_lib.query(np.array([0]), np.array([3 * DT]))
    b = walk_lib.query(np.array([0]), np.array([4 * DT]))
    mid = walk_lib.query(np.array([0]), np.array([3.5 * DT]))
    np.testing.assert_allclose(mid.body_pos, 0.5 * (a.body_pos + b.body_pos), atol=1e-12)
    half = quat_geodesic_angle(a.body_rot, mid.body_rot)
    np.testing.assert_allclose(half, 0.5 * quat_geodesic_angle(a.body_rot, b.body_rot), atol=1e-5)


def test_body_states_match_world_rotation_of_offsets(walk_lib: MotionLibrary, humanoid: Humanoid) -> None:
    """A child's position is its parent's position plus the parent's rotation applied to the joint offset."""
    f = walk_lib.frames
    thigh = humanoid.body_index("right_thigh")
    shin = humanoid.body_index("right_shin")
    offset = humanoid.model.body_pos[shin + 1]
    np.testing.assert_allclose(
        f.body_pos[:, shin], f.body_pos[:, thigh] + quat_rotate(f.body_rot[:, thigh], offset), atol=1e-12
    )


def test_sample_starts_respects_weights(lib3: MotionLibrary) -> None:
    rng = np.random.default_rng(1)
    clips, times = lib3.sample_starts(2000, rng, weights=np.array([1.0, 0.0, 3.0]))
    assert set(np.unique(clips)) == {0, 2}
    assert 0.7 < np.mean(clips == 2) < 0.8
    assert np.all(times >= 0)
    assert np.all(times[clips == 2] < lib3.end_time[2])  # one-shot: at least one step left
    np.testing.assert_allclose(times / DT, np.round(times / DT), atol=1e-9)
    with pytest.raises(ValueError, match="weights"):
        lib3.sample_starts(3, rng, weights=np.array([0.0, 0.0, 0.0]))


def test_clip_weights_by_name_give_one_weight_per_clip_in_library_order(lib3: MotionLibrary) -> None:
    assert lib3.clip_weights({}) is None  # uniform
    np.testing.assert_array_equal(lib3.clip_weights({"kick": 0.0, "walk": 10.0}), [10.0, 1.0, 0.0])
    with pytest.raises(ValueError, match=r"'wlak': no such clip among the motions \(walk, run, kick\)"):
        lib3.clip_weights({"wlak": 10.0})
    with pytest.raises(ValueError, match=r"'run' must be >= 0, got -1"):
        lib3.clip_weights({"run": -1.0})
    with pytest.raises(ValueError, match="all 0"):
        lib3.clip_weights({"walk": 0.0, "run": 0.0, "kick": 0.0})


def test_bundled_long_clips_load() -> None:
    clips = read_clip_pack(bundled_motion_dir() / "long_clips.h5")
    assert len(clips) == 9
    assert sum(c.duration for c in clips) == pytest.approx(301.0, abs=1.0)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{not json", "not valid JSON"),
        (json.dumps({"Loop": "none", "Frames": []}), "no frames"),
        (json.dumps({"Loop": "none", "Frames": [_row(), _row()[:40]]}), "frame 1: expected 44 values, got 40"),
        (
            json.dumps({"Loop": "none", "Frames": [_row(), [*_row()[:5], float("nan"), *_row()[6:]]]}).replace(
                "NaN", "NaN"
            ),
            "frame 1: value nan",
        ),
        (
            json.dumps({"Loop": "none", "Frames": [_row(), [*_row()[:8], 0, 0, 0, 0, *_row()[12:]]]}),
            "frame 1: zero-length quaternion for joint 'chest'",
        ),
        (json.dumps({"Loop": "none", "Frames": [_row(dur=0.0), _row()]}), "frame 0: frame duration must be positive"),
        (json.dumps({"Loop": "once", "Frames": [_row(), _row()]}), "'Loop' must be one of"),
        (json.dumps({"Loop": "none", "Frames": [_row(), [*_row()[:1], 1e30, *_row()[2:]]]}),
         "frame 1: root 1e+30 m from the origin, farther than 100 m"),
        (json.dumps({"Loop": "none", "Frames": [_row(), [0.0, 60.0, 80.1, 0.0, *_row()[4:]]]}),
         "frame 1: root 100.08 m from the origin, farther than 100 m"),  # sqrt(60^2 + 80.1^2)
        (json.dumps({"Loop": "none", "Frames": [_row(dur=1.5), _row()]}),
         "frame 0: frame duration 1.5 s is above 1 s"),
        (json.dumps({"Loop": "none", "Frames": [_row(), _row(dur=5e-5), _row()]}),
         "frame 1: frame duration 5e-05 s is below 0.0001 s"),
        (json.dumps({"Loop": "none", "Frames": [_row(dur=1.0)] * 601 + [_row()]}),
         "the clip lasts 601 s, longer than 600 s"),
        (json.dumps({"Loop": "none", "Frames": [_row(), [*_row()[:4], 3.0, 4.0, 0.0, 12.0, *_row()[8:]]]}),
         "frame 1: quaternion of length 13 for joint 'root' is not a rotation"),  # sqrt(9 + 16 + 144)
        (json.dumps({"Loop": "none", "Frames": [_row(), [*_row()[:8], 1e200, 0, 0, 0, *_row()[12:]]]}),
         "frame 1: quaternion of length 1e+200 for joint 'chest' is not a rotation"),
        (json.dumps({"Loop": "none", "Frames": [_row(), [*_row()[:3], "0.85", *_row()[4:]]]}),
         "frame 1: column 3 holds '0.85' (a string), not a number"),
        (json.dumps({"Loop": "none", "Frames": [_row(), [*_row()[:9], True, *_row()[10:]]]}),
         "frame 1: column 9 holds true, not a number"),
        (json.dumps({"Loop": "none", "Frames": [_row()]}), "a clip needs at least 2 frames, got 1"),
        ('{"Loop": "none", "Frames": [[' + "1" * 5000 + "]]}", "an integer of 5,000 digits"),
        (json.dumps({"Loop": "none", "Frames": [_row(), _row(knee=7.0)]}),
         "frame 1: 'right_knee' angle 7 rad is beyond 6.28319 rad"),
    ],
)
def test_bad_clip_fails_naming_file_and_frame(tmp_path: Path, content: str, message: str) -> None:
    p = tmp_path / "bad_clip.txt"
    p.write_text(content)
    with pytest.raises(MotionFormatError) as err:
        read_deepmimic(p)
    assert str(p) in str(err.value) and message in str(err.value)


def test_binary_clip_fails_naming_file_and_byte(tmp_path: Path) -> None:
    p = tmp_path / "clip.txt"
    text = b'{"Loop": "none", "Frames": [[0.03'
    p.write_bytes(text + b"\xff\xfe\x00\x01")
    with pytest.raises(MotionFormatError, match=rf"{p}: not a text file \(byte 0xff at offset {len(text)} is not"):
        read_deepmimic(p)


def test_unknown_motion_spec_lists_bundled_clips() -> None:
    with pytest.raises(MotionFormatError, match="walk"):
        resolve_clips(["no_such_clip"])


def test_dataset_round_trip(tmp_path: Path, lib3: MotionLibrary, humanoid: Humanoid) -> None:
    path = tmp_path / "motions.h5"
    save_dataset(path, lib3, humanoid)
    back = load_dataset(path, humanoid)
    assert back.names == lib3.names
    np.testing.assert_array_equal(back.loop, lib3.loop)
    rng = np.random.default_rng(2)
    clips, times = rng.integers(0, 3, 30), rng.random(30) * 4
    a, b = lib3.query(clips, times), back.query(clips, times)
    np.testing.assert_array_equal(a.body_pos, b.body_pos)
    np.testing.assert_array_equal(a.qvel, b.qvel)


def test_dataset_truncated_or_other_version_fails_clearly(
    tmp_path: Path, walk_lib: MotionLibrary, humanoid: Humanoid
) -> None:
    path = tmp_path / "motions.h5"
    save_dataset(path, walk_lib, humanoid)
    data = path.read_bytes()
    cut = tmp_path / "cut.h5"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(MotionFormatError, match="cut.h5"):
        load_dataset(cut, humanoid)
    with h5py.File(path, "a") as f:
        f.attrs["version"] = 99
    with pytest.raises(MotionFormatError, match="version 99"):
        load_dataset(path, humanoid)
    # Version 1 (before the loop fix) loads, with a warning naming the looped clips and the way out.
    with h5py.File(path, "a") as f:
        f.attrs["version"] = 1
    with pytest.warns(UserWarning, match=r"version-1 motion dataset: its looped clips \(walk\).*mimic-motions convert"):
        assert load_dataset(path, humanoid).names == walk_lib.names
    from common.character.humanoid import PhysicsConfig

    save_dataset(path, walk_lib, humanoid)
    with pytest.raises(MotionFormatError, match="30.0 Hz"):
        load_dataset(path, Humanoid(PhysicsConfig(control_hz=30.0)))


@pytest.mark.parametrize(("field", "frame", "value", "message"), [
    ("qpos", 5, 1e30, r"clip 'walk': frame 5: root 1e\+30 m from the origin, farther than 100 m"),
    ("body_linvel", 7, float("inf"), r"clip 'walk': frame 7: body_linvel holds a value that is not finite"),
])  # fmt: skip
def test_dataset_with_values_out_of_bounds_fails_naming_clip_and_frame(
    tmp_path: Path, walk_lib: MotionLibrary, humanoid: Humanoid, field: str, frame: int, value: float, message: str
) -> None:
    path = tmp_path / "motions.h5"
    save_dataset(path, walk_lib, humanoid)
    with h5py.File(path, "a") as f:
        f[f"clips/walk/{field}"][frame, 0] = value
    with pytest.raises(MotionFormatError, match=rf"{path}: {message}"):
        load_dataset(path, humanoid)


def test_failed_dataset_write_keeps_good_file(
    tmp_path: Path, walk_lib: MotionLibrary, humanoid: Humanoid, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "motions.h5"
    save_dataset(path, walk_lib, humanoid)
    good = path.read_bytes()

    def broken(*args: object, **kwargs: object) -> None:
        raise RuntimeError("disk full")

    monkeypatch.setattr(h5py.Group, "create_dataset", broken)
    with pytest.raises(RuntimeError, match="disk full"):
        save_dataset(path, walk_lib, humanoid)
    assert path.read_bytes() == good
    assert not list(tmp_path.glob("*.tmp"))
