"""SuperTrack's ``Local()`` features of a character, in numpy (gym, PPO) and torch (SuperTrack's rollouts).

Everything is relative to the root body's transform (Fussell et al. 2021, section 4):
- ``pos``: inv(root_rot) (x_pos - root_pos)             (B, 3)
- ``vel``: inv(root_rot) x_vel                          (B, 3)
- ``rot``: TwoAxis(inv(root_rot) x_rot), the first two *columns* of the rotation matrix  (B, 6)
- ``angvel``: inv(root_rot) x_angvel                    (B, 3)
- ``height``: x_pos.z, height above the ground          (B,)
- ``up``: inv(root_rot) (0, 0, 1)                       (3,)

Both flavours use one layout (:data:`LOCAL_LAYOUT`), so a flat feature vector means the same in the gym and in
the learners; slices are reached by name through :func:`feature_slices`.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np
import torch

from common.maths import rotations as np_rot
from common.maths import torch_rotations as th_rot

# (name, values per body or None for a per-character feature, values)
LOCAL_LAYOUT: tuple[tuple[str, bool, int], ...] = (
    ("pos", True, 3),
    ("vel", True, 3),
    ("rot", True, 6),
    ("angvel", True, 3),
    ("height", True, 1),
    ("up", False, 3),
)


def local_size(num_bodies: int) -> int:
    return sum(n * (num_bodies if per_body else 1) for _, per_body, n in LOCAL_LAYOUT)


def feature_slices(num_bodies: int, prefix: str = "") -> dict[str, slice]:
    """Slices of each named feature in a flat ``Local()`` vector (optionally with a name prefix)."""
    out, start = {}, 0
    for name, per_body, n in LOCAL_LAYOUT:
        size = n * (num_bodies if per_body else 1)
        out[prefix + name] = slice(start, start + size)
        start += size
    return out


def _lib(x: Any) -> tuple[ModuleType, Any]:
    return (th_rot, torch) if isinstance(x, torch.Tensor) else (np_rot, np)


def local_features(body_pos: Any, body_rot: Any, body_linvel: Any, body_angvel: Any) -> dict[str, Any]:
    """Named ``Local()`` features of characters (numpy arrays or torch tensors, differentiable in torch).

    Args:
        body_pos: World body positions. Shape: (..., B, 3).
        body_rot: World body rotations (w, x, y, z); body 0 is the root. Shape: (..., B, 4).
        body_linvel: World linear velocities. Shape: (..., B, 3).
        body_angvel: World angular velocities. Shape: (..., B, 3).

    Returns:
        Dict with pos (..., B, 3), vel (..., B, 3), rot (..., B, 6), angvel (..., B, 3), height (..., B, 1),
        up (..., 3).
    """
    rot_lib, xp = _lib(body_pos)
    if xp is torch:
        return _local_features_torch(body_pos, body_rot, body_linvel, body_angvel)
    root_rot = body_rot[..., :1, :]
    root_pos = body_pos[..., :1, :]
    inv = rot_lib.quat_conj(root_rot)
    up = xp.zeros_like(body_pos[..., 0, :])
    up[..., 2] = 1.0
    return {
        "pos": rot_lib.quat_rotate(inv, body_pos - root_pos),
        "vel": rot_lib.quat_rotate(inv, body_linvel),
        "rot": rot_lib.quat_to_two_axis(rot_lib.quat_mul(inv, body_rot)),
        "angvel": rot_lib.quat_rotate(inv, body_angvel),
        "height": body_pos[..., 2:3],
        "up": rot_lib.quat_rotate(inv[..., 0, :], up),
    }


def _local_features_torch(body_pos: torch.Tensor, body_rot: torch.Tensor, body_linvel: torch.Tensor,
                          body_angvel: torch.Tensor) -> dict[str, torch.Tensor]:  # fmt: skip
    """:func:`local_features` for tensors through one root rotation matrix M.

    A row vector v expressed in the root frame is v M (= (M^T v)^T); a body's two-axis in the root frame is the
    first two columns of M^T B (B: the body's matrix), whose transpose is B[:, :2]^T M; the up vector is M's row 2.
    """
    m = th_rot.quat_to_matrix(body_rot[..., 0, :])  # (..., 3, 3)
    n = body_pos.shape[-2]
    vectors = torch.cat([body_pos - body_pos[..., :1, :], body_linvel, body_angvel], dim=-2)  # (..., 3N, 3)
    local = th_rot.rows_times_matrix(vectors, m[..., None, :, :])
    body_cols = th_rot.quat_to_matrix(body_rot)[..., :2].transpose(-1, -2)  # (..., N, 2, 3): rows are columns
    rot = th_rot.rows_times_matrix(body_cols, m[..., None, None, :, :]).reshape(*body_rot.shape[:-1], 6)
    return {
        "pos": local[..., :n, :],
        "vel": local[..., n : 2 * n, :],
        "rot": rot,
        "angvel": local[..., 2 * n :, :],
        "height": body_pos[..., 2:3],
        "up": m[..., 2, :],
    }


def flatten_local(features: dict[str, Any]) -> Any:
    """Concatenates named ``Local()`` features in :data:`LOCAL_LAYOUT` order. (..., B, k) pieces -> (..., D)."""
    _, xp = _lib(features["pos"])
    parts = []
    for name, per_body, _ in LOCAL_LAYOUT:
        x = features[name]
        parts.append(x.reshape(*x.shape[:-2], -1) if per_body else x)
    return xp.concatenate(parts, axis=-1)


def local_vector(body_pos: Any, body_rot: Any, body_linvel: Any, body_angvel: Any) -> Any:
    """Flat ``Local()`` vector. Shape: (..., local_size(B))."""
    return flatten_local(local_features(body_pos, body_rot, body_linvel, body_angvel))


def tracking_observation(sim: Any, ref_next: Any, phase: np.ndarray) -> dict[str, np.ndarray]:
    """Named observation features of a tracking policy (PPO), numpy.

    Args:
        sim: Simulated CharacterState at time t, leading shape (N,).
        ref_next: Reference CharacterState at t + dt.
        phase: Clip phase in [0, 1). Shape: (N,).

    Returns:
        ``sim_local`` (N, D) and ``ref_local`` (N, D): Local() of each character in its own root frame;
        ``ref_root_pos`` (N, 3) and ``ref_root_rot`` (N, 6): the reference root in the simulated root's frame
        (position, two-axis rotation), which Local() alone cannot tell; ``phase`` (N, 2): sin and cos of 2 pi phase.
    """
    inv = np_rot.quat_conj(sim.body_rot[:, 0])
    return {
        "sim_local": local_vector(sim.body_pos, sim.body_rot, sim.body_linvel, sim.body_angvel),
        "ref_local": local_vector(ref_next.body_pos, ref_next.body_rot, ref_next.body_linvel, ref_next.body_angvel),
        "ref_root_pos": np_rot.quat_rotate(inv, ref_next.body_pos[:, 0] - sim.body_pos[:, 0]),
        "ref_root_rot": np_rot.quat_to_two_axis(np_rot.quat_mul(inv, ref_next.body_rot[:, 0])),
        "phase": np.stack([np.sin(2 * np.pi * phase), np.cos(2 * np.pi * phase)], axis=-1),
    }


OBSERVATION_KEYS = ("sim_local", "ref_local", "ref_root_pos", "ref_root_rot", "phase")


def flatten_observation(obs: dict[str, np.ndarray]) -> np.ndarray:
    """Concatenates :func:`tracking_observation` features in :data:`OBSERVATION_KEYS` order. Shape: (N, D_obs)."""
    return np.concatenate([obs[k] for k in OBSERVATION_KEYS], axis=-1)
