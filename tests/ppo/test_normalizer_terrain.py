"""PPO and the terrain features of the observation (heightmap, contact labels): never normalised, as in PARC, and in
the exported policy's layout."""

from __future__ import annotations

import numpy as np

from common.character.humanoid import Humanoid
from common.sim.observation import ObservationConfig
from ppo.export import observation_layout
from ppo.normalizer import normalized_mask


def test_terrain_features_are_left_out_of_the_normaliser() -> None:
    layout = {"sim_pos": slice(0, 2), "heightmap": slice(2, 5), "ref1_contacts": slice(5, 7), "phase": slice(7, 8)}
    np.testing.assert_array_equal(normalized_mask(layout, ["phase"]), [True] * 2 + [False] * 6)
    np.testing.assert_array_equal(normalized_mask(layout, ["heightmap"]), [True] * 2 + [False] * 5 + [True])


def test_exported_layout_lists_the_terrain_features() -> None:
    humanoid = Humanoid()
    plain = observation_layout(ObservationConfig(), humanoid)
    terrain = observation_layout(ObservationConfig(heightmap_extent=0.5, contact_frames=(1, 2)), humanoid)
    assert terrain == plain | {"heightmap": 121, "ref1_contacts": 15, "ref2_contacts": 15}
