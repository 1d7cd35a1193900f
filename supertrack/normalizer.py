"""Fixed feature normalisers, computed once from the kinematic motion dataset (Fussell et al. 2021, section 4).

They are module buffers, so they travel with the networks' state dicts into every checkpoint and are restored,
never recomputed, on ``--resume``; nothing updates them during training.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from common.character.humanoid import Humanoid, hinges_to_joint_rotations
from common.maths.rotations import quat_rotate_inv, quat_to_two_axis
from common.motion.library import MotionLibrary
from common.sim.features import local_vector


class Normalizer(nn.Module):
    """x_norm = (x - mean) / std with a frozen mean and std.

    Args:
        mean: Per-feature mean. Shape: (D,).
        std: Per-feature std (already floored). Shape: (D,).
    """

    def __init__(self, mean: np.ndarray | Tensor, std: np.ndarray | Tensor) -> None:
        super().__init__()
        mean_t = torch.as_tensor(np.asarray(mean), dtype=torch.float32)
        std_t = torch.as_tensor(np.asarray(std), dtype=torch.float32)
        if mean_t.shape != std_t.shape or mean_t.ndim != 1:
            raise ValueError(f"mean {tuple(mean_t.shape)} and std {tuple(std_t.shape)} must be equal 1-d shapes")
        if not bool((std_t > 0).all()):
            raise ValueError("every std must be positive")
        self.register_buffer("mean", mean_t)
        self.register_buffer("std", std_t)

    @classmethod
    def from_samples(cls, x: np.ndarray, min_std: float) -> Normalizer:
        """Mean and std over the rows of ``x`` (F, D); std floored at ``min_std`` (constant features)."""
        x = np.asarray(x, dtype=np.float64)
        return cls(x.mean(axis=0), np.maximum(x.std(axis=0), min_std))

    @property
    def size(self) -> int:
        return int(self.mean.shape[0])

    def normalize(self, x: Tensor) -> Tensor:
        """(..., D) -> (..., D)."""
        return (x - self.mean) / self.std

    def denormalize(self, x: Tensor) -> Tensor:
        """(..., D) -> (..., D)."""
        return x * self.std + self.mean


def _consecutive_pairs(library: MotionLibrary) -> tuple[np.ndarray, np.ndarray]:
    """Frame indices (i, i + 1) of consecutive frames inside one clip of ``library.frames``."""
    first = np.concatenate([s + np.arange(n - 1) for s, n in zip(library.start, library.num_frames, strict=True)])
    return first, first + 1


def local_normalizer(library: MotionLibrary, min_std: float) -> Normalizer:
    """Normaliser of Local() features (D = 16 N + 3) over every frame of the motion dataset."""
    f = library.frames
    return Normalizer.from_samples(local_vector(f.body_pos, f.body_rot, f.body_linvel, f.body_angvel), min_std)


def target_normalizer(library: MotionLibrary, humanoid: Humanoid, min_std: float) -> Normalizer:
    """Normaliser of PD-target features (two-axis of each joint rotation, D = 6 J) from the reference poses."""
    joint_rot = hinges_to_joint_rotations(humanoid, library.frames.qpos)
    two_axis = quat_to_two_axis(joint_rot)
    return Normalizer.from_samples(two_axis.reshape(len(two_axis), -1), min_std)


def acceleration_normalizer(library: MotionLibrary, min_std: float) -> Normalizer:
    """Normaliser of the world model's outputs: root-frame linear then angular body accelerations (D = 6 N).

    Accelerations are the finite differences (v_{i+1} - v_i) / dt of the reference, expressed in the root frame of
    frame i, the frame in which W predicts them.
    """
    f = library.frames
    i, j = _consecutive_pairs(library)
    root_rot = f.body_rot[i, :1]
    lin = quat_rotate_inv(root_rot, (f.body_linvel[j] - f.body_linvel[i]) / library.dt)
    ang = quat_rotate_inv(root_rot, (f.body_angvel[j] - f.body_angvel[i]) / library.dt)
    return Normalizer.from_samples(np.concatenate([lin.reshape(len(i), -1), ang.reshape(len(i), -1)], -1), min_std)
