"""Probe (not a project measure): the centre of pressure each reference needs, against the support of the bodies that
touch the floor in the reference, and the vertical moment it needs about that point.

    python results/session23-samcon/scratch/cop.py CLIP...   (or: all)

The whole-body wrench the reference needs is the free joint's generalised force of ``mj_inverse`` with contacts and
limits off (samcon.feasibility's measure (c)): F (world) and the torque about the root origin o (MuJoCo gives it in
the root frame; rotated to world). All floor contacts lie on z = 0, so the centre of pressure p solves
(p - o) x F + tau_z e_z = tau: p_x = o_x - (tau_y + o_z F_x) / F_z, p_y = o_y + (tau_x - o_z F_y) / F_z (static:
p is under the centre of mass; checked against the centroidal angular momentum, MuJoCo's subtree_angmom, differenced).
The support is the convex hull of the collision-geom points within 3 cm of the floor over the frame's differencing
window (the box feet's corners, the spheres' and capsule ends' lowest points). Printed per clip: share of frames
with F_z > 0 and some body touching, share whose p lies > 2 cm outside the support, the mean and 95th percentile of
that distance, and F_z d / c_z in body weights (the horizontal force at the centre of mass's height that would move
p by d); and |tau_z|, the vertical moment about p, against mu F_z R (R: the farthest support point from p), an upper
bound of what friction at the support points gives (condim 3: no torsional friction).
"""
import sys

import mujoco
import numpy as np

from common.character.humanoid import BodyGeometry, Humanoid
from common.maths.rotations import quat_rotate
from common.motion.dataset import resolve_clips
from common.motion.library import MotionLibrary
from samcon import feasibility as fz

hum = Humanoid()
m = hum.model
clips = resolve_clips(sys.argv[1:] or ["all"])
lib = MotionLibrary.from_clips(clips, hum)
geo = BodyGeometry(hum)
W = fz.body_weight(hum)
mu = fz.model_friction(hum)


def support(qpos, tol):
    d = mujoco.MjData(m)
    out = []
    for q in qpos:
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        pts = []
        for b in range(hum.num_bodies):
            w = quat_rotate(np.repeat(d.xquat[1 + b : 2 + b], 8, 0), geo.points[b]) + d.xpos[1 + b]
            pts.append(w[w[:, 2] - geo.radius[b] <= tol, :2])
        out.append(np.concatenate(pts))
    return out


def hull(points):
    P = sorted(set(map(tuple, np.round(points, 9))))
    if len(P) <= 2:
        return np.array(P)

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower, upper = [], []
    for p in P:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    for p in reversed(P):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1])


def outside(p, points):
    V = hull(points)
    n = len(V)
    if n >= 3 and all((V[(i + 1) % n][0] - V[i][0]) * (p[1] - V[i][1])
                      - (V[(i + 1) % n][1] - V[i][1]) * (p[0] - V[i][0]) >= 0 for i in range(n)):
        return 0.0
    segs = [(V[i], V[(i + 1) % n]) for i in range(n)] if n > 2 else [(V[0], V[-1])]
    best = np.inf
    for a, b in segs:
        ab = b - a
        t = 0.0 if ab @ ab == 0 else np.clip((p - a) @ ab / (ab @ ab), 0, 1)
        best = min(best, np.linalg.norm(p - (a + t * ab)))
    return best


for c, clip in enumerate(clips):
    step = fz.accel_step(1.0 / clip.source_fps, lib.dt)
    qpos, qvel = fz.clip_reference(hum, lib, c, step)
    inner = slice(step, len(qpos) - step)
    qacc = fz.position_second_difference(hum, qpos, step, lib.dt)
    qf = fz.inverse_dynamics(hum, qpos[inner], qvel[inner], qacc, constraints=False)
    sup = support(qpos, fz.CONTACT_TOLERANCE)
    com, _ = fz.com_and_clearance(hum, qpos)
    d = mujoco.MjData(m)
    dist, force, yaw, ratio = [], [], [], []
    for k in range(len(qf)):
        d.qpos[:] = qpos[inner][k]
        mujoco.mj_kinematics(m, d)
        o, R = d.xpos[1].copy(), d.xmat[1].reshape(3, 3)
        F, tau = qf[k, :3], R @ qf[k, 3:6]
        pts = np.concatenate(sup[k : k + 2 * step + 1])
        if F[2] <= 0.05 * W or len(pts) == 0:
            continue
        p = np.array([o[0] - (tau[1] + o[2] * F[0]) / F[2], o[1] + (tau[0] - o[2] * F[1]) / F[2], 0.0])
        dd = outside(p[:2], pts)
        dist.append(dd)
        force.append(F[2] * dd / com[inner][k][2] / W)
        tz = abs((tau - np.cross(p - o, F))[2])
        yaw.append(tz)
        ratio.append(tz / (mu * F[2] * np.max(np.linalg.norm(pts - p[:2], axis=1))))
    dist, force, yaw, ratio = map(np.array, (dist, force, yaw, ratio))
    print(f"{clip.name:15s} contact {len(dist) / len(qf):4.0%} p out > 2 cm {np.mean(dist > 0.02):4.0%} "
          f"mean {100 * dist.mean():6.1f} p95 {100 * np.percentile(dist, 95):6.1f} cm; F_z d / c_z mean "
          f"{force.mean():.3f} p95 {force.mean() if False else np.percentile(force, 95):.3f} bw; |tau_z| mean "
          f"{yaw.mean():5.1f} p95 {np.percentile(yaw, 95):5.1f} N m, over mu F_z R in {np.mean(ratio > 1):.0%}")
