"""Rotation maths in numpy: the project's single source of truth for quaternion conventions.

Conventions used everywhere in the project:

* Quaternions are ``(w, x, y, z)`` on the last axis (size 4) and multiply with the Hamilton product.
* Rotating ``v`` by ``q`` is the active rotation ``q * (0, v) * conj(q)``: it maps body-local vectors
  to world vectors, and ``quat_to_matrix(q) @ v`` gives the same result.
* Z is up. Heading (yaw) is the angle about +Z of the rotated +X axis, ``atan2(y, x)``, since the
  character faces +X.
* Every function broadcasts over leading dimensions. Float32 inputs stay float32 where natural;
  everything else is computed in float64.

``common.maths.torch_rotations`` mirrors the subset of this module that the learners need.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.floating]

# Norms below this are treated as zero (a quaternion or axis with no usable direction).
_ZERO_NORM = 1e-12
# Below this angle (rad) the exp/log maps switch to Taylor series; the first dropped terms are
# O(1e-18) relative, so the switch is invisible even in float64.
_SMALL_ANGLE = 1e-3


def _float_dtype(*xs: ArrayLike) -> np.dtype:
    """Common floating dtype of the inputs; Python scalars do not force float64 (float32 stays)."""
    if all(type(x) is np.ndarray and x.dtype == np.float64 for x in xs):
        return np.dtype(np.float64)  # the common case, without the general type promotion's overhead
    arrays = [np.asarray(x) for x in xs if not isinstance(x, (int, float))]
    dtype = np.result_type(*arrays) if arrays else np.dtype(np.float64)
    return dtype if np.issubdtype(dtype, np.floating) else np.dtype(np.float64)


def _arr(x: ArrayLike, *others: ArrayLike) -> Array:
    return np.asarray(x, dtype=_float_dtype(x, *others))


def cross(a: Array, b: Array) -> Array:
    """Cross product over the last axis, (..., 3) x (..., 3) -> (..., 3).

    Written out by component into one output array: ``np.cross`` (and stacking the components) costs several times
    more on the small batched arrays of the gym's hot path, where per-call overhead dominates.
    """
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), dtype=np.result_type(a, b))
    np.subtract(a1 * b2, a2 * b1, out=out[..., 0])
    np.subtract(a2 * b0, a0 * b2, out=out[..., 1])
    np.subtract(a0 * b1, a1 * b0, out=out[..., 2])
    return out


def quat_mul(a: ArrayLike, b: ArrayLike) -> Array:
    """Hamilton product ``a * b``: apply ``b`` first, then ``a``.

    Args:
        a: Quaternions, shape (..., 4).
        b: Quaternions, shape (..., 4).

    Returns:
        Products, shape broadcast(...) + (4,).
    """
    a, b = _arr(a, b), _arr(b, a)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    # (aw, av)(bw, bv) = (aw bw - av.bv, aw bv + bw av + av x bv), by component into one output array.
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), dtype=a.dtype)
    out[..., 0] = aw * bw - ax * bx - ay * by - az * bz
    out[..., 1] = aw * bx + ax * bw + ay * bz - az * by
    out[..., 2] = aw * by - ax * bz + ay * bw + az * bx
    out[..., 3] = aw * bz + ax * by - ay * bx + az * bw
    return out


def quat_conj(q: ArrayLike) -> Array:
    """Conjugate ``(w, -x, -y, -z)``; the inverse of a unit quaternion. Shape (..., 4) -> (..., 4)."""
    q = _arr(q)
    # Negating the whole array and restoring w is contiguous work; an in-place update of the strided (..., 1:)
    # view is several times slower in numpy.
    out = -q
    out[..., 0] = q[..., 0]
    return out


def _norm_checked(q: Array) -> Array:
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm < _ZERO_NORM):
        raise ValueError("cannot normalise a (near) zero-length vector or quaternion")
    return norm


def quat_inv(q: ArrayLike) -> Array:
    """Inverse ``conj(q) / |q|^2``, valid for non-unit quaternions. Shape (..., 4) -> (..., 4).

    Raises:
        ValueError: If any quaternion has (near) zero length.
    """
    q = _arr(q)
    return quat_conj(q) / _norm_checked(q) ** 2


def quat_normalize(q: ArrayLike) -> Array:
    """Scale quaternions to unit length. Shape (..., 4) -> (..., 4).

    Raises:
        ValueError: If any quaternion has (near) zero length.
    """
    q = _arr(q)
    return q / _norm_checked(q)


def quat_identity(shape: int | tuple[int, ...] = ()) -> Array:
    """Identity quaternions ``(1, 0, 0, 0)`` of shape ``shape + (4,)`` (float64)."""
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    q = np.zeros((*shape, 4))
    q[..., 0] = 1.0
    return q


def quat_rotate(q: ArrayLike, v: ArrayLike) -> Array:
    """Rotate vectors by unit quaternions (body-local -> world).

    Args:
        q: Unit quaternions, shape (..., 4).
        v: Vectors, shape (..., 3).

    Returns:
        Rotated vectors, shape broadcast(...) + (3,).
    """
    q, v = _arr(q, v), _arr(v, q)
    w, u = q[..., :1], q[..., 1:]
    # q v q* = v + w t + u x t with t = 2 u x v: two cross products instead of a matrix.
    t = cross(u, v)
    t *= 2.0
    out = cross(u, t)
    out += v
    out += w * t
    return out


def quat_rotate_inv(q: ArrayLike, v: ArrayLike) -> Array:
    """Rotate vectors by the inverse of unit quaternions (world -> body-local). Shapes as quat_rotate."""
    return quat_rotate(quat_conj(q), v)


def quat_from_axis_angle(axis: ArrayLike, angle: ArrayLike) -> Array:
    """Quaternion rotating by ``angle`` (rad, right-handed) about ``axis``.

    Args:
        axis: Rotation axes, shape (..., 3); need not be unit length.
        angle: Angles, shape (...).

    Returns:
        Unit quaternions, shape broadcast(...) + (4,).

    Raises:
        ValueError: If an axis has (near) zero length.
    """
    axis, angle = _arr(axis, angle), _arr(angle, axis)
    axis = axis / _norm_checked(axis)
    half = 0.5 * angle[..., None]
    vec = np.sin(half) * axis
    return np.concatenate([np.broadcast_to(np.cos(half), (*vec.shape[:-1], 1)), vec], axis=-1)


def quat_from_rotvec(r: ArrayLike) -> Array:
    """Exponential map: rotation vector ``angle * unit_axis`` -> unit quaternion.

    Args:
        r: Rotation vectors, shape (..., 3).

    Returns:
        Unit quaternions, shape (..., 4); exact and finite for tiny or zero ``|r|``.
    """
    r = _arr(r)
    theta2 = np.sum(r * r, axis=-1, keepdims=True)
    small = theta2 < _SMALL_ANGLE**2
    theta = np.sqrt(np.where(small, 1.0, theta2))
    # Taylor: cos(t/2) = 1 - t^2/8 + t^4/384, sin(t/2)/t = 1/2 - t^2/48 + t^4/3840.
    w = np.where(small, 1.0 - theta2 / 8.0 + theta2**2 / 384.0, np.cos(0.5 * theta))
    k = np.where(small, 0.5 - theta2 / 48.0 + theta2**2 / 3840.0, np.sin(0.5 * theta) / theta)
    return np.concatenate([w, k * r], axis=-1).astype(r.dtype, copy=False)


def quat_to_rotvec(q: ArrayLike) -> Array:
    """Logarithm map: quaternion -> shortest rotation vector (``q`` and ``-q`` give the same result).

    Args:
        q: Quaternions, shape (..., 4); the result does not depend on their length.

    Returns:
        Rotation vectors ``angle * unit_axis`` with norm in [0, pi], shape (..., 3).
    """
    q = _arr(q)
    q = np.where(q[..., :1] < 0.0, -q, q)
    w, u = q[..., :1], q[..., 1:]
    n2 = np.sum(u * u, axis=-1, keepdims=True)
    small = n2 < (_SMALL_ANGLE * w) ** 2
    n = np.sqrt(np.where(small, 1.0, n2))
    ws = np.where(small, w, 1.0)
    # angle / |u| = 2 atan2(|u|, w) / |u| = (2 / w)(1 - s/3 + s^2/5) with s = |u|^2 / w^2.
    s = n2 / ws**2
    k = np.where(small, 2.0 / ws * (1.0 - s / 3.0 + s * s / 5.0), 2.0 * np.arctan2(n, w) / n)
    return k * u


def quat_geodesic_angle(a: ArrayLike, b: ArrayLike) -> Array:
    """Angle in [0, pi] of the relative rotation ``a * inv(b)``; invariant to the signs of a and b.

    Uses ``2 atan2(|vec|, |w|)``, which stays accurate near zero where ``arccos`` does not.

    Args:
        a: Quaternions, shape (..., 4).
        b: Quaternions, shape (..., 4).

    Returns:
        Angles (rad), shape broadcast(...).
    """
    d = quat_mul(a, quat_conj(b))
    return 2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0]))


def quat_slerp(q0: ArrayLike, q1: ArrayLike, t: ArrayLike) -> Array:
    """Spherical linear interpolation along the shorter arc.

    Args:
        q0: Start quaternions, shape (..., 4) (normalised internally).
        q1: End quaternions, shape (..., 4) (normalised internally).
        t: Interpolation parameters, shape (...); 0 gives q0, 1 gives q1 (up to sign).

    Returns:
        Unit quaternions, shape broadcast(...) + (4,). Nearly parallel pairs use normalised lerp.
    """
    q0, q1 = quat_normalize(_arr(q0, q1)), quat_normalize(_arr(q1, q0))
    t = np.asarray(t, dtype=q0.dtype)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0.0, -q1, q1)
    dot = np.abs(dot)
    near = dot > 1.0 - 1e-6
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_theta = np.where(near, 1.0, np.sin(theta))
    s0 = np.where(near, 1.0 - t, np.sin((1.0 - t) * theta) / sin_theta)
    s1 = np.where(near, t, np.sin(t * theta) / sin_theta)
    out = s0 * q0 + s1 * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def quat_to_matrix(q: ArrayLike) -> Array:
    """Rotation matrices, shape (..., 4) -> (..., 3, 3); non-unit input is treated as normalised."""
    q = _arr(q)
    w, x, y, z = np.moveaxis(q, -1, 0)
    s = 2.0 / np.sum(q * q, axis=-1)
    rows = [
        [1.0 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)],
        [s * (x * y + w * z), 1.0 - s * (x * x + z * z), s * (y * z - w * x)],
        [s * (x * z - w * y), s * (y * z + w * x), 1.0 - s * (x * x + y * y)],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2).astype(q.dtype, copy=False)


def matrix_to_quat(m: ArrayLike) -> Array:
    """Rotation matrices -> unit quaternions with ``w >= 0``, shape (..., 3, 3) -> (..., 4).

    Shepperd's method: ``K = 4 q q^T`` is linear in the matrix entries; the row of ``K`` with the
    largest diagonal entry is ``4 q_i q`` with ``|q_i| >= 1/2``, so normalising it is well conditioned.
    """
    m = _arr(m)
    r = [[m[..., i, j] for j in range(3)] for i in range(3)]
    tr = r[0][0] + r[1][1] + r[2][2]
    d = [1.0 + tr, 1.0 + 2.0 * r[0][0] - tr, 1.0 + 2.0 * r[1][1] - tr, 1.0 + 2.0 * r[2][2] - tr]
    wx, wy, wz = r[2][1] - r[1][2], r[0][2] - r[2][0], r[1][0] - r[0][1]
    xy, xz, yz = r[0][1] + r[1][0], r[0][2] + r[2][0], r[1][2] + r[2][1]
    k = np.stack(
        [
            np.stack([d[0], wx, wy, wz], axis=-1),
            np.stack([wx, d[1], xy, xz], axis=-1),
            np.stack([wy, xy, d[2], yz], axis=-1),
            np.stack([wz, xz, yz, d[3]], axis=-1),
        ],
        axis=-2,
    )
    best = np.argmax(np.stack(d, axis=-1), axis=-1)
    q = np.take_along_axis(k, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def quat_to_two_axis(q: ArrayLike) -> Array:
    """Two-axis (6D) encoding: the first two matrix COLUMNS, ``[R[:, 0], R[:, 1]]``. (..., 4) -> (..., 6).

    These are the body's +X and +Y axes expressed in the world frame (columns, not rows).
    """
    m = quat_to_matrix(q)
    return np.concatenate([m[..., :, 0], m[..., :, 1]], axis=-1)


def two_axis_to_matrix(x: ArrayLike) -> Array:
    """Gram-Schmidt the two-axis encoding into rotation matrices, (..., 6) -> (..., 3, 3).

    Column 0 is the normalised first half, column 1 the second half made orthonormal to it,
    column 2 their cross product. Inverts ``quat_to_two_axis`` on valid input.

    Raises:
        ValueError: If a half is (near) zero or the two halves are (near) parallel.
    """
    x = _arr(x)
    c0 = x[..., :3] / _norm_checked(x[..., :3])
    b = x[..., 3:]
    b = b - np.sum(c0 * b, axis=-1, keepdims=True) * c0
    c1 = b / _norm_checked(b)
    return np.stack([c0, c1, cross(c0, c1)], axis=-1)


def quat_fix_hemisphere(q: ArrayLike, axis: int = 0) -> Array:
    """Flip signs along a sequence so consecutive quaternions have non-negative dot products.

    Args:
        q: Quaternions, shape (..., 4), with the sequence along ``axis`` (not the last axis).
        axis: Sequence axis.

    Returns:
        A new array of the same shape; the first element of the sequence is unchanged.
    """
    q = np.moveaxis(_arr(q), axis, 0)
    dots = np.sum(q[1:] * q[:-1], axis=-1, keepdims=True)
    # Flipping element t by s_t = prod_{k<=t} sign(d_k) makes s_t s_{t-1} d_t = |d_t| >= 0.
    signs = np.cumprod(np.where(dots < 0.0, -1.0, 1.0), axis=0)
    out = np.concatenate([q[:1], signs.astype(q.dtype) * q[1:]], axis=0)
    return np.moveaxis(out, 0, axis)


def _axis_quat(angle: Array, index: int) -> Array:
    q = np.zeros((*angle.shape, 4), dtype=angle.dtype)
    q[..., 0] = np.cos(0.5 * angle)
    q[..., index] = np.sin(0.5 * angle)
    return q


def euler_xyz_to_quat(e: ArrayLike) -> Array:
    """Intrinsic XYZ Euler angles ``(a, b, c)`` -> ``qx(a) * qy(b) * qz(c)``, i.e. ``Rx @ Ry @ Rz``.

    This matches the model's spherical joints, which are nested hinges about x, then y, then z.
    Shape (..., 3) -> (..., 4).
    """
    e = _arr(e)
    return quat_mul(quat_mul(_axis_quat(e[..., 0], 1), _axis_quat(e[..., 1], 2)), _axis_quat(e[..., 2], 3))


def quat_to_euler_xyz(q: ArrayLike) -> Array:
    """Principal intrinsic XYZ Euler angles, (..., 4) -> (..., 3), with ``b`` in [-pi/2, pi/2].

    With ``R = Rx(a) Ry(b) Rz(c)``: ``a = atan2(-R12, R22)``; then ``M = Rx(-a) R = Ry(b) Rz(c)``
    gives ``b = atan2(R02, M22)`` and ``c = atan2(M10, M11)``. Solving ``c`` from the residual keeps
    the rotation exact near gimbal lock (``|b| -> pi/2``), where only ``a + c`` (b > 0) or ``c - a``
    (b < 0) is determined and ``a`` itself is arbitrary.
    """
    m = quat_to_matrix(q)
    a = np.arctan2(-m[..., 1, 2], m[..., 2, 2])
    ca, sa = np.cos(a), np.sin(a)
    b = np.arctan2(m[..., 0, 2], ca * m[..., 2, 2] - sa * m[..., 1, 2])
    c = np.arctan2(ca * m[..., 1, 0] + sa * m[..., 2, 0], ca * m[..., 1, 1] + sa * m[..., 2, 1])
    return np.stack([a, b, c], axis=-1)


def _nearest_branch(x: Array, ref: Array) -> Array:
    """Shift each component of ``x`` by a multiple of 2 pi to lie nearest ``ref``."""
    return x + 2.0 * np.pi * np.round((ref - x) / (2.0 * np.pi))


def quat_to_euler_xyz_continuous(q_seq: ArrayLike) -> Array:
    """Intrinsic XYZ Euler angles for a sequence, continuous in time, (T, ..., 4) -> (T, ..., 3).

    Frame 0 takes the principal solution. Every later frame picks, of the two equivalent
    solutions ``(a, b, c)`` and ``(a + pi, pi - b, c + pi)`` (each component shifted by multiples of
    2 pi towards the previous frame), the one nearest (L2) to the previous frame, so angles may
    leave [-pi, pi] and ``b`` may leave [-pi/2, pi/2]. Near gimbal lock (``|b| -> pi/2``) only
    ``a + c`` or ``a - c`` is determined, so ``a`` and ``c`` individually can still jump there.
    """
    principal = quat_to_euler_xyz(q_seq)
    out = np.empty_like(principal)
    out[0] = principal[0]
    for t in range(1, principal.shape[0]):
        out[t] = _euler_near(principal[t], out[t - 1])
    return out


def _euler_near(principal: Array, ref: Array) -> Array:
    alternative = principal + np.array([np.pi, 0.0, np.pi], dtype=principal.dtype)
    alternative[..., 1] = np.pi - principal[..., 1]
    e0 = _nearest_branch(principal, ref)
    e1 = _nearest_branch(alternative, ref)
    closer = np.sum((e1 - ref) ** 2, axis=-1, keepdims=True) < np.sum((e0 - ref) ** 2, axis=-1, keepdims=True)
    return np.where(closer, e1, e0)


def quat_to_euler_xyz_near(q: ArrayLike, ref: ArrayLike) -> Array:
    """Intrinsic XYZ Euler angles of ``q`` nearest (L2) to the angles ``ref``, (..., 4), (..., 3) -> (..., 3).

    Of the two solutions ``(a, b, c)`` and ``(a + pi, pi - b, c + pi)``, each shifted by multiples of 2 pi
    towards ``ref``, the closer one. Used for PD targets, which must lie near the joint's current angles: a
    target 2 pi away is the same rotation but would spin the hinge round.
    """
    return _euler_near(quat_to_euler_xyz(q), _arr(ref))


def quat_yaw(q: ArrayLike) -> Array:
    """Heading about +Z: ``atan2(y, x)`` of the rotated +X axis, (..., 4) -> (...), in [-pi, pi]."""
    q = _arr(q)
    w, x, y, z = np.moveaxis(q, -1, 0)
    # Rotated +X is proportional to (w^2 + x^2 - y^2 - z^2, 2(xy + wz), 2(xz - wy)).
    return np.arctan2(2.0 * (x * y + w * z), w * w + x * x - y * y - z * z)


def quat_from_yaw(yaw: ArrayLike) -> Array:
    """Rotations by ``yaw`` about +Z, shape (...) -> (..., 4)."""
    return _axis_quat(_arr(yaw), 3)


def quat_split_heading(q: ArrayLike) -> tuple[Array, Array]:
    """Split ``q = heading * tilt`` with ``heading`` about +Z and ``tilt`` having zero yaw.

    Args:
        q: Unit quaternions, shape (..., 4).

    Returns:
        ``(heading, tilt)``, each of shape (..., 4).
    """
    heading = quat_from_yaw(quat_yaw(q))
    return heading, quat_mul(quat_conj(heading), q)


def angular_velocity(q0: ArrayLike, q1: ArrayLike, dt: ArrayLike) -> Array:
    """World-frame angular velocity taking ``q0`` to ``q1`` in ``dt``: ``rotvec(q1 * inv(q0)) / dt``.

    Args:
        q0: Orientations at the start, shape (..., 4).
        q1: Orientations at the end, shape (..., 4).
        dt: Time steps (s), scalar or shape (...), cast to the quaternion dtype.

    Returns:
        Angular velocities (rad/s) along the shorter path, shape broadcast(...) + (3,).
    """
    rotvec = quat_to_rotvec(quat_mul(q1, quat_inv(q0)))
    return rotvec / np.asarray(dt, dtype=rotvec.dtype)[..., None]
