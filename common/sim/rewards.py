"""The tracking reward (named terms from :mod:`common.sim.tracking_rewards`, weighted) and the termination rules.

Reward: each term is r_k = exp(-s_k * e_k) with e_k the term's error; the terms are combined as a weighted sum
sum_k w_k r_k (``form: sum``, DeepMimic) or a weighted product prod_k r_k^w_k = exp(-sum_k w_k s_k e_k)
(``form: product``; with weights summing to 1 a weighted geometric mean, so still in [0, 1] and 1 only at
sim = ref). Two presets (:data:`REWARD_PRESETS`): ``deepmimic`` (Peng et al. 2018: pose, velocity, end effectors,
root, centre of mass, summed) and ``parc`` (PARC's motion tracker documentation: world-space root position and
rotation, body positions and rotations, joint velocities and end effectors, as a product).

Termination: SuperTrack's head-height rule, PARC's distance rules and DeepMimic's fall contact; the rules
``root_height_error`` and ``contact_clearance`` are measured against the reference, so that a clip whose reference
lies on the ground (crawl, roll, getting up) does not end an episode that tracks it.

On a clip's terrain every height in a rule is a height above the ground under the point measured (its clip's terrain,
:meth:`common.sim.terrain.ClipTerrains.height`, the surface MuJoCo collides with), for the simulated character and the
reference alike; on the flat floor that is the height itself, with the same arithmetic as before terrains existed
(:func:`termination`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from common.character.humanoid import Humanoid
from common.character.state import CharacterState
from common.maths.rotations import quat_geodesic_angle
from common.sim.tracking_rewards import REWARD_TERMS, Derived, RewardModel, prepare, term_errors


@dataclass(frozen=True)
class RewardPreset:
    form: Literal["sum", "product"]
    weights: dict[str, float]


REWARD_PRESETS: dict[str, RewardPreset] = {
    # DeepMimic's code: weights 0.5 / 0.05 / 0.15 / 0.2 / 0.1, summed.
    "deepmimic": RewardPreset("sum", {"pose": 0.5, "velocity": 0.05, "end_effector": 0.15, "root": 0.2, "com": 0.1}),
    # PARC's documentation: weights 0.3 / 0.2 / 0.3 / 0.1 / 0.05 / 0.05 (sum 1), as a product.
    "parc": RewardPreset("product", {"root_pos": 0.3, "root_rot": 0.2, "body_pos": 0.3, "body_rot": 0.1,
                                     "dof_vel": 0.05, "end_effector": 0.05}),
}  # fmt: skip
# k of exp(-k e) per term when the config gives none. DeepMimic's five and PARC's root_pos 10, root_rot 5, body_pos 20,
# dof_vel 0.1 are the sources'. PARC's documentation gives none for body_rot and end_effector: body_rot takes 2,
# DeepMimic's pose scale, the same kind of error (a mean of squared angles; 0.3 rad on every body -> 0.84);
# end_effector is DeepMimic's term and keeps its 40 (a 10 cm error of hands and feet -> 0.67).
DEFAULT_SCALES: dict[str, float] = {
    "pose": 2.0, "velocity": 0.1, "end_effector": 40.0, "root": 5.0, "com": 10.0,
    "root_pos": 10.0, "root_rot": 5.0, "body_pos": 20.0, "body_rot": 2.0, "dof_vel": 0.1,
}  # fmt: skip


@dataclass(frozen=True)
class RewardConfig:
    """The tracking reward. Fields left out (None) take the preset's values; after construction all are set.

    Attributes:
        preset: ``deepmimic`` or ``parc`` (:data:`REWARD_PRESETS`).
        form: ``sum`` (sum_k w_k r_k) or ``product`` (prod_k r_k^w_k).
        weights: The terms used and their weights ({term: w}, names from
            :data:`common.sim.tracking_rewards.REWARD_TERMS`); replaces the preset's set of terms when given.
        scales: k in exp(-k * error) per term; terms left out take :data:`DEFAULT_SCALES`.
    """

    preset: Literal["deepmimic", "parc"] = "deepmimic"
    form: Literal["sum", "product"] | None = None
    weights: dict[str, float] | None = None
    scales: dict[str, float] | None = None

    def __post_init__(self) -> None:
        p = REWARD_PRESETS[self.preset]
        weights = dict(p.weights if self.weights is None else self.weights)
        given = dict(self.scales or {})
        for name, table in (("weights", weights), ("scales", given)):
            unknown = sorted(set(table) - set(REWARD_TERMS))
            if unknown:
                raise ValueError(f"{name}: unknown reward terms {unknown} (known: {list(REWARD_TERMS)})")
            if any(v < 0 for v in table.values()):
                raise ValueError(f"{name} must be non-negative, got {table}")
        if not weights:
            raise ValueError("weights: at least one reward term is needed")
        extra = sorted(set(given) - set(weights))
        if extra:
            raise ValueError(f"scales: terms {extra} have no weight (weighted terms: {list(weights)})")
        object.__setattr__(self, "form", self.form or p.form)
        object.__setattr__(self, "weights", weights)
        object.__setattr__(self, "scales", {k: given.get(k, DEFAULT_SCALES[k]) for k in weights})


@dataclass(frozen=True)
class TerminationConfig:
    """When an episode ends. A ``None`` threshold disables its rule.

    Attributes:
        max_episode_frames: Truncate after this many control steps (SuperTrack: 512).
        grace_frames: Failure rules are checked only once an episode has lasted this many steps (SuperTrack: 48).
        head_height_error: Terminate when the head's height above the ground under it differs by more than this (m)
            from the reference head's above the ground under that.
        root_pos_error: Terminate when the root is farther than this from the reference root (m).
        root_rot_error: Terminate when the root rotation differs by more than this (rad).
        body_pos_error: Terminate when any body is farther than this from its reference (m).
        min_root_height: Terminate when the root is lower than this above the ground under it (m; not relative to
            the reference: the reference of crawl, roll and the get-ups breaks 0.3 m in 25-55 % of their frames).
        root_height_error: Terminate when the root's height above the ground under it is more than this (m) below
            the reference root's above the ground under that.
        fall_contact: Terminate on ground contact of ``deepmimic`` (pelvis, torso, head) or ``non_foot`` bodies.
        contact_height: A body whose lowest point is less than this (m) above the ground touches it.
        contact_clearance: When set, a fall contact counts only for bodies whose reference lowest point is more than
            this (m) above the ground at that frame: bodies the reference itself puts on (or near) the ground may
            touch it.
        clip_end: Truncate when a one-shot clip has no frame left.
    """

    max_episode_frames: int | None = 512
    grace_frames: int = 48
    head_height_error: float | None = 0.25
    root_pos_error: float | None = None
    root_rot_error: float | None = None
    body_pos_error: float | None = None
    min_root_height: float | None = None
    root_height_error: float | None = None
    fall_contact: Literal["off", "deepmimic", "non_foot"] = "off"
    contact_height: float = 0.005
    contact_clearance: float | None = None
    clip_end: bool = True


class TrackingReward:
    """Computes the weighted reward and its named terms for N characters (holds only model constants)."""

    def __init__(self, humanoid: Humanoid, config: RewardConfig) -> None:
        self.config = config
        self.model = RewardModel.from_humanoid(humanoid)

    def prepare(self, ref: CharacterState) -> Derived:
        """What the weighted terms derive from the reference state, computed ahead; the gym does it while the
        physics runs, since the reference of a step is known before it."""
        return prepare(self.config.weights, ref, self.model)

    def errors(self, sim: CharacterState, ref: CharacterState | Derived) -> dict[str, np.ndarray]:
        """Error of every weighted term, {term: (N,)}; ``ref`` may come from :meth:`prepare`."""
        ref = ref if isinstance(ref, Derived) else Derived(ref, self.model)
        return term_errors(self.config.weights, Derived(sim, self.model), ref)

    def __call__(self, sim: CharacterState, ref: CharacterState | Derived) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Reward and its named terms exp(-scale * error).

        Args:
            sim: Simulated state. Leading shape (N,).
            ref: Reference state at the same time, or its :meth:`prepare` (the same numbers, part of the work done).

        Returns:
            reward (N,), and {term: (N,)} of the unweighted exponentials of the weighted terms.
        """
        weights, scales = self.config.weights, self.config.scales
        err = self.errors(sim, ref)
        terms = {k: np.exp(-scales[k] * e) for k, e in err.items()}
        if self.config.form == "sum":
            reward = sum(weights[k] * terms[k] for k in terms)
        else:
            reward = np.exp(-sum(weights[k] * scales[k] * err[k] for k in err))
        return reward, terms


def termination(
    config: TerminationConfig,
    humanoid: Humanoid,
    sim: CharacterState,
    ref: CharacterState,
    episode_frames: np.ndarray,
    lowest_points: np.ndarray | None,
    ref_lowest_points: np.ndarray | None = None,
    ground: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Failure rules after a step. Returns terminated (N,) and which rule fired, {rule: (N,) bool}.

    What "height" means on a terrain, rule by rule (``ground`` given):

    - ``head_height``: the head's height above the ground under the head, against the reference head's above the
      ground under the reference head: a character one step behind its reference on stairs, standing upright, is not
      off by the step's rise; one that fell is off by what its fall cost.
    - ``root_height`` (``min_root_height``): the root's height above the ground under the root.
    - ``root_below_ref`` (``root_height_error``): the root's height above the ground under it, against the reference
      root's above the ground under that.
    - ``fall_contact``: each body's clearance above the ground under each point of its collision geom
      (``lowest_points`` and ``ref_lowest_points`` from :func:`common.sim.terrain.ground_clearance`).
    - ``root_pos``, ``root_rot``, ``body_pos``: distances to the reference, which the ground does not enter.

    Without ``ground`` (the flat floor, 0 everywhere) every rule compares the absolute heights, the arithmetic of the
    flat judge; a character on the flat floor in a library with terrains gets the same numbers (its ground is 0.0).

    Args:
        config: The rules.
        humanoid: The model.
        sim: Simulated state after the step.
        ref: Reference state at the same time.
        episode_frames: Steps taken in the episode including this one. Shape: (N,).
        lowest_points: Lowest point of every body of the simulated character; needed when ``config.fall_contact`` is
            on (None otherwise: the gym skips the 0.6 ms it costs at N = 256). Shape: (N, B).
        ref_lowest_points: The same for the reference; needed when ``config.contact_clearance`` is set. (N, B).
        ground: The ground's height under world points of each character, ``ground(x, y)`` with x, y of shape
            (N, K), returning (N, K): its clip's terrain (the gym passes :meth:`common.sim.terrain.ClipTerrains.height`
            of the characters' clips). None: the flat floor.
    """
    rules: dict[str, np.ndarray] = {}
    r = humanoid.root_index
    height = _heights_above_ground(config, humanoid, sim, ref, ground)
    if config.head_height_error is not None:
        rules["head_height"] = np.abs(height["sim_head"] - height["ref_head"]) > config.head_height_error
    if config.root_pos_error is not None:
        rules["root_pos"] = np.linalg.norm(sim.body_pos[:, r] - ref.body_pos[:, r], axis=-1) > config.root_pos_error
    if config.root_rot_error is not None:
        rules["root_rot"] = quat_geodesic_angle(sim.body_rot[:, r], ref.body_rot[:, r]) > config.root_rot_error
    if config.body_pos_error is not None:
        dist = np.linalg.norm(sim.body_pos - ref.body_pos, axis=-1)
        rules["body_pos"] = dist.max(axis=-1) > config.body_pos_error
    if config.min_root_height is not None:
        rules["root_height"] = height["sim_root"] < config.min_root_height
    if config.root_height_error is not None:
        rules["root_below_ref"] = height["sim_root"] < height["ref_root"] - config.root_height_error
    if config.fall_contact != "off":
        if config.fall_contact == "deepmimic":
            bodies = humanoid.fall_contact_indices
        else:
            bodies = np.setdiff1d(np.arange(humanoid.num_bodies), humanoid.foot_indices)
        if lowest_points is None:
            raise ValueError("termination: fall_contact needs the lowest points of the simulated bodies")
        touch = lowest_points[:, bodies] < config.contact_height
        if config.contact_clearance is not None:
            if ref_lowest_points is None:
                raise ValueError("termination: contact_clearance needs the reference's lowest points")
            touch &= ref_lowest_points[:, bodies] > config.contact_clearance
        rules["fall_contact"] = np.any(touch, axis=-1)
    armed = episode_frames >= config.grace_frames
    terminated = np.zeros(len(episode_frames), dtype=bool)
    for k in rules:
        rules[k] &= armed
        terminated |= rules[k]
    return terminated, rules


def _heights_above_ground(
    config: TerminationConfig,
    humanoid: Humanoid,
    sim: CharacterState,
    ref: CharacterState,
    ground: Callable[[np.ndarray, np.ndarray], np.ndarray] | None,
) -> dict[str, np.ndarray]:
    """The heights the enabled rules compare, {``sim_head``, ``ref_head``, ``sim_root``, ``ref_root``: (N,)}, each
    above the ground under its point: one ``ground`` look-up for all of them; without ``ground`` the z coordinates
    themselves (no arithmetic)."""
    r, h = humanoid.root_index, humanoid.head_index
    points: dict[str, np.ndarray] = {}
    if config.head_height_error is not None:
        points.update(sim_head=sim.body_pos[:, h], ref_head=ref.body_pos[:, h])
    if config.min_root_height is not None or config.root_height_error is not None:
        points["sim_root"] = sim.body_pos[:, r]
    if config.root_height_error is not None:
        points["ref_root"] = ref.body_pos[:, r]
    if ground is None or not points:
        return {name: p[:, 2] for name, p in points.items()}
    xyz = np.stack(list(points.values()), axis=1)  # (N, K, 3)
    under = ground(xyz[..., 0], xyz[..., 1])
    return {name: xyz[:, k, 2] - under[:, k] for k, name in enumerate(points)}
