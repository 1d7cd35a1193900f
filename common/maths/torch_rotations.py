"""Differentiable rotation maths in torch, mirroring ``common.maths.rotations`` for the learners.

Same conventions as ``common.maths.rotations``: quaternions ``(w, x, y, z)`` on the last axis, Hamilton
product, active rotation ``q * (0, v) * conj(q)`` (body-local -> world), Z up, heading about +Z
measured on the rotated +X axis. Every function broadcasts over leading dimensions and works on the
device and dtype of its input.

The exp/log maps and the geodesic angle use ``torch.where`` branches whose unused side is fed a
safe value, so gradients stay finite at the identity / zero rotation vector (``sqrt`` and division
by ``|v|`` there would otherwise turn the backward pass into NaN through ``0 * inf``).
"""

from __future__ import annotations

import torch
from torch import Tensor

# Below this angle (rad) the exp/log maps switch to Taylor series; the first dropped terms are
# O(1e-18) relative, so the switch is invisible even in float64.
_SMALL_ANGLE = 1e-3
# Lower bound on norms that are divided by; torch code cannot raise on data without a device sync.
_EPS = 1e-12


def quat_mul(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product ``a * b``: apply ``b`` first, then ``a``.

    Args:
        a: Quaternions, shape (..., 4).
        b: Quaternions, shape (..., 4).

    Returns:
        Products, shape broadcast(...) + (4,).
    """
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


def quat_conj(q: Tensor) -> Tensor:
    """Conjugate ``(w, -x, -y, -z)``; the inverse of a unit quaternion. Shape (..., 4) -> (..., 4)."""
    return torch.cat([q[..., :1], -q[..., 1:]], dim=-1)


def quat_normalize(q: Tensor) -> Tensor:
    """Scale quaternions to unit length, shape (..., 4) -> (..., 4).

    Unlike the numpy version this does not raise on zero length (that would need a device sync);
    the norm is clamped to a tiny epsilon instead.
    """
    return q / torch.linalg.vector_norm(q, dim=-1, keepdim=True).clamp_min(_EPS)


def quat_rotate(q: Tensor, v: Tensor) -> Tensor:
    """Rotate vectors by unit quaternions (body-local -> world).

    Args:
        q: Unit quaternions, shape (..., 4).
        v: Vectors, shape (..., 3).

    Returns:
        Rotated vectors, shape broadcast(...) + (3,).
    """
    w, u = q[..., :1], q[..., 1:]
    u, v = torch.broadcast_tensors(u, v)
    # q v q* = v + w t + u x t with t = 2 u x v.
    t = 2.0 * cross(u, v)
    return v + w * t + cross(u, t)


def cross(a: Tensor, b: Tensor) -> Tensor:
    """Cross product over the last axis, (..., 3) x (..., 3) -> (..., 3).

    Component-wise: on small CPU batches this is several times faster than ``torch.linalg.cross``.
    """
    ax, ay, az = a.unbind(-1)
    bx, by, bz = b.unbind(-1)
    return torch.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], dim=-1)


def rows_times_matrix(v: Tensor, m: Tensor) -> Tensor:
    """Row vectors times 3 x 3 matrices, ``v @ m`` with broadcasting: (..., 3) and (..., 3, 3) -> (..., 3).

    One broadcast multiply and sum: for millions of tiny products this beats batched ``matmul`` on the CPU.
    """
    return (v[..., :, None] * m).sum(dim=-2)


def quat_rotate_inv(q: Tensor, v: Tensor) -> Tensor:
    """Rotate vectors by the inverse of unit quaternions (world -> body-local). Shapes as quat_rotate."""
    return quat_rotate(quat_conj(q), v)


def quat_from_rotvec(r: Tensor) -> Tensor:
    """Exponential map: rotation vector ``angle * unit_axis`` -> unit quaternion, (..., 3) -> (..., 4).

    Finite values and gradients at ``r = 0`` (the Jacobian of the vector part there is ``I / 2``).
    """
    theta2 = (r * r).sum(dim=-1, keepdim=True)
    small = theta2 < _SMALL_ANGLE**2
    theta = torch.sqrt(torch.where(small, torch.ones_like(theta2), theta2))
    # Taylor: cos(t/2) = 1 - t^2/8 + t^4/384, sin(t/2)/t = 1/2 - t^2/48 + t^4/3840.
    w = torch.where(small, 1.0 - theta2 / 8.0 + theta2**2 / 384.0, torch.cos(0.5 * theta))
    k = torch.where(small, 0.5 - theta2 / 48.0 + theta2**2 / 3840.0, torch.sin(0.5 * theta) / theta)
    return torch.cat([w, k * r], dim=-1)


def quat_to_rotvec(q: Tensor) -> Tensor:
    """Logarithm map: quaternion -> shortest rotation vector (norm in [0, pi]), (..., 4) -> (..., 3).

    ``q`` and ``-q`` give the same result and the length of ``q`` does not matter. Finite values and
    gradients at the identity (the Jacobian with respect to the vector part there is ``2 I``).
    """
    q = torch.where(q[..., :1] < 0.0, -q, q)
    w, u = q[..., :1], q[..., 1:]
    n2 = (u * u).sum(dim=-1, keepdim=True)
    small = n2 < (_SMALL_ANGLE * w) ** 2
    n = torch.sqrt(torch.where(small, torch.ones_like(n2), n2))
    ws = torch.where(small, w, torch.ones_like(w))
    # angle / |u| = 2 atan2(|u|, w) / |u| = (2 / w)(1 - s/3 + s^2/5) with s = |u|^2 / w^2.
    s = n2 / ws**2
    k = torch.where(small, 2.0 / ws * (1.0 - s / 3.0 + s * s / 5.0), 2.0 * torch.atan2(n, w) / n)
    return k * u


def quat_geodesic_angle(a: Tensor, b: Tensor) -> Tensor:
    """Angle in [0, pi] of ``a * inv(b)`` as ``2 atan2(|vec|, |w|)``, shape (..., 4) -> (...).

    Sign-invariant in ``a`` and ``b``. At zero angle the gradient is the zero subgradient, not NaN.
    """
    d = quat_mul(a, quat_conj(b))
    n2 = (d[..., 1:] ** 2).sum(dim=-1)
    nonzero = n2 > 0.0
    n = torch.where(nonzero, torch.sqrt(torch.where(nonzero, n2, torch.ones_like(n2))), torch.zeros_like(n2))
    return 2.0 * torch.atan2(n, d[..., 0].abs())


def quat_to_matrix(q: Tensor) -> Tensor:
    """Rotation matrices, shape (..., 4) -> (..., 3, 3); non-unit input is treated as normalised."""
    w, x, y, z = q.unbind(-1)
    s = 2.0 / (q * q).sum(dim=-1)
    rows = [
        [1.0 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)],
        [s * (x * y + w * z), 1.0 - s * (x * x + z * z), s * (y * z - w * x)],
        [s * (x * z - w * y), s * (y * z + w * x), 1.0 - s * (x * x + y * y)],
    ]
    return torch.stack([torch.stack(row, dim=-1) for row in rows], dim=-2)


def quat_to_two_axis(q: Tensor) -> Tensor:
    """Two-axis (6D) encoding: the first two matrix COLUMNS ``[R[:, 0], R[:, 1]]``, (..., 4) -> (..., 6)."""
    m = quat_to_matrix(q)
    return torch.cat([m[..., :, 0], m[..., :, 1]], dim=-1)


def two_axis_to_matrix(x: Tensor) -> Tensor:
    """Gram-Schmidt the two-axis encoding into rotation matrices, (..., 6) -> (..., 3, 3).

    Column 0 is the normalised first half, column 1 the second half made orthonormal to it, column 2
    their cross product. Degenerate input is not detected (norms are clamped to a tiny epsilon).
    """
    a, b = x[..., :3], x[..., 3:]
    c0 = a / torch.linalg.vector_norm(a, dim=-1, keepdim=True).clamp_min(_EPS)
    b = b - (c0 * b).sum(dim=-1, keepdim=True) * c0
    c1 = b / torch.linalg.vector_norm(b, dim=-1, keepdim=True).clamp_min(_EPS)
    return torch.stack([c0, c1, cross(c0, c1)], dim=-1)


def quat_yaw(q: Tensor) -> Tensor:
    """Heading about +Z: ``atan2(y, x)`` of the rotated +X axis, (..., 4) -> (...), in [-pi, pi].

    Undefined (and with NaN gradient) when the rotated +X axis points straight up or down.
    """
    w, x, y, z = q.unbind(-1)
    # Rotated +X is proportional to (w^2 + x^2 - y^2 - z^2, 2(xy + wz), 2(xz - wy)).
    return torch.atan2(2.0 * (x * y + w * z), w * w + x * x - y * y - z * z)


def quat_from_yaw(yaw: Tensor) -> Tensor:
    """Rotations by ``yaw`` about +Z, shape (...) -> (..., 4)."""
    half = 0.5 * yaw
    zero = torch.zeros_like(half)
    return torch.stack([torch.cos(half), zero, zero, torch.sin(half)], dim=-1)


def angular_velocity(q0: Tensor, q1: Tensor, dt: float | Tensor) -> Tensor:
    """World-frame angular velocity taking ``q0`` to ``q1`` in ``dt``: ``rotvec(q1 * inv(q0)) / dt``.

    Args:
        q0: Orientations at the start, shape (..., 4).
        q1: Orientations at the end, shape (..., 4).
        dt: Time step (s), a float or a tensor of shape (...).

    Returns:
        Angular velocities (rad/s) along the shorter path, shape broadcast(...) + (3,).
    """
    # The log map ignores quaternion length, so conj(q0) serves as inv(q0) even for non-unit q0.
    rotvec = quat_to_rotvec(quat_mul(q1, quat_conj(q0)))
    if isinstance(dt, Tensor):
        dt = dt.unsqueeze(-1)
    return rotvec / dt
