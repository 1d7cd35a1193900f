"""``mimic-motions fit-terrain``: a clip fitted to a terrain (stance feet on it, the root raised per frame, smoothed),
the flat special case equal to the ground fix, a clip off its terrain refused in one line, and the output read back
with its terrain by every reader."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from common.character.humanoid import DEEPMIMIC_JOINTS, Humanoid
from common.motion.dataset import load_motions, resolve_clips
from common.motion.library import MotionLibrary
from common.motion.motion import Clip, read_clip_pack, read_deepmimic, write_clip_pack
from common.motion.motion_import import cleanup, terrain_fit
from common.motion.terrain import Terrain, sidecar_path
from common.motion.terrain_generator import generate, stairs
from common.tools.motions import main as mimic_motions

DT = 1 / 60
BOX = 0.10  # m


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


def _box_terrain() -> Terrain:
    """5 cm cells over x -1 .. 2.5, y -1 .. 1; a 10 cm box over 0.6 <= x <= 1.6, |y| <= 0.5."""
    xs, ys = -1.0 + 0.05 * np.arange(71), -1.0 + 0.05 * np.arange(41)
    heights = np.zeros((len(ys), len(xs)))
    heights[np.ix_(np.abs(ys) <= 0.5 + 1e-9, (xs >= 0.6 - 1e-9) & (xs <= 1.6 + 1e-9))] = BOX
    return Terrain(heights, 0.05, np.array([-1.0, -1.0]))


@pytest.fixture(scope="module")
def standing(humanoid: Humanoid) -> Clip:
    """The zero pose standing still at x = 0 for 1 s, gliding to x = 1 in 0.3 s (feet too fast for stance), standing
    still there until 2.5 s; its feet on the floor while it stands."""
    times = np.arange(151) * DT
    u = np.clip((times - 1.0) / 0.3, 0.0, 1.0)
    root = np.zeros((len(times), 3))
    root[:, 0] = u * u * (3 - 2 * u)
    root[:, 2] = 1.0
    rot = np.tile([1.0, 0.0, 0.0, 0.0], (len(times), 1))
    joints = np.tile([1.0, 0.0, 0.0, 0.0], (len(times), len(DEEPMIMIC_JOINTS), 1))
    clip = Clip("stand", "stand", False, times, root, rot, joints)
    low = cleanup.foot_contact(clip, humanoid).height.min()
    return replace(clip, root_pos=root - [0.0, 0.0, low])


def test_a_standing_clip_rises_by_the_box_where_its_feet_stand_on_it(standing: Clip, humanoid: Humanoid) -> None:
    feet = cleanup.foot_contact(standing, humanoid)
    assert np.abs(feet.height[feet.stance]).max() < 1e-12  # both feet flat on the floor while standing
    terrain = _box_terrain()
    fitted, fit = terrain_fit.fit_terrain(standing, humanoid, terrain)
    rise = fitted.root_pos[:, 2] - standing.root_pos[:, 2]
    # Standing at x = 0 (on the floor) the root stays; standing at x = 1 (both feet on the box) it is 10 cm higher.
    # Between, the offset ramps during the glide; the smoothing (a running maximum and a Hann window of +-3 frames)
    # reaches 6 frames beyond the stance frames' ends.
    assert np.abs(rise[standing.times < 0.9]).max() < 1e-12
    np.testing.assert_allclose(rise[standing.times > 1.4], BOX, rtol=0, atol=1e-12)
    assert fit.ground.shift == pytest.approx(0.0, abs=1e-12) and not fit.ground.lift.any()
    # The feet rest on the box as they rested on the floor; the clip carries the terrain.
    assert fitted.terrain is terrain
    on = cleanup.foot_contact(fitted, humanoid)
    late = standing.times[: len(on.height)] > 1.4
    assert np.abs(on.height[late]).max() < 1e-12 and on.stance[late].all()
    # No jump: the root never moves faster vertically than the fit allows, and the offset ramps up monotonically.
    assert np.abs(np.diff(rise)).max() <= terrain_fit.FIT_SPEED * DT + 1e-12
    assert np.all(np.diff(rise) >= -1e-15)
    assert fit.before[0] == pytest.approx(-BOX, abs=1e-9) and fit.after[0] == pytest.approx(0.0, abs=1e-9)
    # Fitted again to level ground, the clip moves from its own terrain to that one: back where it stood.
    level = Terrain(np.zeros_like(terrain.heights), terrain.cell_size, terrain.origin)
    back, _ = terrain_fit.fit_terrain(fitted, humanoid, level)
    away = (standing.times < 0.9) | (standing.times > 1.4)
    np.testing.assert_allclose(back.root_pos[away], standing.root_pos[away], rtol=0, atol=1e-12)


def test_the_target_hands_over_linearly_in_double_support() -> None:
    # Foot 0 stands on 0 m over frames 0-4, foot 1 on 1 m over frames 3-7: in double support (3, 4) the weights are
    # each foot's distance to the nearer end of its stance (0: 2, 1; 1: 1, 2); a stance running off the clip has no
    # end there.
    stance = np.zeros((8, 2), bool)
    stance[:5, 0] = stance[3:, 1] = True
    ground = np.tile([0.0, 1.0], (8, 1))
    target = terrain_fit.stance_target(ground, stance, np.zeros((8, 2)))
    np.testing.assert_allclose(target, [0, 0, 0, 1 / 3, 2 / 3, 1, 1, 1], rtol=0, atol=1e-15)
    # No foot in stance over frames 3-4: linear in time between the neighbours.
    stance[3:5] = False
    np.testing.assert_allclose(terrain_fit.stance_target(ground, stance, np.zeros((8, 2))),
                               [0, 0, 0, 1 / 3, 2 / 3, 1, 1, 1], rtol=0, atol=1e-15)  # fmt: skip
    # Both feet over the whole clip: alike, the mean.
    both = terrain_fit.stance_target(ground, np.ones((8, 2), bool), np.zeros((8, 2)))
    np.testing.assert_allclose(both, 0.5, rtol=0, atol=1e-15)


@pytest.mark.parametrize("lift", [0.12, -0.03])
def test_on_a_flat_terrain_the_fit_is_the_ground_fix(humanoid: Humanoid, lift: float) -> None:
    # 12 cm up: the shift brings it back, and the local lift takes a stance foot out of the floor at two frames
    # (tests/common/test_motion_import.py); 3 cm down: the shift alone.
    walk = resolve_clips(["walk"])[0]
    moved = replace(walk, root_pos=walk.root_pos + [0.0, 0.0, lift])
    flat = Terrain(np.zeros((41, 81)), 0.05, np.array([-1.0, -1.0]))
    fitted, fit = terrain_fit.fit_terrain(moved, humanoid, flat)
    fixed, ground = cleanup.fix_ground(moved, humanoid)
    for field in ("times", "root_pos", "root_rot", "joint_rot"):
        np.testing.assert_array_equal(getattr(fitted, field), getattr(fixed, field))
    assert fitted.loop == fixed.loop and not fit.loop_opened and fitted.terrain is flat
    assert not fit.offset.any() and fit.ground.shift == ground.shift
    np.testing.assert_array_equal(fit.ground.lift, ground.lift)
    if lift > 0:
        assert ground.lift.any()


def test_a_clip_off_its_terrain_is_refused_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "walk_up.txt"
    # The strip begins at x = 0; the walk's rear foot starts behind it.
    argv = ["fit-terrain", "walk", "--terrain", "stairs", "--param", "before=0", "--out", str(out)]
    assert mimic_motions(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and "leaves its terrain" in err
    assert "beyond the terrain's x 0.00 to 2.80 m, y -1.00 to 1.00 m" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("argv", "problem"),
    [
        (["--terrain", "stairs", "--param", "risers=3"], "'risers=3' is not NAME=VALUE for one of its parameters"),
        (["--terrain", "stairs", "--param", "step_height=0.5"], "step_height 0.5 is outside 0.05 to 0.15"),
        (["--terrain", "stairs", "--param", "steps=many"], "steps='many' is not an integer"),
        (["--terrain", "hills"], "hills: no such motion file"),
        (["--terrain", "walk"], "--terrain walk: its clips carry 0 terrains"),
        (["--terrain", "x.terrain.h5", "--param", "steps=3"], "parameters are for the generator's kinds"),
        (["--terrain", "slope", "--cycles", "2"], "only a wrap clip can be unrolled"),
    ],
)
def test_bad_terrain_options_are_refused_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                     argv: list[str], problem: str) -> None:  # fmt: skip
    source = "kick" if "--cycles" in argv else "walk"
    assert mimic_motions(["fit-terrain", source, *argv, "--out", str(tmp_path / "o.txt")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and problem in err, err
    assert list(tmp_path.iterdir()) == []


def test_the_fitted_clip_reads_back_with_its_terrain(tmp_path: Path, humanoid: Humanoid,
                                                     capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    argv = ["fit-terrain", "walk", "--cycles", "2", "--terrain", "stairs", "--param", "step_height=0.1",
            "--param", "step_depth=0.62", "--param", "steps=3", "--param", "before=1.5", "--terrain-at", "0.8", "0",
            "--seed", "3"]  # fmt: skip
    assert mimic_motions([*argv, "--out", str(tmp_path / "up.txt")]) == 0
    printed = capsys.readouterr().out
    assert "terrain fit: root offset +0.0 to +30.0 cm" in printed and "stance frames" in printed
    assert "lowest stance foot above the terrain" in printed and f"and {tmp_path / 'up.terrain.h5'}" in printed
    assert mimic_motions([*argv, "--out", str(tmp_path / "up.h5")]) == 0
    # What the command fitted, by the library functions.
    terrain = generate("stairs", 3, ["step_height=0.1", "step_depth=0.62", "steps=3", "before=1.5"])
    terrain = Terrain(terrain.heights, terrain.cell_size, terrain.origin + [0.8, 0.0])
    expected, fit = terrain_fit.fit_terrain(cleanup.unroll(resolve_clips(["walk"])[0], humanoid, 2), humanoid, terrain)
    assert fit.after[0] >= -cleanup.GROUND_TOLERANCE and fit.loop_opened is False and not expected.loop

    def same(t: Terrain | None) -> None:
        assert t is not None and t.cell_size == terrain.cell_size
        np.testing.assert_array_equal(t.heights, terrain.heights)
        np.testing.assert_array_equal(t.origin, terrain.origin)

    txt = read_deepmimic(tmp_path / "up.txt")  # the .txt and its sidecar
    same(txt.terrain)
    assert sidecar_path(tmp_path / "up.txt").exists()
    np.testing.assert_allclose(txt.root_pos, expected.root_pos, rtol=0, atol=1e-8)  # .txt: 9 significant digits
    write_clip_pack(tmp_path / "pack.h5", [tmp_path / "up.txt"])  # a pack of it
    same(read_clip_pack(tmp_path / "pack.h5")[0].terrain)
    library = load_motions([str(tmp_path / "up.h5")], humanoid)  # the motion dataset
    same(library.clips[0].terrain)
    frames = MotionLibrary.from_clips([expected], humanoid).frames
    np.testing.assert_array_equal(library.frames.qpos, frames.qpos)
    # Velocities of the new positions, as every reader derives them: central differences on the control grid.
    np.testing.assert_allclose(library.frames.qvel[:, :3], np.gradient(library.frames.qpos[:, :3], DT, axis=0),
                               rtol=0, atol=1e-9)  # fmt: skip
    assert np.abs(library.frames.qvel[:, 2]).max() > 0.3  # the climb's vertical speed is in them


def test_a_wrap_clip_stays_wrap_only_where_its_offset_closes(humanoid: Humanoid) -> None:
    walk = resolve_clips(["walk"])[0]
    up, fit = terrain_fit.fit_terrain(walk, humanoid, stairs("up", steps=4, step_height=0.1, step_depth=0.3,
                                                             before=1.0, seed=0))  # fmt: skip
    assert fit.loop_opened and not up.loop and "written one-shot" in fit.report()[-1]
    level, fit = terrain_fit.fit_terrain(walk, humanoid, Terrain(np.full((41, 81), 0.2), 0.05, np.array([-1.0, -1.0])))
    assert level.loop and not fit.loop_opened
    np.testing.assert_allclose(fit.offset, 0.2, rtol=0, atol=1e-12)


def test_mirror_reflects_the_terrain_with_the_clip(humanoid: Humanoid) -> None:
    walk = resolve_clips(["walk"])[0]
    terrain = generate("slope", 0, ["angle_deg=10", "width=3"])
    terrain = Terrain(terrain.heights + np.linspace(0.0, 0.02, terrain.shape[0])[:, None], terrain.cell_size,
                      terrain.origin + [0.0, 0.3])  # fmt: skip
    on = replace(walk, terrain=terrain)
    mirrored = cleanup.mirror(on)
    # The mirrored feet stand as high above the mirrored terrain as the feet above the terrain (a field linear in y
    # within each cell row: exact to rounding).
    a = cleanup.foot_contact(on, humanoid).height
    b = cleanup.foot_contact(mirrored, humanoid).height
    np.testing.assert_allclose(b[:, ::-1], a, rtol=0, atol=1e-9)
    twice = cleanup.mirror(mirrored).terrain
    np.testing.assert_array_equal(twice.heights, terrain.heights)
    np.testing.assert_allclose(twice.origin, terrain.origin, rtol=0, atol=1e-12)


def test_unroll_plays_a_wrap_clip_as_the_library_does(humanoid: Humanoid) -> None:
    walk = resolve_clips(["walk"])[0]
    unrolled = cleanup.unroll(walk, humanoid, 3)
    library = MotionLibrary.from_clips([walk], humanoid)
    frames = MotionLibrary.from_clips([unrolled], humanoid).frames
    assert not unrolled.loop and len(frames.qpos) == 3 * (library.num_frames[0] - 1) + 1
    played = library.query(np.zeros(len(frames.qpos), dtype=np.int64), np.arange(len(frames.qpos)) * DT)
    np.testing.assert_allclose(frames.qpos, played.qpos, rtol=0, atol=1e-12)
    np.testing.assert_allclose(frames.body_pos, played.body_pos, rtol=0, atol=1e-12)


def test_the_fit_measures_feet_as_the_judge_does(humanoid: Humanoid) -> None:
    from common.character.humanoid import BodyGeometry
    from common.sim.terrain import ClipTerrains, support_clearance

    frames = MotionLibrary.from_clips([resolve_clips(["walk"])[0]], humanoid).frames
    terrain = stairs("up", steps=4, step_height=0.12, step_depth=0.3, seed=0)
    geometry = BodyGeometry(humanoid)
    ours = geometry.clearance(frames.body_pos, frames.body_rot, terrain.height_at)
    judge = support_clearance(ClipTerrains([terrain]), np.zeros(len(frames.body_pos), dtype=np.int64), geometry,
                              frames.body_pos, frames.body_rot)  # fmt: skip
    np.testing.assert_allclose(ours, judge, rtol=0, atol=1e-12)
    flat = Terrain(np.zeros((41, 81)), 0.05, np.array([-1.0, -1.0]))
    np.testing.assert_array_equal(geometry.clearance(frames.body_pos, frames.body_rot, flat.height_at),
                                  geometry.lowest_points(frames.body_pos, frames.body_rot))  # fmt: skip


def test_the_stance_speed_sets_which_slow_feet_stand(standing: Clip, humanoid: Humanoid) -> None:
    """The glide's feet move with the root: 5 m/s at its middle, under 1 m/s for a few frames at each end. A foot
    slower than ``stance_speed`` (and at its usual height: the pose never changes) stands; the report says which."""
    speed = cleanup.foot_contact(standing, humanoid).speed
    terrain = _box_terrain()
    default = terrain_fit.fit_terrain(standing, humanoid, terrain)[1]
    fitted, fit = terrain_fit.fit_terrain(standing, humanoid, terrain, stance_speed=1.0)
    np.testing.assert_array_equal(default.stance, speed < cleanup.STANCE_SPEED)
    np.testing.assert_array_equal(fit.stance, speed < 1.0)
    # The glide's first and last frames stand too: the library's central difference there is x(dt) / (2 dt), the
    # smoothstep at u = 1/18 of its 0.3 s, 0.0089 m / (1/30 s) = 0.27 m/s; the next frame's is 1.03 m/s.
    assert fit.stance.sum() == default.stance.sum() + 2 * 2
    assert "foot slower than 1 m/s" in fit.report()[0] and "foot slower than 0.2 m/s" in default.report()[0]
    # Standing still at either end, the result is the same: the box's 10 cm under both feet at x = 1.
    rise = fitted.root_pos[:, 2] - standing.root_pos[:, 2]
    assert np.abs(rise[standing.times < 0.9]).max() < 1e-12
    np.testing.assert_allclose(rise[standing.times > 1.4], BOX, rtol=0, atol=1e-12)
