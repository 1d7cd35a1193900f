"""What a SuperTrack frame holds: the gym actor's fields, the buffer's fields, and buffer rows of older runs in
today's layout.

Buffer frame i of a character holds S_i (``sim``), K_{i+1} (``kin_next``: the reference the step aims for, which
is also the reference at the time of S_{i+1}), k_{i+1} (``kin_next_joint_rot``) and the applied targets T_i
(``target_rot``). So a window's kin_next[i] is the target of the policy's i-th step and the state its prediction
P_{i+1} is compared with, and target_rot[i] leads from sim[i] to sim[i + 1]. ``clip`` is the clip of the frame's
episode (a window never crosses an episode, so it has one clip, whose terrain its rollouts sample). ``collected_at``
is the number of updates done when the weights that collected the frame were sent (the buffer age is measured from
it). On terrain the actor adds ``sim_contacts`` and ``kin_contacts`` (:func:`supertrack.terrain.terrain_fields`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from common.sim.collect import EPISODE_FIELDS
from supertrack.config import TerrainConfig
from supertrack.state import STATE_WIDTH
from supertrack.terrain import terrain_fields

Layout = dict[str, tuple[tuple[int, ...], Any]]


def gym_fields(num_bodies: int, num_joints: int, terrain: TerrainConfig | None = None) -> Layout:
    """The per-frame fields the gym's actor writes (:class:`supertrack.actor.GymActor`)."""
    return {
        "sim": ((num_bodies, STATE_WIDTH), "float32"),
        "kin_next": ((num_bodies, STATE_WIDTH), "float32"),
        "kin_next_joint_rot": ((num_joints, 4), "float32"),
        "target_rot": ((num_joints, 4), "float32"),
        **({} if terrain is None else terrain_fields(terrain, num_bodies)),
    }


def buffer_fields(num_bodies: int, num_joints: int, terrain: TerrainConfig | None = None) -> Layout:
    """The buffer's per-frame fields (see the module docstring)."""
    return {**gym_fields(num_bodies, num_joints, terrain), **EPISODE_FIELDS, "collected_at": ((), "int64")}


def upgrade_rows(rows: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Buffer rows (a buffer's ``state_dict()["rows"]``) of an older run in today's layout: frames from before
    ``collected_at`` count as collected before the first update; frames from before the buffer kept each frame's
    ``clip`` (issue 59) get clip 0, which only the terrain inputs read, and a run with those never lacked it."""
    out = dict(rows)
    shape = np.shape(rows["episode_id"])
    out.setdefault("collected_at", np.zeros(shape, dtype=np.int64))
    out.setdefault("clip", np.zeros(shape, dtype=np.int64))
    return out
