"""How physically feasible each reference clip is for this character, measured from the kinematic reference alone.

Three measures per reference frame of the motion library (no simulation, no tracking):

1. **Residual external force** (contact-model-free). The whole-body centre of mass c (the bodies' masses at their
   inertial frames, MuJoCo's ``xipos``) gives the net external force the reference implies, F_k = m (a_k - g), g =
   ``model.opt.gravity`` (Z up), with a_k = (c_{k+h} - 2 c_k + c_{k-h}) / (h dt)^2 on the control grid (dt =
   ``library.dt``). Only the floor can supply F. A frame is *touching* when any body's collision geom (feet, hands,
   knees, back, head: not only the feet, so crawl, roll, getup_* and cartwheel are judged fairly) has its lowest
   point within ``tolerance`` of the floor plane z = 0; the tolerance is how far above the floor a geom may be in the
   reference and still count as touching it (penetration counts as touching): it absorbs mocap foot-height noise and
   the difference between the actor's feet and the character's boxes; a larger one hides short flight phases.
   The residual, the part of F no floor contact can supply, is |F| without contact; with contact |F| when F_z < 0
   (the floor cannot pull), else max(0, |F_h| - mu F_z).
   All floor contacts share the normal +z, so a sum of contact forces inside their friction cones lies in the same
   cone: the test on the net force is exact for any number of touching bodies. It does not check the moment (a force
   inside the cone may still need a centre of pressure outside the support).
   The step h: the library interpolates keyframes linearly, so c'' is a train of impulses at the source keyframes
   (every 2 grid steps for 30 Hz clips, 3.75 for 16 Hz ones) and a one-step difference alternates between 0 and twice
   the true value. The h-step difference is exactly the mean of c'' under a triangle of half-width h dt, so h is the
   keyframe spacing in grid steps, at least 2 (:func:`accel_step`). Because a_k is that mean, frame k counts as in
   contact when any frame in [k - h, k + h] touches: a mean of forces that are inside the cone while touching and 0
   in flight is inside the cone, so a reference whose force is feasible at every instant scores 0, and a residual
   proves infeasibility (a lower bound, up to contacts that begin and end between two frames).

2. **Inverse dynamics** (``mujoco.mj_inverse``) on the library's qpos and qvel and the qacc of the same h-step
   difference, qacc_k = (dq(q_k, q_{k+h}) - dq(q_{k-h}, q_k)) / (h dt)^2 with dq MuJoCo's ``mj_differentiatePos``
   (the free joint's 6 dofs: world linear, then root-frame angular; one per hinge); for h = 2 and the linear
   coordinates this equals the central difference of the library's qvel. ``qfrc_inverse`` is the generalised force
   that realises qacc *given the contact forces MuJoCo's soft contact model produces at that state*: (a) at the
   actuated hinges it is the torque the PD actuators must deliver, compared with ``actuator_forcerange`` times the
   gear; (b) at the free joint's translation dofs it is the force a "root force" would have to add (world frame).
   Both depend strongly on the reference's floor clearance: with prescribed accelerations the soft contact's force
   grows with penetration (a foot 2-5 cm in the floor gets tens of body weights, which the hinges above it must then
   hold: on run, kick and backflip 38-61% of the frames are over a limit with contacts, 2-10% without), a foot on or
   above the floor gets none (walk's feet, at most 5 mm in, leave about one body weight to the root), so mocap height
   noise moves (a) and (b) a lot; measure 1 is the figure that does not depend on the contact model. Joint limits
   (knees, elbows) act too: a reference knee bent past its range is pushed back by the limit's soft constraint, which
   the hinge must then hold. (c) The hinge torques *unconstrained*, with contacts and joint limits switched off,
   every external force supplied at the root: free of the contact model, but it spares the stance legs the body's
   weight, so it understates their torques; in flight (a) and (c) agree unless a limit is violated, and the root
   force of (c) is m (a_com - g), measure 1's F. Besides, the reference's hinge angles are checked against the joint
   ranges (``jnt_range``): the simulated character cannot go past them at all.

3. **Moment** (contact-model-free, needs the contacts' places). About the whole-body CoM gravity has no moment, so
   the rate of change of the character's angular momentum about its CoM, dL/dt (L: MuJoCo's ``subtree_angmom`` of
   the root body from the library's qpos and qvel; dL/dt on the same triangle of half-width h dt as measure 1's
   force, by the trapezoid rule over each half), is the moment sum_i (p_i - c) x f_i of the floor's contact forces
   f_i at their points p_i. Measure 1 asks only whether F = sum_i f_i lies in the cone; a spin, a lean or a turn on
   one foot can need a moment no set of forces at the touching points gives (without torsional friction, which
   MuJoCo's default ``condim`` 3 contacts do not have, a foot turns the body about the vertical only through the
   lever of its tangential forces about its corners). The contact points are the support points of every touching
   geom (box corners, capsule ends, sphere centres, lowered by the radius, :class:`BodyGeometry`) within
   ``tolerance`` of the floor in any frame of [k - h, k + h], placed on the floor; each gets the friction pyramid of
   8 edges that holds the cone (edges mu / cos(pi / 8) out), so the contacts can do at least what the true cones
   can. The forces f_i are found by non-negative least squares (:func:`nnls`) on the pyramid edges, the force rows
   weighted :data:`FORCE_PRIORITY` times the moment rows in body-weight units (m |g| and m |g| x 1 m): the force
   is matched first (as closely as measure 1 allows), then the moment as closely as forces with that sum allow.
   The **moment residual** is the part of dL/dt left, in body-weight metres (the unit of ``studies.samcon.assist``'s
   ``--torque-cap``): the smallest root couple the reference needs on top of what its contacts give. Moving the
   contact points and the moment arm within the window is where it is an estimate, not a bound.

One-shot clips skip their first and last h frames (no central difference there). Looping clips are measured over
one whole cycle, frames h..h+n-1, the frames past the cycle end coming from the library's own continuation (frame n
is frame 0 moved by the cycle transform), so the loop seam is differentiated like any other frame.

Command::

    python -m studies.samcon.feasibility --motions all --out runs/feasibility.json
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from common.character.humanoid import BodyGeometry, Humanoid, hinges_to_joint_rotations, joint_rotations_to_hinges
from common.config import atomic_output
from common.motion.dataset import resolve_clips
from common.motion.library import MotionLibrary

CONTACT_TOLERANCE = 0.03  # m: a geom whose lowest point is this close to the floor (or below it) touches it
RESIDUAL_THRESHOLD = 0.1  # body weights: the residual force counted as "large"
# body-weight metres: the moment residual counted as "large" (half the 0.1 couple of studies.samcon.assist)
MOMENT_THRESHOLD = 0.05
FORCE_FITS = 0.01  # body weights: a frame whose residual force is below this has its force in the cone (measure 3)
FORCE_PRIORITY = 1000.0  # weight of the force rows against the moment rows in the contact-force fit (measure 3)
PYRAMID_EDGES = 8
MIN_STEP = 2  # grid steps: differencing the library's central-difference velocities once more spans 2 steps


@dataclass(frozen=True)
class FrameFeasibility:
    """Per-frame measures of one reference, T frames (those with h frames on both sides).

    Attributes:
        force: Net external force F = m (a_com - g), world. Shape: (T, 3), N.
        contact: Some body touches the floor within the frame's differencing window. Shape: (T,).
        clearance: Lowest collision-geom point of the whole character above the floor (< 0: in it). Shape: (T,), m.
        residual: Part of F outside the floor's friction cone, in body weights m |g|. Shape: (T,).
        hinge_torque: ``qfrc_inverse`` at the actuated hinges, actuator order. Shape: (T, nu), N m.
        hinge_ratio: |hinge torque| / the actuator's limit on that side (> 1: over it). Shape: (T, nu).
        root_residual: |qfrc_inverse| at the free joint's translation dofs, in body weights. Shape: (T,).
        hinge_ratio_unconstrained: ``hinge_ratio`` with contacts and joint limits off. Shape: (T, nu).
        range_excess: How far each hinge angle lies outside its joint range (0 inside). Shape: (T, nu), rad.
        moment_rate: dL/dt, angular momentum about the CoM, world (measure 3). Shape: (T, 3), N m.
        moment_residual: The part of dL/dt no contact forces at the touching points give, world, in body-weight
            metres m |g| x 1 m. Shape: (T, 3).
    """

    force: np.ndarray
    contact: np.ndarray
    clearance: np.ndarray
    residual: np.ndarray
    hinge_torque: np.ndarray
    hinge_ratio: np.ndarray
    root_residual: np.ndarray
    hinge_ratio_unconstrained: np.ndarray
    range_excess: np.ndarray
    moment_rate: np.ndarray
    moment_residual: np.ndarray


def total_mass(humanoid: Humanoid) -> float:
    """m: the character's mass in kg (MuJoCo's world body has none)."""
    return float(humanoid.model.body_mass.sum())


def body_weight(humanoid: Humanoid) -> float:
    """m |g| in N."""
    return total_mass(humanoid) * float(np.linalg.norm(humanoid.model.opt.gravity))


def model_friction(humanoid: Humanoid) -> float:
    """The sliding friction coefficient of a body-floor contact in the model.

    MuJoCo gives a contact between geoms of equal priority the larger of their ``geom_friction[:, 0]``; this is the
    smallest such value over the character's geoms against the floor plane(s), the most restrictive contact.
    """
    m = humanoid.model
    floors = np.flatnonzero((m.geom_bodyid == 0) & (m.geom_type == mujoco.mjtGeom.mjGEOM_PLANE))
    if len(floors) == 0:
        raise ValueError(f"{humanoid.xml_path}: no floor plane on the world body")
    body_geoms = np.flatnonzero(m.geom_bodyid > 0)
    return float(np.maximum(m.geom_friction[floors, 0][:, None], m.geom_friction[body_geoms, 0][None, :]).min())


def torque_limits(humanoid: Humanoid) -> tuple[np.ndarray, np.ndarray]:
    """Torque limits of the actuated hinges (actuator force range times gear), actuator order.

    Returns:
        (lower, upper), each of shape (nu,), N m; lower < 0 < upper.
    """
    m = humanoid.model
    bounds = np.sort(m.actuator_forcerange * m.actuator_gear[:, :1], axis=1)
    if not np.all(m.actuator_forcelimited) or not np.all((bounds[:, 0] < 0) & (bounds[:, 1] > 0)):
        raise ValueError(f"{humanoid.xml_path}: every actuator needs a force range around 0 for the torque check")
    return bounds[:, 0].copy(), bounds[:, 1].copy()


def accel_step(keyframe_spacing: float, dt: float) -> int:
    """h: the source keyframe spacing in grid steps, rounded up, at least :data:`MIN_STEP`.

    Wrap clips are time-scaled by up to 1% onto whole cycles, hence the 5% slack before rounding up.
    """
    return max(MIN_STEP, math.ceil(keyframe_spacing / dt - 0.05))


def com_and_clearance(humanoid: Humanoid, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whole-body centre of mass and lowest collision-geom point per frame, from MuJoCo's kinematics.

    Args:
        humanoid: The model.
        qpos: Shape: (T, nq).

    Returns:
        com (T, 3) in m, world; clearance (T,): the character's lowest geom surface point, m above z = 0.
    """
    m = humanoid.model
    data = mujoco.MjData(m)
    mass = m.body_mass / m.body_mass.sum()
    com = np.empty((len(qpos), 3))
    body_pos = np.empty((len(qpos), humanoid.num_bodies, 3))
    body_rot = np.empty((len(qpos), humanoid.num_bodies, 4))
    for k, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(m, data)
        com[k] = mass @ data.xipos
        body_pos[k], body_rot[k] = data.xpos[1:], data.xquat[1:]
    return com, BodyGeometry(humanoid).lowest_points(body_pos, body_rot).min(axis=-1)


def residual_vector(force: np.ndarray, contact: np.ndarray, friction: float) -> np.ndarray:
    """The part of the external force no floor contact (normal +z, friction coefficient mu) can supply, as a vector.

    Without contact, or when F_z < 0 (the floor cannot pull), all of F. With contact and F_z >= 0 the floor gives F_z
    and at most mu F_z horizontally, so the rest is horizontal, along F_h, of length max(0, |F_h| - mu F_z).

    Args:
        force: Net external force. Shape: (T, 3).
        contact: True where the floor can push. Shape: (T,).
        friction: mu >= 0.

    Returns:
        Shape: (T, 3), in the units of ``force``.
    """
    horizontal = np.linalg.norm(force[:, :2], axis=-1)
    excess = np.maximum(0.0, horizontal - friction * force[:, 2])
    share = np.divide(excess, horizontal, out=np.zeros_like(excess), where=horizontal > 0.0)
    in_cone = np.concatenate([force[:, :2] * share[:, None], np.zeros((len(force), 1))], axis=1)
    return np.where((contact & (force[:, 2] >= 0.0))[:, None], in_cone, force)


def residual_force(force: np.ndarray, contact: np.ndarray, friction: float) -> np.ndarray:
    """|:func:`residual_vector`|: |F| without contact or when F_z < 0, else max(0, |F_h| - mu F_z). Shape: (T,)."""
    return np.linalg.norm(residual_vector(force, contact, friction), axis=-1)


def external_force(humanoid: Humanoid, com: np.ndarray, clearance: np.ndarray, dt: float, step: int,
                   tolerance: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Measure 1's net external force and contact flag for frames h..h+T-1 (see the module docstring).

    Args:
        com: Whole-body centre of mass per frame (:func:`com_and_clearance`). Shape: (T + 2h, 3), m.
        clearance: Lowest geom point per frame. Shape: (T + 2h,), m.
        dt: Grid step in s.
        step: h in grid steps.
        tolerance: Contact tolerance in m.

    Returns:
        F = m (a_com - g) (T, 3), N, world; whether any frame of [k - h, k + h] touches the floor (T,).
    """
    acc = (com[2 * step :] - 2.0 * com[step:-step] + com[: -2 * step]) / (step * dt) ** 2
    force = total_mass(humanoid) * (acc - np.asarray(humanoid.model.opt.gravity))
    touching = np.lib.stride_tricks.sliding_window_view(clearance <= tolerance, 2 * step + 1)
    return force, touching.any(axis=-1)


def position_second_difference(humanoid: Humanoid, qpos: np.ndarray, step: int, dt: float) -> np.ndarray:
    """qacc_k = (dq(q_k, q_{k+h}) - dq(q_{k-h}, q_k)) / (h dt)^2 with dq from ``mj_differentiatePos``.

    Args:
        qpos: Shape: (T + 2h, nq).
        step: h in grid steps.
        dt: Grid step in s.

    Returns:
        qacc of frames h..h+T-1. Shape: (T, nv).
    """
    m = humanoid.model
    span = step * dt
    vel = np.empty((len(qpos) - step, m.nv))  # vel[j]: mean velocity from frame j to j + h
    for j in range(len(vel)):
        mujoco.mj_differentiatePos(m, vel[j], span, qpos[j], qpos[j + step])
    return (vel[step:] - vel[:-step]) / span


def inverse_dynamics(humanoid: Humanoid, qpos: np.ndarray, qvel: np.ndarray, qacc: np.ndarray,
                     constraints: bool = True) -> np.ndarray:  # fmt: skip
    """``qfrc_inverse`` per frame: the generalised force realising qacc, net of MuJoCo's soft contact forces.

    Args:
        qpos: Shape: (T, nq).
        qvel: Shape: (T, nv).
        qacc: Shape: (T, nv).
        constraints: False switches contacts and joint limits off (on a copy of the model).

    Returns:
        Shape: (T, nv); the free joint first (world force in N, then root-frame torque in N m), then hinges in N m.
    """
    m = humanoid.model
    if not constraints:
        m = copy.copy(m)
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    data = mujoco.MjData(m)
    out = np.empty((len(qpos), m.nv))
    for k in range(len(qpos)):
        data.qpos[:], data.qvel[:], data.qacc[:] = qpos[k], qvel[k], qacc[k]
        mujoco.mj_inverse(m, data)
        out[k] = data.qfrc_inverse
    return out


def hinge_ratios(humanoid: Humanoid, torque: np.ndarray) -> np.ndarray:
    """|torque| over the limit on its side (upper for tau >= 0, lower for tau < 0).

    Args:
        torque: Hinge torques in actuator order. Shape: (T, nu), N m.

    Returns:
        Shape: (T, nu); > 1 is over the limit.
    """
    lower, upper = torque_limits(humanoid)
    return np.where(torque >= 0.0, torque / upper, torque / lower)


def range_excess(humanoid: Humanoid, qpos: np.ndarray) -> np.ndarray:
    """How far each actuated hinge's angle lies outside its joint range; 0 inside it or for unlimited hinges.

    Args:
        qpos: Shape: (T, nq).

    Returns:
        Actuator order. Shape: (T, nu), rad.
    """
    m = humanoid.model
    joints = m.actuator_trnid[:, 0]
    angle = qpos[:, m.jnt_qposadr[joints]]
    lower, upper = m.jnt_range[joints, 0], m.jnt_range[joints, 1]
    return np.where(m.jnt_limited[joints].astype(bool), np.maximum(0.0, np.maximum(lower - angle, angle - upper)), 0.0)


def angular_momentum(humanoid: Humanoid, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
    """L: the character's angular momentum about its centre of mass per frame, world, N m s.

    MuJoCo's ``subtree_angmom`` of the character's root body (``mj_subtreeVel``), the sum over the bodies of
    m_b (x_b - c) x (v_b - v_c) + I_b w_b.

    Args:
        qpos: Shape: (T, nq).
        qvel: Shape: (T, nv).
    """
    m = humanoid.model
    roots = np.flatnonzero(m.body_parentid[1:] == 0) + 1
    if len(roots) != 1:
        raise ValueError(f"{humanoid.xml_path}: the character must be one kinematic tree (world children: {roots})")
    data = mujoco.MjData(m)
    out = np.empty((len(qpos), 3))
    for k in range(len(qpos)):
        data.qpos[:], data.qvel[:] = qpos[k], qvel[k]
        mujoco.mj_forward(m, data)
        mujoco.mj_subtreeVel(m, data)
        out[k] = data.subtree_angmom[roots[0]]
    return out


def triangle_rate(values: np.ndarray, dt: float, step: int) -> np.ndarray:
    """The mean time derivative of a sampled quantity under a triangle of half-width h dt, at frames h..T+h-1.

    (mean over [t_k, t_k+h] - mean over [t_k-h, t_k]) / (h dt), each mean by the trapezoid rule: the weighting of
    measure 1's force (for positions, whose means over the halves are the chords' slopes, it is the h-step second
    difference). Exact for a quantity linear in time.

    Args:
        values: Shape: (T + 2h, ...).
        dt: Grid step in s.
        step: h in grid steps.

    Returns:
        Shape: (T, ...).
    """
    area = np.concatenate([np.zeros_like(values[:1]), np.cumsum(0.5 * (values[1:] + values[:-1]), axis=0)])
    ahead, behind = area[2 * step :] - area[step:-step], area[step:-step] - area[: -2 * step]
    return (ahead - behind) / (step * step * dt)


def support_points(humanoid: Humanoid, qpos: np.ndarray) -> np.ndarray:
    """The lowest surface point over each collision support point (box corner, capsule end, sphere centre, lowered
    by its radius) of every body per frame, world, m.

    Args:
        qpos: Shape: (T, nq).

    Returns:
        Shape: (T, B * 8, 3); boxes give 8 points, capsules 2 and spheres 1, repeated to 8 (:class:`BodyGeometry`).
    """
    from common.maths.rotations import quat_rotate

    m, geometry = humanoid.model, BodyGeometry(humanoid)
    data = mujoco.MjData(m)
    out = np.empty((len(qpos), humanoid.num_bodies, 8, 3))
    for k, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(m, data)
        rot = np.repeat(data.xquat[1:, None], 8, axis=1)
        out[k] = data.xpos[1:, None] + quat_rotate(rot, geometry.points)
    out[..., 2] -= geometry.radius[:, None]
    return out.reshape(len(qpos), -1, 3)


def pyramid(friction: float, edges: int = PYRAMID_EDGES) -> np.ndarray:
    """Edge directions of a friction pyramid that holds the cone |f_h| <= mu f_z (normal +z).

    The polygon of the tangential parts circumscribes the circle of radius mu: its vertices lie mu / cos(pi / n) out,
    at angles 2 pi j / n.

    Returns:
        Shape: (n, 3), each with unit normal part.
    """
    angle = 2.0 * np.pi * np.arange(edges) / edges
    reach = friction / np.cos(np.pi / edges)
    return np.stack([reach * np.cos(angle), reach * np.sin(angle), np.ones(edges)], axis=1)


def nnls(a: np.ndarray, b: np.ndarray, max_iterations: int | None = None) -> np.ndarray:
    """min_x |a x - b| subject to x >= 0, by Lawson and Hanson's active-set method (Solving Least Squares Problems,
    1974, ch. 23).

    Args:
        a: Shape: (m, n).
        b: Shape: (m,).
        max_iterations: Outer iterations before giving up (default 3 n); the last iterate is returned.

    Returns:
        x of shape (n,), x >= 0; at the solution the gradient a^T (b - a x) is <= 0 where x = 0 and 0 where x > 0.
    """
    rows, n = a.shape
    x, passive = np.zeros(n), np.zeros(n, dtype=bool)
    tol = 1e-12 * max(1.0, float(np.abs(a).sum(axis=0).max() * np.abs(b).sum()))
    for _ in range(3 * n if max_iterations is None else max_iterations):
        gradient = a.T @ (b - a @ x)
        gradient[passive] = -np.inf
        j = int(np.argmax(gradient))
        if gradient[j] <= tol:
            break
        passive[j] = True
        while True:
            z = np.zeros(n)
            z[passive] = np.linalg.lstsq(a[:, passive], b, rcond=None)[0]
            if np.all(z[passive] > 0.0):
                x = z
                break
            blocking = passive & (z <= 0.0)
            alpha = np.min(x[blocking] / (x[blocking] - z[blocking]))
            x = x + alpha * (z - x)
            passive &= x > tol
            x[~passive] = 0.0
            if not passive.any():
                break
    return x


def contact_wrench_residual(force: np.ndarray, moment: np.ndarray, com: np.ndarray, points: np.ndarray,
                            friction: float, weight: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """What floor contact forces at ``points`` cannot give of a net force and a moment about the CoM.

    The forces are non-negative combinations of each point's :func:`pyramid` edges, fitted by :func:`nnls` to the
    wrench in body-weight units, the force rows weighted :data:`FORCE_PRIORITY` (see measure 3).

    Args:
        force: Net external force, world. Shape: (3,), N.
        moment: Moment about the CoM (dL/dt), world. Shape: (3,), N m.
        com: Centre of mass. Shape: (3,), m.
        points: Contact points on the floor. Shape: (P, 3), m; P may be 0.
        friction: mu.
        weight: m |g| in N.

    Returns:
        The force left (3,) in body weights and the moment left (3,) in body-weight metres.
    """
    want = np.concatenate([FORCE_PRIORITY * force, moment]) / weight
    if len(points) == 0:
        return force / weight, moment / weight
    edges = pyramid(friction)
    arms = points - com
    columns = np.concatenate([np.broadcast_to(edges, (len(points), *edges.shape)),
                              np.cross(arms[:, None, :], edges[None, :, :])], axis=2).reshape(-1, 6)  # fmt: skip
    columns[:, :3] *= FORCE_PRIORITY
    left = want - columns.T @ nnls(columns.T, want)
    return left[:3] / FORCE_PRIORITY, left[3:]


def moment_residuals(humanoid: Humanoid, qpos: np.ndarray, qvel: np.ndarray, force: np.ndarray, com: np.ndarray,
                     dt: float, step: int, tolerance: float,
                     friction: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Measure 3 for frames h..h+T-1: dL/dt (T, 3) in N m and its residual (T, 3) in body-weight metres.

    Args:
        qpos: Shape: (T + 2h, nq).
        qvel: Shape: (T + 2h, nv).
        force: Measure 1's F of frames h..h+T-1. Shape: (T, 3), N.
        com: Centre of mass of every frame. Shape: (T + 2h, 3), m.
    """
    rate = triangle_rate(angular_momentum(humanoid, qpos, qvel), dt, step)
    points = support_points(humanoid, qpos)
    weight = body_weight(humanoid)
    left = np.empty_like(rate)
    for j in range(len(rate)):
        near = points[j : j + 2 * step + 1].reshape(-1, 3)
        near = near[near[:, 2] <= tolerance]
        floor = np.unique(np.round(near[:, :2], 4), axis=0)
        floor = np.concatenate([floor, np.zeros((len(floor), 1))], axis=1)
        left[j] = contact_wrench_residual(force[j], rate[j], com[j + step], floor, friction, weight)[1]
    return rate, left


def measure(humanoid: Humanoid, qpos: np.ndarray, qvel: np.ndarray, dt: float, step: int = MIN_STEP,
            tolerance: float = CONTACT_TOLERANCE, friction: float | None = None) -> FrameFeasibility:  # fmt: skip
    """The three measures for frames h..h+T-1 of a reference given on a grid of step dt.

    Args:
        humanoid: The model.
        qpos: Reference generalised positions at t_k = k dt, h extra frames on each side. Shape: (T + 2h, nq).
        qvel: The matching generalised velocities (as the library builds them). Shape: (T + 2h, nv).
        dt: Grid step in s.
        step: h, the differencing step in grid steps (see the module docstring).
        tolerance: Contact tolerance in m (see the module docstring).
        friction: Sliding friction coefficient mu; None takes :func:`model_friction`.
    """
    if step < 1 or len(qpos) < 2 * step + 1 or qpos.shape[0] != qvel.shape[0]:
        raise ValueError(f"need >= {2 * step + 1} frames of matching qpos and qvel, got {qpos.shape}, {qvel.shape}")
    mu = model_friction(humanoid) if friction is None else friction
    weight = body_weight(humanoid)
    com, clearance = com_and_clearance(humanoid, qpos)
    force, contact = external_force(humanoid, com, clearance, dt, step, tolerance)
    inner = slice(step, len(qpos) - step)
    qacc = position_second_difference(humanoid, qpos, step, dt)
    qfrc = inverse_dynamics(humanoid, qpos[inner], qvel[inner], qacc)
    qfrc_free = inverse_dynamics(humanoid, qpos[inner], qvel[inner], qacc, constraints=False)
    torque = qfrc[:, humanoid.hinge_dof]
    rate, moment_left = moment_residuals(humanoid, qpos, qvel, force, com, dt, step, tolerance, mu)
    return FrameFeasibility(
        force=force, contact=contact, clearance=clearance[inner], residual=residual_force(force, contact, mu) / weight,
        hinge_torque=torque, hinge_ratio=hinge_ratios(humanoid, torque),
        root_residual=np.linalg.norm(qfrc[:, 0:3], axis=-1) / weight,
        hinge_ratio_unconstrained=hinge_ratios(humanoid, qfrc_free[:, humanoid.hinge_dof]),
        range_excess=range_excess(humanoid, qpos[inner]), moment_rate=rate, moment_residual=moment_left,
    )  # fmt: skip


def clip_reference(humanoid: Humanoid, library: MotionLibrary, clip: int, step: int) -> tuple[np.ndarray, np.ndarray]:
    """A clip's qpos and qvel with h frames on each side of the measured ones.

    One-shot clips: all their frames (frames h..N-1-h are measured). Looping clips of n frames per cycle: stored
    frames 0..n and frames n+1..n+2h-1 from the library's continuation (frames h..h+n-1, one cycle, are measured).
    The continuation carries whole turns of the hinge angles on (dance_a, cartwheel, crawl and sideflip come back 2 pi
    away: :meth:`MotionLibrary._cycle_wind`) but not a seam on the other Euler branch (spinkick, backflip): each
    continued frame's hinge angles are re-chosen nearest the previous frame's, the same joint rotations.

    Returns:
        qpos (T + 2h, nq) and qvel (T + 2h, nv).
    """
    start, count = library.start[clip], library.num_frames[clip]
    frames = library.frames[np.arange(start, start + count)]
    if not library.loop[clip]:
        return frames.qpos, frames.qvel
    extra = np.arange(count, count + 2 * step - 1)
    after = library.query(np.full(len(extra), clip), extra * library.dt)
    qpos = np.concatenate([frames.qpos, after.qpos])
    for k in range(count, len(qpos)):
        rot = hinges_to_joint_rotations(humanoid, qpos[k : k + 1])
        qpos[k, humanoid.hinge_qpos] = joint_rotations_to_hinges(humanoid, rot, qpos[k - 1 : k])[0]
    return qpos, np.concatenate([frames.qvel, after.qvel])


def summarise(humanoid: Humanoid, frames: FrameFeasibility, first_frame: int) -> dict[str, Any]:
    """Per-clip numbers: residual force, inverse-dynamics root residual, hinge torques against their limits.

    The worst joint is the hinge over its limit in the most frames (ties, and clips with none over, go to the
    highest 95th-percentile ratio). ``first_frame`` is the clip frame of ``frames``' first row.
    """
    names = [mujoco.mj_id2name(humanoid.model, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in range(humanoid.nu)]
    over, p95, worst = _hinge_summary(frames.hinge_ratio)
    over_free, p95_free, worst_free = _hinge_summary(frames.hinge_ratio_unconstrained)
    beyond = frames.range_excess.max(axis=0)
    peak = int(np.argmax(frames.residual))
    moment = np.linalg.norm(frames.moment_residual, axis=-1)
    fits = frames.residual < FORCE_FITS  # frames whose force lies in the cone: the moment is all that is left
    fit_moment, fit_yaw = moment[fits], np.abs(frames.moment_residual[fits, 2])
    return {
        "frames": len(frames.residual),
        "residual_mean": float(frames.residual.mean()),
        "residual_p95": float(np.percentile(frames.residual, 95)),
        "residual_share_over": float(np.mean(frames.residual > RESIDUAL_THRESHOLD)),
        "residual_max": float(frames.residual[peak]),
        "residual_max_frame": first_frame + peak,
        "flight_share": float(np.mean(~frames.contact)),
        "clearance_min_m": float(frames.clearance.min()),
        "root_residual_mean": float(frames.root_residual.mean()),
        "root_residual_p95": float(np.percentile(frames.root_residual, 95)),
        "hinge_over_share": float(np.mean(over.any(axis=1))),
        "worst_joint": names[worst],
        "worst_joint_over_share": float(np.mean(over[:, worst])),
        "worst_joint_p95_ratio": float(p95[worst]),
        "hinge_p95_ratio": {n: float(r) for n, r in zip(names, p95, strict=True)},
        "unconstrained_hinge_over_share": float(np.mean(over_free.any(axis=1))),
        "unconstrained_worst_joint": names[worst_free],
        "unconstrained_worst_joint_p95_ratio": float(p95_free[worst_free]),
        "out_of_range_share": float(np.mean((frames.range_excess > 0.0).any(axis=1))),
        "out_of_range_joint": names[int(np.argmax(beyond))] if beyond.max() > 0.0 else None,
        "out_of_range_max_rad": float(beyond.max()),
        "moment_rate_mean": float(np.linalg.norm(frames.moment_rate, axis=-1).mean() / body_weight(humanoid)),
        "moment_residual_mean": float(moment.mean()),
        "force_fits_share": float(fits.mean()),
        "moment_residual_fit_mean": float(fit_moment.mean()) if fits.any() else None,
        "moment_residual_fit_p95": float(np.percentile(fit_moment, 95)) if fits.any() else None,
        "moment_residual_fit_share_over": float(np.mean(fit_moment > MOMENT_THRESHOLD)) if fits.any() else None,
        "yaw_residual_fit_mean": float(fit_yaw.mean()) if fits.any() else None,
        "yaw_residual_fit_p95": float(np.percentile(fit_yaw, 95)) if fits.any() else None,
    }


def _hinge_summary(ratio: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """(over the limit (T, nu), 95th-percentile ratio per hinge (nu,), the worst hinge) of ratios (T, nu)."""
    over = ratio > 1.0
    p95 = np.percentile(ratio, 95, axis=0)
    return over, p95, max(range(ratio.shape[1]), key=lambda a: (int(over[:, a].sum()), float(p95[a])))


def assess(humanoid: Humanoid, library: MotionLibrary, steps: Sequence[int], tolerance: float = CONTACT_TOLERANCE,
           friction: float | None = None) -> dict[str, dict[str, Any]]:  # fmt: skip
    """:func:`summarise` of every clip of a library by clip name, clip c differenced with step ``steps[c]``."""
    rows = {}
    for c, (name, step) in enumerate(zip(library.names, steps, strict=True)):
        qpos, qvel = clip_reference(humanoid, library, c, step)
        frames = measure(humanoid, qpos, qvel, library.dt, step, tolerance, friction)
        rows[name] = {"step": step, **summarise(humanoid, frames, step)}
    return rows


def table(rows: dict[str, dict[str, Any]]) -> str:
    """One line per clip; forces in body weights m g, torques as |torque| / limit."""
    lines = [f"{'clip':<15}{'frames':>6}{'h':>3}{'res mean':>9}{'res p95':>8}{'>0.1mg':>7}{'flight':>7}{'min z cm':>9}"
             f"{'root mean':>10}{'root p95':>9}{'hinge>lim':>10}  {'worst joint (p95 ratio)':<26}"
             f"{'unconstr.>lim':>13}  {'worst joint (p95 ratio)':<26}{'out of range':<30}{'dL/dt':>6}{'mom res':>8}"
             f"{'fits':>5}{'mom|fit':>8}{'>0.05':>6}{'yaw|fit':>8}{'yaw p95':>8}"]  # fmt: skip
    for name, r in rows.items():
        beyond = r["out_of_range_joint"]
        lines.append(
            f"{name:<15}{r['frames']:>6d}{r['step']:>3d}{r['residual_mean']:>9.3f}{r['residual_p95']:>8.3f}"
            f"{r['residual_share_over']:>7.0%}{r['flight_share']:>7.0%}{100 * r['clearance_min_m']:>9.1f}"
            f"{r['root_residual_mean']:>10.3f}{r['root_residual_p95']:>9.3f}{r['hinge_over_share']:>10.0%}"
            f"  {_joint_cell(r['worst_joint'], r['worst_joint_p95_ratio']):<26}"
            f"{r['unconstrained_hinge_over_share']:>13.0%}"
            f"  {_joint_cell(r['unconstrained_worst_joint'], r['unconstrained_worst_joint_p95_ratio']):<26}"
            + f"{r['out_of_range_share']:.0%}{_beyond_cell(beyond, r['out_of_range_max_rad']):<26}"
            f"{r['moment_rate_mean']:>6.3f}{r['moment_residual_mean']:>8.3f}{r['force_fits_share']:>5.0%}"
            + _cells(r, ("moment_residual_fit_mean", 8, ".3f"), ("moment_residual_fit_share_over", 6, ".0%"),
                     ("yaw_residual_fit_mean", 8, ".3f"), ("yaw_residual_fit_p95", 8, ".3f"))  # fmt: skip
        )
    return "\n".join(lines)


def _cells(row: dict[str, Any], *cells: tuple[str, int, str]) -> str:
    """Right-aligned cells (key, width, format) of a row, '-' where the value is None."""
    return "".join(f"{'-' if row[k] is None else format(row[k], spec):>{width}}" for k, width, spec in cells)


def _beyond_cell(joint: str | None, rad: float) -> str:
    return f" {joint} by {rad:.2f} rad" if joint else ""


def _joint_cell(name: str, ratio: float) -> str:
    return f"{name} ({ratio:.2f})"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m studies.samcon.feasibility", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--motions", nargs="+", default=["all"],
                        help="clips to measure: bundled clip names (walk run ...), 'all' (the 20 bundled "
                             "clips), 'long', DeepMimic .txt files, folders of them or clip packs .h5 "
                             "(default: all)")  # fmt: skip
    parser.add_argument(
        "--out",
        default=None,
        metavar="FILE.json",
        help="write the per-clip numbers there (atomically); without it the table is only printed",
    )
    parser.add_argument("--contact-tolerance", type=float, default=CONTACT_TOLERANCE, metavar="METRES",
                        help="a body touches the floor when its collision geom's lowest point is this close to "
                             f"z = 0 or below it (default: {CONTACT_TOLERANCE} m)")  # fmt: skip
    parser.add_argument("--friction", type=float, default=None, metavar="MU",
                        help="sliding friction coefficient of the floor contacts (default: the model's, the larger "
                             "of the floor's and the body geom's geom_friction, as MuJoCo mixes them)")  # fmt: skip
    parser.add_argument("--step", type=int, default=None, metavar="H",
                        help="differencing step in control steps for every clip (default: per clip, the source "
                             f"keyframe spacing rounded up, at least {MIN_STEP})")  # fmt: skip
    return parser


def main(argv: Sequence[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    try:
        if not args.contact_tolerance >= 0.0:
            raise ValueError(f"--contact-tolerance must be >= 0 m, got {args.contact_tolerance}")
        if args.friction is not None and not args.friction >= 0.0:
            raise ValueError(f"--friction must be >= 0, got {args.friction}")
        if args.step is not None and args.step < 1:
            raise ValueError(f"--step must be >= 1, got {args.step}")
        humanoid = Humanoid()
        # resolve_clips + from_clips is load_motions without its dataset branch: h needs the source keyframe times.
        clips = resolve_clips(list(args.motions))
        library = MotionLibrary.from_clips(clips, humanoid)
    except (ValueError, FileNotFoundError) as e:  # MotionFormatError is a ValueError
        sys.exit(f"error: {e}")
    steps = [args.step or accel_step(1.0 / c.source_fps, library.dt) for c in clips]
    friction = model_friction(humanoid) if args.friction is None else args.friction
    rows = assess(humanoid, library, steps, args.contact_tolerance, friction)
    print(f"contact tolerance {args.contact_tolerance} m, friction mu = {friction:g}, mass {total_mass(humanoid):.1f} "
          f"kg, dt = {library.dt:.5f} s, h = differencing step; forces in body weights m g, moments (dL/dt and "
          f"its residual) in body-weight metres; fits: frames whose force is in the cone (residual < {FORCE_FITS}), "
          f"over which mom|fit, >{MOMENT_THRESHOLD} and yaw|fit (the vertical part) are taken")  # fmt: skip
    print(table(rows))
    if args.out is not None:
        out = {"contact_tolerance_m": args.contact_tolerance, "friction": friction,
               "friction_source": "model" if args.friction is None else "--friction", "mass_kg": total_mass(humanoid),
               "gravity": [float(g) for g in humanoid.model.opt.gravity], "dt": library.dt,
               "residual_threshold_body_weights": RESIDUAL_THRESHOLD, "force_fits_body_weights": FORCE_FITS,
               "moment_threshold_body_weight_metres": MOMENT_THRESHOLD, "force_priority": FORCE_PRIORITY,
               "pyramid_edges": PYRAMID_EDGES, "clips": rows}  # fmt: skip
        with atomic_output(args.out) as tmp:
            tmp.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
        print(f"written: {args.out}")


if __name__ == "__main__":
    main()
