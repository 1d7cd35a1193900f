"""Retargeting a BVH take onto the humanoid: per-bone rest alignment, hinge projection and root scaling.

Method (all rotations active, quaternions (w, x, y, z)):

1. **World frame.** W takes the source's axes to the project's: its rows are the source's forward, left and up
   directions, up from the map's axis and left from the source's right hip to its left hip at rest
   (forward = left x up). A Y-up CMU take facing +Z with its left at +X gets (x, y, z) -> (z, x, y); DeepMimic's
   Y-up frame (left at -Z) gets DeepMimic's own (x, y, z) -> (x, -z, y). Source rotations become w G w^-1.
2. **Rest alignment per bone.** In the source's rest pose (every channel zero) each mapped body b gets the world
   rotation A_b that turns the character's zero-pose bone directions onto the source's rest bone directions: the
   bone to its one mapped child, or to its tip (head, feet); for the pelvis and torso the bone up the spine exactly
   and the right-to-left line (hips, shoulders) as close as possible (TRIAD). A T-pose and an A-pose source therefore
   give the same character pose for the same bone directions.
3. **Per frame** the body's world rotation is R_b(t) = G'_s(t) A_b, with G'_s the world rotation of its source
   joint: every unmapped source joint above it (extra spine links, collars) is already composed into G'_s. A tip
   marked ``with_parent`` (the CMU feet) instead takes its rotation from its tip and its parent bone, frame by frame.
4. **Hinges.** Bone directions leave a limb's twist about its bone free, so thigh and shin (upper arm and forearm)
   are first turned together about the bone until the flexion axis seen in the data (the principal axis of the
   hinge's rotation vectors) lies on the character's hinge. The local rotation L = R_parent^-1 R_child is then
   replaced by its twist about the hinge (+y): theta = 2 atan2(L_y, L_w); the residual angle |L Ry(theta)^-1| is
   reported. The foot keeps its world rotation (the ankle absorbs the change).
5. **Root.** The pelvis follows the source's hip midpoint scaled by the ratio of leg lengths (thigh + shin), so
   that a taller subject's stride fits the character's legs (``root="source"``: scaled by the units instead).

Units: ``scale`` (source unit in metres) is given or inferred from the rest skeleton's height (lowest to highest
joint or End Site, about 1.3-1.8 m for an adult) among metres, centimetres, millimetres, inches and CMU's unit
(1/0.45 inch = 0.056444 m, the factor used by IsaacGymEnvs' CMU retargeting).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from common.character.humanoid import Humanoid
from common.maths.rotations import (
    matrix_to_quat,
    quat_conj,
    quat_fix_hemisphere,
    quat_from_axis_angle,
    quat_geodesic_angle,
    quat_mul,
    quat_normalize,
    quat_rotate,
    quat_to_rotvec,
)
from common.motion.motion import Clip, MotionFormatError
from common.motion.motion_import.bvh import END_SUFFIX, Bvh, forward_kinematics, rest_positions
from common.motion.motion_import.joint_map import JointMap

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254, "cmu": 0.056444}
TYPICAL_HEIGHT = 1.6  # m: rest skeleton height (joints and End Sites) that unit inference aims at
ROOT_MODES = ("legs", "source")
_HINGE = np.array([0.0, 1.0, 0.0])


@dataclass(frozen=True)
class RetargetOptions:
    """How to retarget.

    Attributes:
        scale: Metres per source unit; None infers it from the skeleton's height (see :data:`UNITS`).
        up: Source up axis (``"y"`` or ``"z"``); None takes the joint map's.
        root: ``"legs"`` scales the root's path by leg length, ``"source"`` by ``scale`` only.
    """

    scale: float | None = None
    up: str | None = None
    root: str = "legs"

    def __post_init__(self) -> None:
        if self.scale is not None and not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale must be a positive number of metres per source unit, got {self.scale}")
        if self.up not in (None, "y", "z"):
            raise ValueError(f"up must be 'y' or 'z', got {self.up!r}")
        if self.root not in ROOT_MODES:
            raise ValueError(f"root must be one of {ROOT_MODES}, got {self.root!r}")


@dataclass
class Retargeted:
    """A retargeted take and what was done to it.

    Attributes:
        clip: The clip on the character (Z up, metres), at the source's frame times.
        sources: Character body -> the source joint (or End Site) that drives it; tips as ``"<body> tip"``.
        scale: Metres per source unit used; ``scale_note`` says whether it was given or inferred.
        leg_ratio: Character leg length / source leg length (both in metres).
        world: W, source axes -> project axes. Shape: (3, 3).
        hinge_residual_deg: Per knee/elbow, (mean, max) over frames of the rotation the hinge could not take, degrees.
        hinge_twist_deg: Per knee/elbow, how far its limb was turned about the bone to put the flexion on the hinge.
    """

    clip: Clip
    sources: dict[str, str]
    scale: float
    scale_note: str
    leg_ratio: float
    world: np.ndarray
    hinge_residual_deg: dict[str, tuple[float, float]] = field(default_factory=dict)
    hinge_twist_deg: dict[str, float] = field(default_factory=dict)

    def report(self) -> str:
        lines = [
            f"scale {self.scale:g} m per source unit ({self.scale_note}); leg ratio {self.leg_ratio:.3f}",
            "bodies <- source: " + ", ".join(f"{b} <- {s}" for b, s in self.sources.items()),
        ]
        lines += [f"hinge {j}: limb turned {self.hinge_twist_deg.get(j, 0.0):.1f} deg about its bone onto the hinge;"
                  f" off-axis residual mean {m:.1f} deg, max {x:.1f} deg"
                  for j, (m, x) in self.hinge_residual_deg.items()]  # fmt: skip
        return "\n".join(lines)


def zero_pose(humanoid: Humanoid) -> np.ndarray:
    """World positions of the character's body origins at qpos = 0 (root at the origin, unrotated). Shape: (B, 3)."""
    data = mujoco.MjData(humanoid.model)
    data.qpos[:] = 0.0
    data.qpos[3] = 1.0
    mujoco.mj_kinematics(humanoid.model, data)
    if not np.allclose(data.xquat[1:], [1.0, 0.0, 0.0, 0.0]):
        raise ValueError(f"{humanoid.xml_path}: bodies are rotated at the zero pose; retargeting assumes they are not")
    return np.array(data.xpos[1:])


def _resolve(bvh: Bvh, candidates: tuple[str, ...], rest: dict[str, np.ndarray], what: str, source: str) -> str:
    for name in candidates:
        if name in rest:
            return name
    raise MotionFormatError(f"{bvh.source}: joint map {source}: none of {list(candidates)} ({what}) is in the file")


def infer_scale(rest: dict[str, np.ndarray], up: int) -> tuple[float, str]:
    """The unit of :data:`UNITS` that makes the rest skeleton's height nearest :data:`TYPICAL_HEIGHT` (log scale)."""
    heights = np.array([p[up] for p in rest.values()])
    height = float(heights.max() - heights.min())
    if height <= 0:
        raise MotionFormatError("the rest skeleton has no height along the up axis: pass --scale and --up")
    unit = min(UNITS, key=lambda u: abs(math.log(height * UNITS[u] / TYPICAL_HEIGHT)))
    return UNITS[unit], f"inferred: {unit}, rest skeleton {height:.3g} units = {height * UNITS[unit]:.2f} m high"


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v)
    if n < 1e-9:
        raise MotionFormatError("a mapped bone has zero length at rest (two mapped joints at one point)")
    return v / n


def align(char: list[np.ndarray], src: list[np.ndarray]) -> np.ndarray:
    """The rotation taking the character's directions onto the source's: the first exactly, the second as close as
    possible (TRIAD); one direction: the shortest rotation. Returns a quaternion (4,)."""
    e1, d1 = _unit(char[0]), _unit(src[0])
    if len(char) == 1:
        axis = np.cross(e1, d1)
        s, c = np.linalg.norm(axis), float(np.dot(e1, d1))
        if s < 1e-9:
            if c > 0:
                return np.array([1.0, 0.0, 0.0, 0.0])
            # Opposite directions: half a turn about any axis perpendicular to e1.
            perp = np.cross(e1, [1.0, 0.0, 0.0] if abs(e1[0]) < 0.9 else [0.0, 1.0, 0.0])
            return quat_from_axis_angle(_unit(perp), np.pi)
        return quat_from_axis_angle(axis / s, math.atan2(s, c))
    e2, d2 = _unit(np.cross(e1, char[1])), _unit(np.cross(d1, src[1]))
    frame_c = np.stack([e1, e2, np.cross(e1, e2)], axis=-1)
    frame_s = np.stack([d1, d2, np.cross(d1, d2)], axis=-1)
    return matrix_to_quat(frame_s @ frame_c.T)


def hinge_twist(local: np.ndarray, bone: np.ndarray, flex: np.ndarray, min_motion_deg: float = 10.0) -> np.ndarray:
    """The turn T about ``bone`` that brings a hinge's flexion axis, as seen in the data, onto ``flex``.

    The flexion axis is the principal axis of the local rotation vectors (weighted by their size), pointed along the
    mean flexion and projected perpendicular to the bone. With T, T^-1 L T turns about ``flex`` as nearly as possible.

    Args:
        local: The hinge's local rotation per frame before the turn. Shape: (F, 4).
        bone: The parent's bone direction, parent body frame. Shape: (3,).
        flex: The character's flexion axis (the hinge axis signed as its joint range). Shape: (3,).
        min_motion_deg: Below this largest rotation the axis is not measurable: no turn.

    Returns:
        T as a quaternion, about ``bone``. Shape: (4,).
    """
    rv = quat_to_rotvec(local)
    angle = np.linalg.norm(rv, axis=-1)
    if angle.max() < np.radians(min_motion_deg):
        return np.array([1.0, 0.0, 0.0, 0.0])
    axis = np.linalg.eigh(rv.T @ rv)[1][:, -1]
    axis = axis if np.sum(rv @ axis) >= 0 else -axis
    e = _unit(bone)
    axis = axis - np.dot(axis, e) * e
    target = flex - np.dot(flex, e) * e
    return quat_from_axis_angle(e, math.atan2(np.dot(e, np.cross(target, axis)), np.dot(target, axis)))


def triad(e1: np.ndarray, e2: np.ndarray, d1: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """Per frame, the rotation taking e1 onto d1 exactly and e2 as near d2 as possible.

    Args:
        e1, e2: Directions in the body frame. Shape: (3,).
        d1, d2: Directions in the world per frame. Shape: (F, 3).

    Returns:
        Quaternions. Shape: (F, 4).
    """
    def frame(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        a = a / np.linalg.norm(a, axis=-1, keepdims=True)
        n = np.cross(a, b)
        n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
        return np.stack([a, n, np.cross(a, n)], axis=-1)

    return matrix_to_quat(frame(d1, d2) @ np.swapaxes(frame(e1, e2), -1, -2))


def world_axes(up: str, left: np.ndarray) -> np.ndarray:
    """W with rows forward, left, up of the source (see the module docstring). Shape: (3, 3)."""
    u = np.eye(3)["xyz".index(up)]
    left = _unit(left - np.dot(left, u) * u)
    return np.stack([np.cross(left, u), left, u])


@dataclass(frozen=True)
class _Pair:
    """The two skeletons side by side: the character at its zero pose, the source at rest, in project axes.

    Attributes:
        bodies: Character body names; ``parent`` their parent indices (-1 for the root).
        zero: Character body origins at the zero pose. Shape: (B, 3).
        rest: Source joint and End Site positions at rest (file units, file axes).
        src: Character body -> its source joint; ``tips``: leaf body -> the joint or End Site its tip aims at.
        world: W, file axes -> project axes. Shape: (3, 3).
    """

    bodies: tuple[str, ...]
    parent: np.ndarray
    zero: np.ndarray
    rest: dict[str, np.ndarray]
    src: dict[str, str]
    tips: dict[str, str]
    world: np.ndarray

    def char_vec(self, a: str, b: str) -> np.ndarray:
        """Character body a -> body b at the zero pose."""
        return self.zero[self.bodies.index(b)] - self.zero[self.bodies.index(a)]

    def src_vec(self, a: str, b: str) -> np.ndarray:
        """Source point a -> point b at rest, in project axes (file units)."""
        return self.world @ (self.rest[b] - self.rest[a])

    def parent_of(self, body: str) -> str:
        return self.bodies[self.parent[self.bodies.index(body)]]

    def children(self, body: str) -> list[str]:
        return [self.bodies[c] for c in np.flatnonzero(self.parent == self.bodies.index(body))]


def _rest_rotations(pair: _Pair, joint_map: JointMap, driven: list[str]) -> dict[str, np.ndarray]:
    """A_b per driven body: the character's zero-pose bone directions turned onto the source's rest ones."""
    out = {}
    for b in driven:
        kids = pair.children(b)
        if not kids:
            if b not in joint_map.tips:
                raise MotionFormatError(f"{joint_map.name}: body {b} has no mapped child: give it a tip")
            pairs = [(joint_map.tips[b].along, pair.src_vec(pair.src[b], pair.tips[b]))]
        elif len(kids) == 1:
            pairs = [(pair.char_vec(b, kids[0]), pair.src_vec(pair.src[b], pair.src[kids[0]]))]
        else:
            centre = [k for k in kids if not k.startswith(("left_", "right_"))]
            left = [k for k in kids if k.startswith("left_")]
            right = [k for k in kids if k.startswith("right_")]
            if len(centre) != 1 or len(left) != 1 or len(right) != 1:
                raise ValueError(f"body {b}: expected one centre, one left and one right child, got {kids}")
            # Up the spine exactly, then the right-to-left line (hips or shoulders) as near as possible.
            pairs = [(pair.char_vec(b, centre[0]), pair.src_vec(pair.src[b], pair.src[centre[0]])),
                     (pair.char_vec(right[0], left[0]),
                      pair.src_vec(pair.src[right[0]], pair.src[left[0]]))]  # fmt: skip
        out[b] = align([p[0] for p in pairs], [p[1] for p in pairs])
    return out


def _point(bvh: Bvh, pos: np.ndarray, rot: np.ndarray, name: str) -> np.ndarray:
    """World position per frame of a joint or an End Site (``JOINT/end``). Shape: (F, 3)."""
    if name.endswith(END_SUFFIX):
        j = bvh.index(name.removesuffix(END_SUFFIX))
        return pos[:, j] + quat_rotate(rot[:, j], bvh.joints[j].end_site)
    return pos[:, bvh.index(name)]


def _onto_hinges(pair: _Pair, humanoid: Humanoid, body_rot: dict[str, np.ndarray]) -> tuple[dict, dict]:
    """Turns each knee's and elbow's limb onto its hinge and keeps only the twist about it (``body_rot`` in place).

    Returns:
        ({hinge: limb turn in degrees}, {hinge: (mean, max) residual in degrees}).
    """
    turns, residual = {}, {}
    model = humanoid.model
    for g in humanoid.joint_groups:
        if g.kind != "revolute":
            continue
        p = pair.parent_of(g.body)
        local = quat_mul(quat_conj(body_rot[p]), body_rot[g.body])
        # Bone directions leave the limb's twist about its bone free: choose it so that the source's flexion axis
        # (from the data) falls on the character's hinge, signed as the joint's range. Both bones turn alike.
        lo, hi = model.jnt_range[model.jnt_qposadr == g.qpos[0]][0]
        turn = hinge_twist(local, pair.char_vec(p, g.body), -_HINGE if lo + hi < 0 else _HINGE)
        turns[g.name] = float(np.degrees(quat_geodesic_angle(turn, np.array([1.0, 0.0, 0.0, 0.0]))))
        for b in (p, g.body):
            body_rot[b] = quat_mul(body_rot[b], turn)
        local = quat_mul(quat_conj(body_rot[p]), body_rot[g.body])
        twist = quat_from_axis_angle(_HINGE, 2.0 * np.arctan2(local[:, 2], local[:, 0]))
        err = np.degrees(quat_geodesic_angle(local, twist))
        residual[g.name] = (float(err.mean()), float(err.max()))
        body_rot[g.body] = quat_mul(body_rot[p], twist)
    return turns, residual


def retarget(bvh: Bvh, humanoid: Humanoid, joint_map: JointMap, options: RetargetOptions | None = None,
             name: str | None = None) -> Retargeted:  # fmt: skip
    """Retargets a BVH take onto the humanoid (see the module docstring).

    Args:
        bvh: The take.
        humanoid: The character.
        joint_map: Source joint per character body.
        options: Units, up axis and root scaling.
        name: Clip name; the file stem by default.

    Raises:
        MotionFormatError: a mapped joint missing from the file, a leaf body without a tip, or degenerate bones.
    """
    options = options or RetargetOptions()
    rest = rest_positions(bvh)
    bodies = humanoid.body_names
    src = {b: _resolve(bvh, joint_map.bodies[b], rest, f"for body {b}", joint_map.name) for b in bodies}
    tips = {b: _resolve(bvh, t.source, rest, f"tip of {b}", joint_map.name) for b, t in joint_map.tips.items()}
    for b in bodies:
        if src[b].endswith(END_SUFFIX):
            raise MotionFormatError(f"{bvh.source}: body {b} is mapped to End Site {src[b]}: it needs a joint")
    up = options.up or joint_map.up
    world = world_axes(up, rest[src["left_thigh"]] - rest[src["right_thigh"]])
    pair = _Pair(bodies, humanoid.parent_index, zero_pose(humanoid), rest, src, tips, world)
    # Bodies with no joint of their own (the hands, welded to the forearms) only mark where their parent points.
    pelvis = bodies[humanoid.root_index]
    driven = [pelvis] + [g.body for g in humanoid.joint_groups]
    rest_rot = _rest_rotations(pair, joint_map, driven)

    pos, rot = forward_kinematics(bvh)
    w = matrix_to_quat(world)
    w_inv = quat_conj(w)
    body_rot = {b: quat_mul(quat_mul(quat_mul(w, rot[:, bvh.index(src[b])]), w_inv), rest_rot[b]) for b in driven}
    for b, tip in joint_map.tips.items():
        if tip.with_parent:
            toward_parent = (pos[:, bvh.index(src[pair.parent_of(b)])] - pos[:, bvh.index(src[b])]) @ world.T
            tip_dir = (_point(bvh, pos, rot, tips[b]) - pos[:, bvh.index(src[b])]) @ world.T
            body_rot[b] = triad(tip.along, -pair.char_vec(pair.parent_of(b), b), tip_dir, toward_parent)
    turns, residual = _onto_hinges(pair, humanoid, body_rot)

    scale, note = (options.scale, "given") if options.scale else infer_scale(rest, "xyz".index(up))
    legs = [("right_thigh", "right_shin", "right_foot"), ("left_thigh", "left_shin", "left_foot")]
    char_leg = np.mean([np.linalg.norm(pair.char_vec(a, b)) + np.linalg.norm(pair.char_vec(b, c)) for a, b, c in legs])
    src_leg = np.mean([np.linalg.norm(pair.src_vec(src[a], src[b])) + np.linalg.norm(pair.src_vec(src[b], src[c]))
                       for a, b, c in legs])  # fmt: skip
    leg_ratio = float(char_leg / (src_leg * scale))
    k = leg_ratio * scale if options.root == "legs" else scale
    hips = 0.5 * (pos[:, bvh.index(src["left_thigh"])] + pos[:, bvh.index(src["right_thigh"])])
    hip_offset = 0.5 * (pair.char_vec(pelvis, "left_thigh") + pair.char_vec(pelvis, "right_thigh"))
    root_pos = k * hips @ world.T - quat_rotate(body_rot[pelvis], hip_offset)

    joint_rot = np.stack([quat_mul(quat_conj(body_rot[pair.parent_of(g.body)]), body_rot[g.body])
                          for g in humanoid.joint_groups], axis=1)  # fmt: skip
    clip = Clip(
        name=name or Path(bvh.source).stem, source=bvh.source, loop=False,
        times=np.arange(bvh.num_frames) * bvh.frame_time, root_pos=root_pos,
        root_rot=quat_fix_hemisphere(quat_normalize(body_rot[pelvis]), axis=0),
        joint_rot=quat_fix_hemisphere(quat_normalize(joint_rot), axis=0),
    )  # fmt: skip
    sources = {b: src[b] for b in bodies} | {f"{b} tip": t for b, t in tips.items()}
    return Retargeted(clip, sources, scale, note, leg_ratio, world, residual, turns)
