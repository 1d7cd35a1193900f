"""Clips on terrain in the simulator: a MuJoCo model per terrain, the ground's height under every character, and the
terrain features of the observation (a heightmap around the root, the reference's contact labels).

**A model per terrain.** ``mujoco.rollout`` takes one model per character, so each character is stepped in the model
of its clip's terrain: the humanoid with a heightfield geom (:func:`terrain_model`), one model per distinct terrain,
shared by the characters on it. A rollout's models must have the same sizes (one ``MjData`` per thread serves them
all), so once any clip has a terrain every model carries the heightfield geom; a flat clip's is switched off
(``contype = conaffinity = 0``). A library without terrain builds no such model and steps as before. PARC's
alternative, one model holding every terrain as a tile with each character placed on its clip's tile, moves every
character off its clip's coordinates; ``benchmarks/terrain_models.py`` measured it no faster (docs/gym-and-judge.md).
"""

from __future__ import annotations

import mujoco
import numpy as np

from common.character.humanoid import BodyGeometry, Humanoid, apply_physics
from common.maths.rotations import quat_yaw
from common.motion.library import MotionLibrary
from common.motion.terrain import OFF_GRID_DROP, Terrain

FLOOR_GEOM = "floor"
TERRAIN_GEOM = "terrain"
MIN_ELEVATION = 1e-3  # m: MuJoCo's heightfield needs a positive elevation range, even for a flat one


def terrain_model(humanoid: Humanoid, terrain: Terrain | None) -> mujoco.MjModel:
    """The humanoid's model with ``terrain`` as a heightfield geom (:func:`add_terrain`), under ``humanoid.physics``.

    ``terrain`` None: the flat floor, with a heightfield geom that collides with nothing (so that the model has the
    sizes of the terrain models).
    """
    spec = mujoco.MjSpec.from_file(str(humanoid.xml_path))
    floor = spec.geom(FLOOR_GEOM)
    if floor is None:
        raise ValueError(f"{humanoid.xml_path}: no '{FLOOR_GEOM}' geom to put a terrain beside")
    add_terrain(spec, terrain, floor)
    model = spec.compile()
    apply_physics(model, humanoid.physics)
    return model


def add_terrain(spec: mujoco.MjSpec, terrain: Terrain | None, floor: mujoco.MjsGeom) -> None:
    """Adds ``terrain`` to a model's spec as a heightfield geom colliding like ``floor`` (its plane), in place.

    The heightfield's nodes are the terrain's (MuJoCo normalises heights to [0, 1] times the elevation range, stored
    in float32: 6e-8 of the range); its contacts are the floor's (``contype``, ``condim``, friction). Its solid
    reaches ``OFF_GRID_DROP`` below its lowest point, where the floor plane is moved: the ground outside the grid
    (:attr:`~common.motion.terrain.Terrain.floor`). ``terrain`` None: a heightfield geom that collides with nothing,
    the floor left as it is.
    """
    heights = np.zeros((2, 2)) if terrain is None else terrain.heights
    cell = 1.0 if terrain is None else terrain.cell_size
    origin = np.zeros(2) if terrain is None else terrain.origin
    lo = float(heights.min())
    elevation = max(float(heights.max()) - lo, MIN_ELEVATION)
    rows, cols = heights.shape
    half = 0.5 * np.array([(cols - 1) * cell, (rows - 1) * cell])
    spec.add_hfield(name=TERRAIN_GEOM, nrow=rows, ncol=cols, size=[half[0], half[1], elevation, OFF_GRID_DROP],
                    userdata=((heights - lo) / elevation).ravel().tolist())  # fmt: skip
    on = terrain is not None
    spec.worldbody.add_geom(
        name=TERRAIN_GEOM, type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname=TERRAIN_GEOM,
        pos=[origin[0] + half[0], origin[1] + half[1], lo], contype=floor.contype if on else 0,
        conaffinity=floor.conaffinity if on else 0, condim=floor.condim, friction=floor.friction,
        material=floor.material,
    )  # fmt: skip
    if on:
        floor.pos = [floor.pos[0], floor.pos[1], terrain.floor]


class ClipTerrains:
    """The terrain of every clip of a library: heights under any character, and one simulator model per terrain.

    Args:
        terrains: Per clip its terrain, None for the flat floor (height 0).
    """

    def __init__(self, terrains: list[Terrain | None]) -> None:
        self.unique: list[Terrain] = []
        keys: dict[tuple, int] = {}
        index = []
        for terrain in terrains:
            if terrain is None:
                index.append(-1)
                continue
            index.append(keys.setdefault(terrain.key(), len(keys)))
            if index[-1] == len(self.unique):
                self.unique.append(terrain)
        self.index = np.array(index, dtype=np.int64)  # (C,): the clip's terrain in ``unique``, -1 for flat

    @classmethod
    def of(cls, library: MotionLibrary) -> ClipTerrains:
        return cls([clip.terrain for clip in library.clips])

    @property
    def any(self) -> bool:
        """Some clip has a terrain."""
        return bool(self.unique)

    def height(self, clip: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The ground's height at (x, y) of each character's terrain (0 on the flat floor).

        Args:
            clip: Clip of each character. Shape: (N,).
            x, y: World coordinates. Shape: (N, ...).

        Returns:
            Shape: (N, ...).
        """
        out = np.zeros(np.broadcast_shapes(np.shape(x), np.shape(y)))
        which = self.index[np.asarray(clip, dtype=np.int64)]
        for t in np.unique(which[which >= 0]):
            rows = which == t
            out[rows] = self.unique[t].height_at(x[rows], y[rows])
        return out

    def models(self, humanoid: Humanoid) -> tuple[mujoco.MjModel, list[mujoco.MjModel]]:
        """The flat model and the model of every clip (shared by the clips of one terrain)."""
        flat = terrain_model(humanoid, None)
        built = [terrain_model(humanoid, t) for t in self.unique]
        return flat, [flat if t < 0 else built[t] for t in self.index]


def heightmap_offsets(extent: float, spacing: float) -> np.ndarray:
    """The heightmap's sample points in the heading frame: a square grid from -extent to extent along x (forward) and
    y (left), x varying fastest. Shape: (P, 2), P = (2 round(extent / spacing) + 1)^2."""
    k = int(round(extent / spacing))
    s = spacing * np.arange(-k, k + 1)
    gx, gy = np.meshgrid(s, s)
    return np.stack([gx.ravel(), gy.ravel()], axis=-1)


def heightmap(terrains: ClipTerrains, clip: np.ndarray, root_pos: np.ndarray, root_rot: np.ndarray,
              offsets: np.ndarray) -> np.ndarray:  # fmt: skip
    """How high the root is above the ground at points around it, the points turned with the root's heading.

    Args:
        terrains: The clips' terrains.
        clip: Clip of each character. Shape: (N,).
        root_pos: Root position, world. Shape: (N, 3).
        root_rot: Root rotation, world (w, x, y, z). Shape: (N, 4).
        offsets: Sample points in the heading frame (:func:`heightmap_offsets`). Shape: (P, 2).

    Returns:
        root height - ground height at each point (m). Shape: (N, P).
    """
    yaw = quat_yaw(root_rot)[:, None]
    c, s = np.cos(yaw), np.sin(yaw)
    x = root_pos[:, :1] + c * offsets[:, 0] - s * offsets[:, 1]
    y = root_pos[:, 1:2] + s * offsets[:, 0] + c * offsets[:, 1]
    return root_pos[:, 2:3] - terrains.height(clip, x, y)


def support_clearance(terrains: ClipTerrains, clip: np.ndarray, geometry: BodyGeometry, body_pos: np.ndarray,
                      body_rot: np.ndarray) -> np.ndarray:  # fmt: skip
    """How far every body's collision geom is above its clip's ground
    (:meth:`~common.character.humanoid.BodyGeometry.clearance` over :meth:`ClipTerrains.height`).

    Args:
        terrains: The clips' terrains.
        clip: Clip of each character. Shape: (N,).
        geometry: The bodies' collision geoms.
        body_pos: Body positions, world. Shape: (N, B, 3).
        body_rot: Body rotations, world. Shape: (N, B, 4).

    Returns:
        Clearance (m). Shape: (N, B).
    """
    return geometry.clearance(body_pos, body_rot, lambda x, y: terrains.height(clip, x, y))


def ground_clearance(terrains: ClipTerrains, clip: np.ndarray, geometry: BodyGeometry, body_pos: np.ndarray,
                     body_rot: np.ndarray) -> np.ndarray:  # fmt: skip
    """The judge's lowest point of every body: its clearance above its clip's ground, for the fall-contact rule and
    the evaluator's foot contacts.

    A character on a terrain: :func:`support_clearance` (the ground under each support point). A character on the flat
    floor: :meth:`~common.character.humanoid.BodyGeometry.lowest_points`, the height of the lowest point above z = 0,
    bit for bit what the judge measured before terrains existed (in a library that has a terrain too); a library
    without any terrain costs nothing more than that.

    Args:
        terrains: The clips' terrains.
        clip: Clip of each character. Shape: (N,).
        geometry: The bodies' collision geoms.
        body_pos: Body positions, world. Shape: (N, B, 3).
        body_rot: Body rotations, world. Shape: (N, B, 4).

    Returns:
        Clearance (m). Shape: (N, B).
    """
    out = geometry.lowest_points(body_pos, body_rot)
    if not terrains.any:
        return out
    rows = np.flatnonzero(terrains.index[np.asarray(clip, dtype=np.int64)] >= 0)
    if len(rows):
        out[rows] = support_clearance(terrains, np.asarray(clip)[rows], geometry, body_pos[rows], body_rot[rows])
    return out


def contact_labels(terrains: ClipTerrains, clip: np.ndarray, geometry: BodyGeometry, body_pos: np.ndarray,
                   body_rot: np.ndarray, contact_height: float) -> np.ndarray:  # fmt: skip
    """Which bodies touch the ground: 1 where a body's collision geom comes within ``contact_height`` of it, its
    :func:`support_clearance` at most ``contact_height``.

    Args:
        terrains: The clips' terrains.
        clip: Clip of each character. Shape: (N,).
        geometry: The bodies' collision geoms.
        body_pos: Body positions, world. Shape: (N, B, 3).
        body_rot: Body rotations, world. Shape: (N, B, 4).
        contact_height: The largest clearance that counts as contact (m).

    Returns:
        0.0 or 1.0 per body. Shape: (N, B).
    """
    clearance = support_clearance(terrains, clip, geometry, body_pos, body_rot)
    return (clearance <= contact_height).astype(np.float64)
