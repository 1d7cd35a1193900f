"""The terrain suite's bundled clips (``benchmarks/terrain_clips.py``): 9 clips that load as ``terrain`` and by name
with their terrains, are what the documented command makes, keep their stance feet on the ground, and stay on their
terrain with the heightmap's reach to spare; ``all`` is what it was."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.motion.dataset import bundled_clip_names, bundled_terrain_clip_names, load_motions, resolve_clips
from common.motion.errors import MotionFormatError
from common.motion.library import MotionLibrary
from common.motion.motion import Clip, read_deepmimic
from common.motion.motion_import import cleanup
from common.motion.motion_import.terrain_fit import STANCE_HEIGHT
from common.tools.motions import main as mimic_motions
from tests.benchmark_module import benchmark_module

SUITE = benchmark_module("terrain_clips")
SPECS = {spec.name: spec for spec in SUITE.CLIPS}
PARC_HEIGHTMAP = 1.0  # m: the suite's heightmap extent (benchmarks/compare_trackers.py SUITE_SETTINGS)


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


@pytest.fixture(scope="module")
def clips() -> dict[str, Clip]:
    return {clip.name: clip for clip in resolve_clips(["terrain"])}


@pytest.fixture(scope="module")
def flat(humanoid: Humanoid) -> dict[str, Clip]:
    """Each source played for the suite's cycles and fitted to flat ground (the fit's flat case, the ground fix)."""
    return {name: cleanup.fix_ground(cleanup.unroll(resolve_clips([name])[0], humanoid, SUITE.CYCLES), humanoid)[0]
            for name in ("walk", "jog", "run")}  # fmt: skip


def test_the_nine_clips_load_as_a_group_and_by_name(clips: dict[str, Clip]) -> None:
    names = [f"{m}_{k}" for m in ("jog", "run", "walk") for k in ("rough", "slope", "stairs")]
    assert sorted(SPECS) == bundled_terrain_clip_names() == sorted(clips) == names
    assert all(clip.terrain is not None and not clip.loop for clip in clips.values())
    assert [c.name for c in resolve_clips(["run_rough", "walk_stairs"])] == ["run_rough", "walk_stairs"]
    # 'all' is the 20 flat short clips, as before the terrain clips were bundled.
    short = resolve_clips(["all"])
    assert len(short) == 20 and [c.name for c in short] == bundled_clip_names()
    assert all(c.terrain is None for c in short)
    with pytest.raises(MotionFormatError, match="clip names must be unique"):
        resolve_clips(["terrain", "walk_stairs"])
    with pytest.raises(MotionFormatError, match="on terrain: jog_rough, .*, walk_stairs, 'terrain'"):
        resolve_clips(["walk_stair"])


@pytest.mark.parametrize("name", sorted(SPECS))
def test_each_clip_is_its_source_for_four_cycles_on_the_generated_terrain(name: str, clips: dict[str, Clip],
                                                                          humanoid: Humanoid) -> None:  # fmt: skip
    spec, clip = SPECS[name], clips[name]
    assert clip.terrain.key() == spec.terrain().key()  # bit for bit: heights stored in float64
    cycle = MotionLibrary.from_clips(resolve_clips([spec.source]), humanoid)  # the cycle on the control grid
    assert clip.duration == pytest.approx(SUITE.CYCLES * cycle.duration[0], abs=1e-6)  # float32 frame durations
    assert 3.0 <= clip.duration <= 5.1


def test_a_clip_is_what_its_command_makes(tmp_path: Path, clips: dict[str, Clip]) -> None:
    """jog_stairs (with ``--stance-speed 1``), made again by its ``mimic-motions fit-terrain`` command: the bundled
    rows are its rows in float32."""
    out = tmp_path / "jog_stairs.txt"
    assert mimic_motions(SPECS["jog_stairs"].argv(out)) == 0
    made, bundled = read_deepmimic(out), clips["jog_stairs"]
    assert made.terrain.key() == bundled.terrain.key() and made.loop == bundled.loop
    for field in ("times", "root_pos", "root_rot", "joint_rot"):
        np.testing.assert_allclose(getattr(bundled, field), getattr(made, field), rtol=2e-7, atol=2e-7)


@pytest.mark.parametrize("name", sorted(SPECS))
def test_stance_feet_rest_on_the_terrain_as_on_the_floor(name: str, clips: dict[str, Clip], flat: dict[str, Clip],
                                                         humanoid: Humanoid) -> None:  # fmt: skip
    """Where a foot stands in the source (the fit's own rule: slower than the clip's stance speed, within 5 cm of its
    usual height), it stands as high above the terrain as the source's above the floor: within 1 cm, the spread of a
    recorded planted foot (walk's: -0.5 to +1.1 cm), in at least 70 % of those frames and within 3 cm in every one.
    The rest is the fit's documented cost: at a handover its smoothing (a running maximum and a +-0.05 s window,
    never below the target) lifts the leaving or landing foot for a few frames (measured: up to 2.5 cm, walk_stairs;
    74-100 % within 1 cm, jog_slope the least). No stance foot is deeper in the terrain than the ground fix lets one
    be (1 cm), or than the source's own deepest, by more than 2 mm (measured: run_slope's last frame, 1.1 cm)."""
    spec = SPECS[name]
    speed = spec.stance_speed or cleanup.STANCE_SPEED
    source = cleanup.foot_contact(flat[spec.source], humanoid)
    fitted = cleanup.foot_contact(clips[name], humanoid)
    n = min(len(source.height), len(fitted.height))  # float32 frame durations may drop the last frame
    slow = source.speed[:n] < speed
    stance = slow & (source.height[:n] <= np.median(source.height[:n][slow]) + STANCE_HEIGHT)
    off = (fitted.height[:n] - source.height[:n])[stance]
    assert stance.sum() >= 70  # every contact is counted (jog and run: 8 and 0 frames at the default 0.2 m/s)
    assert np.mean(np.abs(off) <= 0.01) >= 0.7, np.mean(np.abs(off) <= 0.01)
    assert np.abs(off).max() <= 0.03, np.abs(off).max()
    deepest = min(source.height[:n][stance].min(), -cleanup.GROUND_TOLERANCE)
    assert fitted.height[:n][stance].min() >= deepest - 0.002, fitted.height[:n][stance].min()


@pytest.mark.parametrize("name", sorted(SPECS))
def test_the_heightmap_never_leaves_the_terrain_along_the_reference(name: str, clips: dict[str, Clip],
                                                                    humanoid: Humanoid) -> None:  # fmt: skip
    """The reference root stays MARGIN inside the grid, beyond the corners of a 1 m heightmap turned any way."""
    assert np.hypot(PARC_HEIGHTMAP, PARC_HEIGHTMAP) < SUITE.MARGIN
    clip = clips[name]
    root = load_motions([name], humanoid).frames.body_pos[:, humanoid.root_index, :2]
    lo, hi = clip.terrain.origin, clip.terrain.origin + clip.terrain.size
    assert (root - lo).min() >= SUITE.MARGIN - 1e-9 and (hi - root).min() >= SUITE.MARGIN - 1e-9
