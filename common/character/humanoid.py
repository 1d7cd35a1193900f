"""The DeepMimic humanoid in MuJoCo and a description of it by name.

Everything else in the project reaches bodies, joints and actuators through :class:`Humanoid`, never through
hard-coded indices. The MJCF lives in ``common/character/assets/humanoid3d.xml``; see its header for the conversion from
DeepMimic's character file.

Conventions: Z up, metres, radians; MuJoCo quaternions (w, x, y, z). The free root joint's qvel is
[linear velocity (world frame), angular velocity (root body frame)], as MuJoCo defines it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from importlib import resources
from pathlib import Path

import mujoco
import numpy as np

ASSET_XML = "humanoid3d.xml"

# DeepMimic joint name -> (child body, kind). The order is DeepMimic's joint order (the motion file's order).
DEEPMIMIC_JOINTS: tuple[tuple[str, str, str], ...] = (
    ("chest", "torso", "spherical"),
    ("neck", "head", "spherical"),
    ("right_hip", "right_thigh", "spherical"),
    ("right_knee", "right_shin", "revolute"),
    ("right_ankle", "right_foot", "spherical"),
    ("right_shoulder", "right_upper_arm", "spherical"),
    ("right_elbow", "right_lower_arm", "revolute"),
    ("left_hip", "left_thigh", "spherical"),
    ("left_knee", "left_shin", "revolute"),
    ("left_ankle", "left_foot", "spherical"),
    ("left_shoulder", "left_upper_arm", "spherical"),
    ("left_elbow", "left_lower_arm", "revolute"),
)
ROOT_BODY = "pelvis"
HEAD_BODY = "head"
FOOT_BODIES = ("right_foot", "left_foot")


def mirror_name(name: str) -> str:
    """The left-right twin of a joint, body, actuator or feature name (``left_*`` <-> ``right_*``); itself for the
    names of neither side (chest, neck, root)."""
    if name.startswith("left_"):
        return "right_" + name[len("left_") :]
    if name.startswith("right_"):
        return "left_" + name[len("right_") :]
    return name


def set_torsional_friction(m: mujoco.MjModel, coefficient: float) -> None:
    """Gives every geom of the world body (the floor) ``condim`` 4 and the torsional friction ``coefficient`` (m), so
    that each contact with it resists spinning about its normal up to ``coefficient`` times its normal force
    (:class:`PhysicsConfig`'s ``torsional_friction``). MuJoCo reads both at every collision; a contact's ``condim`` and
    friction are the larger of its two geoms'."""
    floor = np.flatnonzero(m.geom_bodyid == 0)
    if floor.size == 0:
        raise ValueError("physics.torsional_friction: the model has no floor geom (a geom of the world body)")
    m.geom_condim[floor] = np.maximum(m.geom_condim[floor], 4)
    m.geom_friction[floor, 1] = coefficient


def apply_physics(m: mujoco.MjModel, physics: PhysicsConfig) -> None:
    """Sets a freshly compiled model of the character to ``physics``' rates, solver and study knobs (in place)."""
    m.opt.timestep = physics.physics_dt
    m.opt.iterations = physics.solver_iterations
    m.opt.ls_iterations = physics.ls_iterations
    if physics.armature is not None:
        m.dof_armature[m.jnt_dofadr[m.jnt_type == mujoco.mjtJoint.mjJNT_HINGE]] = physics.armature
    if physics.torque_scale != 1.0:
        m.actuator_forcerange[:] *= physics.torque_scale
    if physics.torsional_friction > 0.0:
        set_torsional_friction(m, physics.torsional_friction)


HAND_BODIES = ("right_hand", "left_hand")
# DeepMimic's EnableFallContact bodies: touching the ground with one of them is a fall.
FALL_CONTACT_BODIES = ("pelvis", "torso", "head")


@dataclass(frozen=True)
class PhysicsConfig:
    """Simulation rates and solver settings.

    Attributes:
        control_hz: Control (and reference data) rate in Hz; one gym step is 1 / control_hz seconds.
        substeps: Physics steps per control step; the physics timestep is 1 / (control_hz * substeps).
        solver_iterations: Constraint solver iterations (MuJoCo's default is 100).
        ls_iterations: Line-search iterations of the Newton solver.
        armature: Rotor inertia (kg m^2) added to every hinge; None keeps the MJCF's value. Too little lets the
            stiff PD servos chatter at the physics rate (see ``common/character/assets/humanoid3d.xml``).
        torque_scale: Multiplies every servo's torque limit (the actuators' ``forcerange``; the MJCF's, DeepMimic's,
            at 1). A study knob, not a tuning one: how strong the character must be to track a clip (session 23).
        torsional_friction: 0 (the MJCF's contacts, ``condim`` 3): a contact resists sliding only, so the character
            turns about the vertical by the sliding friction of separate contact points alone. Above 0: every floor
            contact also resists spinning about its normal, up to this length (m) times its normal force (MuJoCo's
            ``condim`` 4 and torsional friction coefficient, set on the floor geoms; a contact takes the larger of its
            two geoms' values). A study knob like ``torque_scale`` (session 26): do the spins fail for the lack of it?
            A foot's patch of radius r pressed evenly resists up to 2/3 mu r N (r = 4.5 cm: 0.03 m at mu = 1).
    """

    control_hz: float = 60.0
    substeps: int = 8
    solver_iterations: int = 100
    ls_iterations: int = 50
    armature: float | None = None
    torque_scale: float = 1.0
    torsional_friction: float = 0.0

    def __post_init__(self) -> None:
        if self.control_hz <= 0:
            raise ValueError(f"physics.control_hz must be positive, got {self.control_hz}")
        if self.substeps < 1:
            raise ValueError(f"physics.substeps must be >= 1, got {self.substeps}")
        if self.armature is not None and not self.armature >= 0:
            raise ValueError(f"physics.armature must be >= 0 (kg m^2), got {self.armature}")
        if not self.torque_scale > 0:
            raise ValueError(f"physics.torque_scale must be > 0, got {self.torque_scale}")
        if not self.torsional_friction >= 0:
            raise ValueError(f"physics.torsional_friction must be >= 0 (m), got {self.torsional_friction}")

    @property
    def control_dt(self) -> float:
        return 1.0 / self.control_hz

    @property
    def physics_dt(self) -> float:
        return 1.0 / (self.control_hz * self.substeps)


@dataclass(frozen=True)
class JointGroup:
    """One DeepMimic joint: a spherical joint (three hinges x, y, z) or a revolute one (one hinge about +y).

    Attributes:
        name: DeepMimic joint name, e.g. ``"right_hip"``.
        body: Name of the child body the joint moves.
        kind: ``"spherical"`` or ``"revolute"``.
        qpos: Indices into qpos of its hinges (3 or 1).
        dof: Indices into qvel of its hinges.
        actuators: Indices into ctrl of its position actuators (same order as ``qpos``).
    """

    name: str
    body: str
    kind: str
    qpos: tuple[int, ...]
    dof: tuple[int, ...]
    actuators: tuple[int, ...]


class Humanoid:
    """The MuJoCo model plus name-based indices that the rest of the project uses.

    Args:
        physics: Rates and solver settings applied to the loaded model.
        xml_path: MJCF file; the bundled DeepMimic humanoid by default.
    """

    def __init__(self, physics: PhysicsConfig | None = None, xml_path: str | Path | None = None) -> None:
        self.physics = physics or PhysicsConfig()
        if xml_path is None:
            xml_path = resources.files("common.character") / "assets" / ASSET_XML
        self.xml_path = Path(str(xml_path))
        self.model = mujoco.MjModel.from_xml_path(str(self.xml_path))
        apply_physics(self.model, self.physics)
        m = self.model
        # Body 0 is MuJoCo's world body; the character's bodies follow in depth-first order.
        self.body_names: tuple[str, ...] = tuple(
            mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(1, m.nbody)
        )
        self.joint_groups: tuple[JointGroup, ...] = tuple(self._group(n, b, k) for n, b, k in DEEPMIMIC_JOINTS)
        free = m.jnt_type == mujoco.mjtJoint.mjJNT_FREE
        if free.sum() != 1 or m.jnt_qposadr[np.flatnonzero(free)[0]] != 0:
            raise ValueError(f"{self.xml_path}: expected exactly one free joint at qpos[0:7]")

    def _group(self, name: str, body: str, kind: str) -> JointGroup:
        m = self.model
        axes = ("_x", "_y", "_z") if kind == "spherical" else ("",)
        qpos, dof, act = [], [], []
        for axis in axes:
            jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name + axis)
            aid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, name + axis)
            if jid < 0 or aid < 0:
                raise ValueError(f"{self.xml_path}: joint or actuator '{name + axis}' is missing")
            moved = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.jnt_bodyid[jid]))
            if moved != body:
                raise ValueError(f"{self.xml_path}: joint '{name + axis}' moves body '{moved}', expected '{body}'")
            qpos.append(int(m.jnt_qposadr[jid]))
            dof.append(int(m.jnt_dofadr[jid]))
            act.append(aid)
        return JointGroup(name, body, kind, tuple(qpos), tuple(dof), tuple(act))

    @property
    def num_bodies(self) -> int:
        return len(self.body_names)

    @property
    def nq(self) -> int:
        return self.model.nq

    @property
    def nv(self) -> int:
        return self.model.nv

    @property
    def nu(self) -> int:
        return self.model.nu

    def body_index(self, name: str) -> int:
        """Index of a body in the project's body arrays (MuJoCo body id - 1)."""
        try:
            return self.body_names.index(name)
        except ValueError:
            raise KeyError(f"no body '{name}' in {self.xml_path}; bodies: {self.body_names}") from None

    def body_indices(self, names: tuple[str, ...] | list[str]) -> np.ndarray:
        return np.array([self.body_index(n) for n in names], dtype=np.int64)

    @cached_property
    def root_index(self) -> int:
        return self.body_index(ROOT_BODY)

    @cached_property
    def head_index(self) -> int:
        return self.body_index(HEAD_BODY)

    @cached_property
    def foot_indices(self) -> np.ndarray:
        return self.body_indices(FOOT_BODIES)

    @cached_property
    def end_effector_indices(self) -> np.ndarray:
        """Hands and feet, DeepMimic's end effectors."""
        return self.body_indices(HAND_BODIES + FOOT_BODIES)

    @cached_property
    def fall_contact_indices(self) -> np.ndarray:
        return self.body_indices(FALL_CONTACT_BODIES)

    @cached_property
    def hinge_qpos(self) -> np.ndarray:
        """qpos indices of all actuated hinges, in actuator order. Shape: (nu,)."""
        idx = np.empty(self.nu, dtype=np.int64)
        for g in self.joint_groups:
            idx[list(g.actuators)] = g.qpos
        return idx

    @cached_property
    def hinge_dof(self) -> np.ndarray:
        """qvel indices of all actuated hinges, in actuator order. Shape: (nu,)."""
        idx = np.empty(self.nu, dtype=np.int64)
        for g in self.joint_groups:
            idx[list(g.actuators)] = g.dof
        return idx

    @cached_property
    def parent_index(self) -> np.ndarray:
        """Parent of each body in the project's body arrays (-1 for the root). Shape: (num_bodies,)."""
        return np.asarray(self.model.body_parentid[1:], dtype=np.int64) - 1

    @cached_property
    def body_mass(self) -> np.ndarray:
        return np.asarray(self.model.body_mass[1:], dtype=np.float64)

    def geom_of_body(self, name: str) -> int:
        """The id of the single collision geom of a body."""
        ids = np.flatnonzero(self.model.geom_bodyid == self.body_index(name) + 1)
        if len(ids) != 1:
            raise ValueError(f"{self.xml_path}: body '{name}' has {len(ids)} geoms, expected 1")
        return int(ids[0])


def hinges_to_joint_rotations(humanoid: Humanoid, qpos: np.ndarray) -> np.ndarray:
    """Local rotation of every DeepMimic joint from the hinge angles in qpos.

    Args:
        humanoid: The model.
        qpos: Shape: (..., nq).

    Returns:
        Unit quaternions in ``humanoid.joint_groups`` order. Shape: (..., J=12, 4).
    """
    from common.maths.rotations import euler_xyz_to_quat, quat_from_axis_angle

    out = []
    for g in humanoid.joint_groups:
        if g.kind == "spherical":
            out.append(euler_xyz_to_quat(qpos[..., list(g.qpos)]))
        else:
            out.append(quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), qpos[..., g.qpos[0]]))
    return np.stack(out, axis=-2)


def joint_rotations_to_hinges(humanoid: Humanoid, rot: np.ndarray, near_qpos: np.ndarray) -> np.ndarray:
    """Hinge angles (actuator order) realising joint rotations, each chosen nearest the angles in ``near_qpos``.

    A PD target must lie near the joint's current or reference angles: the same rotation 2 pi away would make the
    position actuator spin the hinge round.

    Args:
        humanoid: The model.
        rot: Local joint rotations in ``joint_groups`` order. Shape: (N, J, 4).
        near_qpos: qpos whose hinge angles the result should be near. Shape: (N, nq).

    Returns:
        Hinge angle targets in actuator order. Shape: (N, nu).
    """
    from common.maths.rotations import quat_to_euler_xyz_near

    out = np.empty((rot.shape[0], humanoid.nu))
    for j, g in enumerate(humanoid.joint_groups):
        ref = near_qpos[:, list(g.qpos)]
        if g.kind == "spherical":
            out[:, list(g.actuators)] = quat_to_euler_xyz_near(rot[:, j], ref)
        else:
            # Angle about the hinge axis, 2 atan2(q_y, q_w), on the 2 pi branch nearest ref.
            a = 2.0 * np.arctan2(rot[:, j, 2], rot[:, j, 0])
            out[:, g.actuators[0]] = a + 2.0 * np.pi * np.round((ref[:, 0] - a) / (2.0 * np.pi))
    return out


class BodyGeometry:
    """Lowest point of every body's collision geom, vectorised over characters (for ground contact checks).

    Spheres and capsules are their centre points/segment ends minus the radius; boxes their eight corners.
    """

    def __init__(self, humanoid: Humanoid) -> None:
        from common.maths.rotations import quat_rotate

        m = humanoid.model
        points, radius = [], []
        for name in humanoid.body_names:
            g = humanoid.geom_of_body(name)
            kind, size = m.geom_type[g], m.geom_size[g]
            if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
                local, r = np.zeros((1, 3)), size[0]
            elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
                local, r = np.array([[0.0, 0.0, size[1]], [0.0, 0.0, -size[1]]]), size[0]
            elif kind == mujoco.mjtGeom.mjGEOM_BOX:
                signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
                local, r = signs * size, 0.0
            else:
                raise ValueError(f"{humanoid.xml_path}: body '{name}' has an unsupported geom type {kind}")
            pts = m.geom_pos[g] + quat_rotate(np.asarray(m.geom_quat[g], dtype=np.float64), local)
            points.append(np.concatenate([pts, np.repeat(pts[:1], 8 - len(pts), axis=0)]))
            radius.append(r)
        self.points = np.stack(points)  # (B, 8, 3) support points in the body frame
        self.radius = np.array(radius)

    def lowest_points(self, body_pos: np.ndarray, body_rot: np.ndarray) -> np.ndarray:
        """Height of each body's lowest surface point.

        Args:
            body_pos: Shape: (..., B, 3).
            body_rot: Shape: (..., B, 4), (w, x, y, z).

        Returns:
            Shape: (..., B).
        """
        w, x, y, z = (body_rot[..., i] for i in range(4))
        # Third row of the rotation matrix: world z of a body-frame vector.
        row = np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1)
        heights = np.einsum("...bk,bpk->...bp", row, self.points)
        return body_pos[..., 2] + heights.min(axis=-1) - self.radius

    def support_points(self, body_pos: np.ndarray, body_rot: np.ndarray) -> np.ndarray:
        """World x, y, z of every body's support points (sphere centre, capsule ends, box corners).

        z is computed with the arithmetic of :meth:`lowest_points`, so that over a ground of height 0
        :meth:`clearance` equals it bit for bit.

        Args:
            body_pos: Shape: (..., B, 3).
            body_rot: Shape: (..., B, 4), (w, x, y, z).

        Returns:
            Shape: (3, ..., B, 8).
        """
        w, x, y, z = (body_rot[..., i] for i in range(4))
        rows = (
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        )
        return np.stack([body_pos[..., a, None] + np.einsum("...bk,bpk->...bp", row, self.points)
                         for a, row in enumerate(rows)])  # fmt: skip

    def clearance(self, body_pos: np.ndarray, body_rot: np.ndarray,
                  ground: Callable[[np.ndarray, np.ndarray], np.ndarray] | None) -> np.ndarray:  # fmt: skip
        """Height of each body's collision geom above the ground: the least, over the body's support points, of the
        point's height above the ground under it, less the geom's radius (for spheres and capsules the vertical gap
        under their lowest point: on a slope of angle a that overstates the gap normal to it by radius (1 / cos a -
        1), 1.1 mm for a 5 cm foot at 12 deg; for boxes under their lowest corner); negative inside the ground.

        Args:
            body_pos: Shape: (..., B, 3).
            body_rot: Shape: (..., B, 4), (w, x, y, z).
            ground: The ground's height at world (x, y) (arrays of shape (..., B, 8)); None: the floor z = 0,
                :meth:`lowest_points`, which a ground of height 0 equals bit for bit.

        Returns:
            Shape: (..., B).
        """
        if ground is None:
            return self.lowest_points(body_pos, body_rot)
        px, py, pz = self.support_points(body_pos, body_rot)
        return (pz - ground(px, py)).min(axis=-1) - self.radius
