"""Local() features: invariance, hand-computed values, numpy/torch agreement; the PPO observation."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from common.character.humanoid import Humanoid
from common.maths.rotations import quat_from_axis_angle, quat_from_yaw, quat_mul, quat_rotate
from common.motion.dataset import load_motions
from common.sim.features import (
    feature_slices,
    flatten_observation,
    local_features,
    local_size,
    local_vector,
    tracking_observation,
)


@pytest.fixture(scope="module")
def states():
    h = Humanoid()
    lib = load_motions(["walk", "backflip"], h)
    return lib.query(np.array([0, 1, 1]), np.array([0.2, 0.4, 0.9]))


def _moved(s, yaw: float, shift: np.ndarray):
    q = quat_from_yaw(np.array(yaw))
    return (quat_rotate(q, s.body_pos) + shift, quat_mul(q, s.body_rot), quat_rotate(q, s.body_linvel),
            quat_rotate(q, s.body_angvel))  # fmt: skip


def test_local_unchanged_by_ground_shift_and_yaw(states) -> None:
    base = local_vector(states.body_pos, states.body_rot, states.body_linvel, states.body_angvel)
    moved = local_vector(*_moved(states, 1.3, np.array([4.0, -2.0, 0.0])))
    np.testing.assert_allclose(moved, base, atol=1e-12)
    # A vertical shift changes only the heights.
    up = local_features(states.body_pos + [0, 0, 0.5], states.body_rot, states.body_linvel, states.body_angvel)
    ref = local_features(states.body_pos, states.body_rot, states.body_linvel, states.body_angvel)
    np.testing.assert_allclose(up["height"], ref["height"] + 0.5)
    np.testing.assert_allclose(up["pos"], ref["pos"], atol=1e-12)


def test_local_by_hand() -> None:
    """Root turned 90 deg about z at (1, 0, 1); a body 1 m ahead along world +y is 1 m along the root's +x."""
    rot = np.tile(quat_from_yaw(np.array(np.pi / 2)), (2, 1))
    pos = np.array([[1.0, 0.0, 1.0], [1.0, 1.0, 0.5]])
    vel = np.array([[0.0, 2.0, 0.0], [0.0, 0.0, 0.0]])
    f = local_features(pos, rot, vel, np.zeros((2, 3)))
    np.testing.assert_allclose(f["pos"][1], [1.0, 0.0, -0.5], atol=1e-12)
    np.testing.assert_allclose(f["vel"][0], [2.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(f["height"][:, 0], [1.0, 0.5])
    np.testing.assert_allclose(f["rot"][1], [1, 0, 0, 0, 1, 0], atol=1e-12)  # same rotation as the root
    # +90 deg about y takes the root's +z to world +x, so world up lies along the root's -x.
    pitch = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), np.array(np.pi / 2))
    g = local_features(pos, np.stack([pitch, pitch]), vel, np.zeros((2, 3)))
    np.testing.assert_allclose(g["up"], [-1.0, 0.0, 0.0], atol=1e-12)


def test_torch_matches_numpy_and_is_differentiable(states) -> None:
    arrays = (states.body_pos, states.body_rot, states.body_linvel, states.body_angvel)
    tensors = [torch.tensor(a, requires_grad=True) for a in arrays]
    out = local_vector(*tensors)
    np.testing.assert_allclose(out.detach().numpy(), local_vector(*arrays), atol=1e-12)
    out.sum().backward()
    assert all(t.grad is not None and torch.isfinite(t.grad).all() for t in tensors)


def test_layout_sizes_and_slices(states) -> None:
    assert local_size(15) == 15 * 16 + 3 == 243
    sl = feature_slices(15)
    v = local_vector(states.body_pos, states.body_rot, states.body_linvel, states.body_angvel)
    f = local_features(states.body_pos, states.body_rot, states.body_linvel, states.body_angvel)
    np.testing.assert_array_equal(v[:, sl["rot"]], f["rot"].reshape(3, -1))
    np.testing.assert_array_equal(v[:, sl["up"]], f["up"])


def test_tracking_observation_relative_root(states) -> None:
    obs = tracking_observation(states, states, np.array([0.0, 0.25, 0.5]))
    np.testing.assert_allclose(obs["ref_root_pos"], 0.0, atol=1e-12)  # reference root = own root
    np.testing.assert_allclose(obs["ref_root_rot"], np.tile([1, 0, 0, 0, 1, 0], (3, 1)), atol=1e-12)
    np.testing.assert_allclose(obs["phase"], [[0, 1], [1, 0], [0, -1]], atol=1e-12)
    assert flatten_observation(obs).shape == (3, 2 * 243 + 3 + 6 + 2)
