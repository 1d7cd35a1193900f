"""The ``parc`` observation's terrain features: the heightmap by hand on a sloped plane (turned with the heading),
the reference's contact labels on a constructed clip, and the observation unchanged when they are off."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.config import ConfigError, from_dict
from common.maths.rotations import quat_from_axis_angle, quat_from_yaw, quat_mul
from common.motion.dataset import load_motions
from common.motion.library import MotionLibrary
from common.motion.terrain import check_terrain
from common.sim.gym import GymConfig, TrackingGym
from common.sim.observation import (
    ObservationConfig,
    Observer,
    is_raw_feature,
    parc_features,
    terrain_feature_widths,
)
from common.sim.terrain import ClipTerrains, heightmap, heightmap_offsets
from tests.common.test_terrain import _standing_clip


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


def test_heightmap_by_hand_on_a_sloped_plane_turns_with_the_heading() -> None:
    # The plane h = 0.2 x - 0.1 y on a 6 m square grid.
    nodes = -3.0 + 0.1 * np.arange(61)
    terrain = check_terrain(0.2 * nodes[None, :] - 0.1 * nodes[:, None], 0.1, np.array([-3.0, -3.0]), "slope")
    terrains = ClipTerrains([None, terrain])
    offsets = heightmap_offsets(0.2, 0.1)
    assert offsets.shape == (25, 2) and offsets[:3].tolist() == [[-0.2, -0.2], [-0.1, -0.2], [0.0, -0.2]]
    centre, ahead, left = 12, 13, 17  # (0, 0), (0.1, 0): one step forward, (0, 0.1): one step left
    root = np.array([[0.4, -0.3, 1.1]] * 3)
    # Heading 30 deg; the third character is also pitched by 20 deg, which the heading frame ignores.
    yaw30 = quat_from_yaw(np.radians(30.0))
    rot = np.stack([yaw30, yaw30, quat_mul(yaw30, quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), 0.35))])
    hm = heightmap(terrains, np.array([0, 1, 1]), root, rot, offsets)
    np.testing.assert_allclose(hm[0], 1.1)  # the flat floor: the root's height everywhere
    ground = 0.2 * 0.4 - 0.1 * -0.3  # 0.11 under the root
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    assert hm[1, centre] == pytest.approx(1.1 - ground)
    assert hm[1, ahead] == pytest.approx(1.1 - (ground + 0.1 * (0.2 * c - 0.1 * s)))  # forward = (cos, sin)
    assert hm[1, left] == pytest.approx(1.1 - (ground + 0.1 * (-0.2 * s - 0.1 * c)))  # left = (-sin, cos)
    np.testing.assert_allclose(hm[2], hm[1], atol=1e-12)
    # Turned a further 90 deg to the left, what was on the left is straight ahead.
    turned = heightmap(terrains, np.array([1]), root[:1], quat_from_yaw(np.radians(120.0))[None], offsets)
    assert turned[0, ahead] == pytest.approx(hm[1, left])


def _one_clip_observer(humanoid: Humanoid, clip, config: ObservationConfig) -> tuple[Observer, dict]:
    library = MotionLibrary.from_clips([clip], humanoid)
    observer = Observer(config, humanoid, library)
    ref = library.query(np.array([0]), np.array([0.0]))
    ref_next = library.query(np.array([0]), np.array([library.dt]))
    return observer, observer.features(ref, ref_next, np.zeros(1), np.array([0]), np.zeros(1))


def test_contact_labels_of_a_constructed_clip(humanoid: Humanoid) -> None:
    # A character standing straight at x = 0.5, its right foot (y < 0) on ground at 0, its left over a 10 cm dip.
    ys = -1.0 + 0.05 * np.arange(41)
    dip = check_terrain(np.where(ys[:, None] > 0.0, -0.1, 0.0) + np.zeros(41), 0.05, np.array([-0.5, -1.0]), "dip")
    config = ObservationConfig(contact_frames=(1, 3), contact_height=0.03)
    names = humanoid.body_names
    right, left, shin = names.index("right_foot"), names.index("left_foot"), names.index("right_shin")
    # Sunk by 8 cm: the left foot 2 cm above its dip, the right shin's lowest point (5.5 cm up) 2.5 cm in the ground.
    for lift, expected in ((0.0, {right}), (0.02, {right}), (0.04, set()), (-0.08, {left, right, shin})):
        clip = replace(_standing_clip(humanoid, lift=lift), terrain=dip)
        _, features = _one_clip_observer(humanoid, clip, config)
        for k in (1, 3):
            labels = features[f"ref{k}_contacts"]
            assert labels.shape == (1, 15) and set(np.flatnonzero(labels[0])) == expected, (lift, k)
    # On the flat floor (no terrain) both feet of the standing clip touch it.
    _, features = _one_clip_observer(humanoid, _standing_clip(humanoid), config)
    assert set(np.flatnonzero(features["ref1_contacts"][0])) == {left, right}


def test_features_off_leave_the_observation_as_it_was(humanoid: Humanoid) -> None:
    library = load_motions(["walk", "backflip"], humanoid)
    gym = TrackingGym(GymConfig(num_envs=3, threads=1), library, humanoid)
    result = gym.reset(clips=np.array([0, 1, 1]), times=np.array([0.1, 0.3, 0.7]))
    off = Observer(ObservationConfig(), humanoid, library)
    dt = library.dt
    refs = {k: library.query(result.clip, result.time + k * dt) for k in (1, 2, 4, 8, 16)}
    expected = np.concatenate(list(parc_features(result.sim, refs, humanoid.hinge_qpos, humanoid.hinge_dof).values()),
                              axis=-1)  # fmt: skip
    np.testing.assert_array_equal(off(result), expected)
    assert off.terrains is None and off.offsets is None
    on = Observer(ObservationConfig(heightmap_extent=1.0, contact_frames=(1, 4)), humanoid, library)
    layout_off, layout_on = off.layout(result), on.layout(result)
    assert list(layout_on)[: len(layout_off)] == list(layout_off)
    assert list(layout_on)[len(layout_off) :] == ["heightmap", "ref1_contacts", "ref4_contacts"]
    assert layout_on["heightmap"].stop - layout_on["heightmap"].start == 21 * 21
    obs_on = on(result)
    np.testing.assert_array_equal(obs_on[:, : expected.shape[1]], expected)
    # Flat clips observe a flat heightmap: the root's height above the floor at every point.
    hm = obs_on[:, layout_on["heightmap"]]
    np.testing.assert_allclose(hm, np.broadcast_to(result.sim.body_pos[:, :1, 2], hm.shape))
    assert [k for k in layout_on if is_raw_feature(k)] == ["heightmap", "ref1_contacts", "ref4_contacts"]
    widths = {k: v.stop - v.start for k, v in layout_on.items() if is_raw_feature(k)}
    assert terrain_feature_widths(on.config, humanoid.num_bodies) == widths
    assert terrain_feature_widths(off.config, humanoid.num_bodies) == {}


def test_terrain_feature_config(humanoid: Humanoid) -> None:
    cfg = from_dict(ObservationConfig, {"heightmap_extent": 0.5, "contact_frames": [1, 2]})
    assert cfg.heightmap_extent == 0.5 and cfg.contact_frames == (1, 2)
    for bad in ({"kind": "local", "heightmap_extent": 1.0}, {"contact_frames": [2, 1]},
                {"heightmap_extent": 0.05}, {"heightmap_spacing": 0.0}):  # fmt: skip
        with pytest.raises((ConfigError, ValueError)):
            from_dict(ObservationConfig, bad)
