"""Terrain in the simulator: the terrain's height equals MuJoCo's heightfield (rays, the contacts of a character
standing on a step, a box resting on one), the generator's shapes, and a gym stepping characters on their clips'
terrains."""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np
import pytest

from common.character.humanoid import BodyGeometry, Humanoid
from common.motion.dataset import resolve_clips
from common.motion.library import MotionLibrary
from common.motion.motion import Clip
from common.motion.terrain import OFF_GRID_DROP, Terrain, check_terrain
from common.motion.terrain_generator import boxes, rough, slope, stairs
from common.sim.gym import GymConfig, TrackingGym
from common.sim.terrain import TERRAIN_GEOM, ClipTerrains, add_terrain, terrain_model


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


def _random_terrain(seed: int = 0) -> Terrain:
    rng = np.random.default_rng(seed)
    return check_terrain(rng.uniform(-0.1, 0.3, (6, 9)), 0.2, np.array([-0.7, -0.4]), "random")


def _scene(terrain: Terrain) -> mujoco.MjSpec:
    """A floor plane with ``terrain`` added as the simulator adds it, nothing else."""
    spec = mujoco.MjSpec()
    floor = spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05])
    add_terrain(spec, terrain, floor)
    return spec


def test_height_at_is_mujocos_heightfield_under_rays() -> None:
    terrain = _random_terrain()
    model = _scene(terrain).compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    rng = np.random.default_rng(1)
    lo, hi = terrain.origin - 0.3, terrain.origin + terrain.size + 0.3  # also off the grid: the floor
    points = rng.uniform(lo, hi, (300, 2))
    geom = np.zeros(1, dtype=np.int32)
    hit = []
    for x, y in points:
        hit.append(5.0 - mujoco.mj_ray(model, data, np.array([x, y, 5.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1,
                                       geom))  # fmt: skip
    np.testing.assert_allclose(hit, terrain.height_at(points[:, 0], points[:, 1]), atol=1e-6)
    off = (points < terrain.origin).any(axis=1) | (points > terrain.origin + terrain.size).any(axis=1)
    assert off.sum() > 30 and np.allclose(terrain.height_at(points[off, 0], points[off, 1]), terrain.floor)
    assert terrain.floor == terrain.heights.min() - OFF_GRID_DROP
    # Where the two triangles of a cell differ, bilinear interpolation is not the surface MuJoCo collides with.
    h = terrain.heights
    x, y = terrain.origin + np.array([0.75, 0.25]) * terrain.cell_size  # below the cell's diagonal
    triangle = h[0, 0] + 0.75 * (h[0, 1] - h[0, 0]) + 0.25 * (h[1, 1] - h[0, 1])
    bilinear = 0.75 * 0.25 * h[1, 1] + 0.25 * 0.25 * h[1, 0] + 0.75 * 0.75 * h[0, 1] + 0.25 * 0.75 * h[0, 0]
    assert terrain.height_at(x, y) == pytest.approx(triangle, abs=1e-12)
    assert abs(bilinear - triangle) > 0.005


def test_contacts_of_a_character_standing_on_a_step_lie_on_the_terrain(humanoid: Humanoid) -> None:
    terrain = stairs("up", steps=4, step_height=0.12, step_depth=0.5, cell=0.02, seed=0)
    model = terrain_model(humanoid, terrain)
    data = mujoco.MjData(model)
    # The zero pose stands straight with flat feet: its feet 2 mm into the second step's tread (x 0.5 to 1.0).
    geometry = BodyGeometry(humanoid)
    data.qpos[:] = 0.0
    data.qpos[:7] = [0.75, 0.005, 1.0, 1.0, 0.0, 0.0, 0.0]  # no foot's side on a grid line (see below)
    mujoco.mj_kinematics(model, data)
    feet = humanoid.foot_indices
    lowest = geometry.lowest_points(data.xpos[1:][None], data.xquat[1:][None])[0, feet].min()
    step = terrain.height_at(0.75, 0.0)
    assert step == pytest.approx(0.24)
    data.qpos[2] += step - 0.002 - lowest
    mujoco.mj_forward(model, data)
    ground = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, TERRAIN_GEOM)
    contacts = [data.contact[i] for i in range(data.ncon) if ground in data.contact[i].geom]
    bodies = {int(model.geom_bodyid[c.geom[1 - list(c.geom).index(ground)]]) - 1 for c in contacts}
    assert bodies == set(feet.tolist())
    # MuJoCo collides a geom with each triangular prism of the field on its own: a foot 2 mm into a tread of 2 cm
    # cells meets ~90 prisms and keeps 50 contacts (its cap per geom pair). A prism whose side wall lies within the
    # penetration of the foot's side can give a sideways contact; the rest are on the tread.
    normals = np.array([c.frame[:3] if c.geom[0] == ground else -c.frame[:3] for c in contacts])  # terrain to foot
    top = normals[:, 2] > 0.999
    assert top.mean() > 0.95
    for c, normal in zip(np.array(contacts)[top], normals[top], strict=True):
        surface = c.pos - normal * c.dist / 2  # the contact point lies halfway between the two surfaces
        assert surface[2] == pytest.approx(terrain.height_at(surface[0], surface[1]), abs=1e-6)
        assert c.dist == pytest.approx(-0.002, abs=1e-6)


def test_a_box_comes_to_rest_on_a_step_at_the_terrains_height() -> None:
    terrain = stairs("up", steps=3, step_height=0.1, step_depth=0.4, seed=0)
    spec = _scene(terrain)
    body = spec.worldbody.add_body(name="box", pos=[0.6, 0.1, 0.4])
    body.add_freejoint()
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05, 0.05, 0.05], mass=1.0)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data, nstep=1000)  # 2 s at MuJoCo's default 2 ms
    assert np.abs(data.qvel).max() < 1e-2  # at rest: mm/s and mrad/s of solver creep
    bottom = data.qpos[2] - 0.05
    assert terrain.height_at(data.qpos[0], data.qpos[1]) == pytest.approx(0.2)
    assert bottom == pytest.approx(0.2, abs=1e-3)  # MuJoCo's soft contact lets it sink by a fraction of a mm


def test_generator_shapes_and_seeds() -> None:
    up = stairs("up", steps=5, step_depth=0.3, seed=3)
    rise = up.height_at(np.array([0.15, 0.45]), 0.0)
    assert 0.05 <= rise[0] <= 0.15 and rise[1] == pytest.approx(2 * rise[0])
    assert up.height_at(-0.5, 0.3) == 0.0 and up.height_at(2.0, -0.5) == pytest.approx(5 * rise[0])
    assert np.array_equal(up.heights, stairs("up", steps=5, step_depth=0.3, seed=3).heights)
    assert not np.array_equal(up.heights, stairs("up", steps=5, step_depth=0.3, seed=4).heights)
    down = stairs("down", steps=2, step_height=0.1, seed=0)
    assert down.height_at(0.45, 0.0) == pytest.approx(-0.2)
    ramp = slope(angle_deg=-8.0, length=3.0)
    assert ramp.height_at(2.0, 0.3) - ramp.height_at(1.0, 0.3) == pytest.approx(np.tan(np.radians(-8.0)))
    drawn = [slope(seed=s) for s in range(6)]
    grades = [np.degrees(np.arctan(t.height_at(1.0, 0.0))) for t in drawn]
    assert all(5.0 <= abs(g) <= 12.0 for g in grades) and min(grades) < 0 < max(grades)
    bumps = rough(seed=1)
    assert np.abs(bumps.heights).max() <= 0.03 and np.abs(bumps.heights).max() > 0.02
    assert np.all(bumps.height_at(np.array([-0.5, 4.5]), 0.0) == 0.0)
    tops = boxes(count=3, seed=2).heights
    assert set(np.unique(tops)) - {0.0} and tops.max() <= 0.25 and np.unique(tops).size <= 4
    with pytest.raises(ValueError, match="step_height"):
        stairs(step_height=0.3)
    with pytest.raises(ValueError, match="angle_deg"):
        slope(angle_deg=20.0)


def _standing_clip(humanoid: Humanoid, name: str = "stand", lift: float = 0.0) -> Clip:
    """Two seconds of the zero pose (straight, feet flat), the feet ``lift`` metres above z = 0, at x = 0.5."""
    times = np.array([0.0, 2.0])
    rot = np.tile([1.0, 0.0, 0.0, 0.0], (2, 1))
    clip = Clip(name, name, False, times, np.array([[0.5, 0.0, 1.0]] * 2), rot, np.tile(rot[:, None], (1, 12, 1)))
    ref = MotionLibrary.from_clips([clip], humanoid).query(np.array([0]), np.array([0.0]))
    lowest = BodyGeometry(humanoid).lowest_points(ref.body_pos, ref.body_rot).min()
    return replace(clip, root_pos=clip.root_pos + [0.0, 0.0, lift - lowest])


def test_gym_stands_characters_on_their_clips_terrains(humanoid: Humanoid) -> None:
    plateau = check_terrain(np.full((21, 21), 0.3), 0.1, np.array([-0.5, -1.0]), "plateau")
    flat = _standing_clip(humanoid)
    raised = replace(_standing_clip(humanoid, "raised", lift=0.3), terrain=plateau)
    library = MotionLibrary.from_clips([flat, raised], humanoid)
    assert ClipTerrains.of(library).index.tolist() == [-1, 0]
    gym = TrackingGym(GymConfig(num_envs=4, threads=1), library, humanoid)
    gym.reset(clips=np.array([0, 1, 0, 1]), times=np.zeros(4))
    for _ in range(30):
        result = gym.step(gym.reference_targets(), autoreset=False)
    # On its terrain the raised character stands 0.3 m up as its reference does; in the flat model it would fall.
    root = result.sim.body_pos[:, 0, 2]
    np.testing.assert_allclose(root, result.ref.body_pos[:, 0, 2], atol=0.02)
    assert root[1] - root[0] == pytest.approx(0.3, abs=0.01)
    state = gym.state_dict()
    again = TrackingGym(GymConfig(num_envs=4, threads=1), library, humanoid)
    again.load_state_dict(state)
    for _ in range(5):
        a = gym.step(gym.reference_targets(), autoreset=False)
        b = again.step(again.reference_targets(), autoreset=False)
    np.testing.assert_array_equal(a.sim.qpos, b.sim.qpos)
    assert again.sim.models[1] is again.sim.models[3] and again.sim.models[0] is not again.sim.models[1]


def test_a_library_without_terrain_steps_in_the_characters_own_model(humanoid: Humanoid) -> None:
    library = MotionLibrary.from_clips(resolve_clips(["walk"]), humanoid)
    gym = TrackingGym(GymConfig(num_envs=2, threads=1), library, humanoid)
    assert not gym.terrains.any and all(m is humanoid.model for m in gym.sim.models)


def test_rsi_lift_measures_from_the_terrain(humanoid: Humanoid) -> None:
    plateau = check_terrain(np.full((21, 21), 0.3), 0.1, np.array([-0.5, -1.0]), "plateau")
    sunk = replace(_standing_clip(humanoid, "sunk", lift=0.25), terrain=plateau)  # feet 5 cm into the plateau
    library = MotionLibrary.from_clips([sunk], humanoid)
    gym = TrackingGym(GymConfig(num_envs=1, threads=1, rsi_lift=True), library, humanoid)
    result = gym.reset(clips=np.array([0]), times=np.zeros(1))
    lowest = BodyGeometry(humanoid).lowest_points(result.sim.body_pos, result.sim.body_rot).min()
    assert lowest == pytest.approx(0.3, abs=1e-9)
