"""SuperTrack's two networks: the world model W and the policy (Fussell et al. 2021, sections 4.1-4.2).

W maps [Local(P_i), T_i] to per-body accelerations in the root frame (normalised), which are rotated to the world
and integrated by :func:`supertrack.state.integrate`. The policy maps [Local(P_i), Local(K_{i+1})] to axis-angle
offsets o of the reference joint rotations.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from common import torch_rotations as R
from supertrack.normalizer import Normalizer
from supertrack.state import BodyState, integrate, target_features


def mlp(in_size: int, hidden: Sequence[int], out_size: int, out_scale: float = 1.0) -> nn.Sequential:
    """ELU multilayer perceptron (the paper's layers) with an optionally down-scaled output layer.

    Args:
        in_size: Input features.
        hidden: Hidden layer widths.
        out_size: Outputs.
        out_scale: Factor on the output layer's initial weights (its bias starts at zero).
    """
    layers: list[nn.Module] = []
    width = in_size
    for h in hidden:
        layers += [nn.Linear(width, h), nn.ELU()]
        width = h
    out = nn.Linear(width, out_size)
    with torch.no_grad():
        out.weight.mul_(out_scale)
        out.bias.zero_()
    layers.append(out)
    return nn.Sequential(*layers)


class WorldModel(nn.Module):
    """W: predicts the next simulated state from the current one and the PD targets.

    Args:
        num_bodies: N.
        revolute: True for each joint whose PD controller is a single hinge. Shape: (J,).
        hidden: Hidden layer widths.
        local_norm: Normaliser of Local() (D = 16 N + 3).
        target_norm: Normaliser of the target features (D = 6 J).
        accel_norm: Normaliser of the root-frame accelerations, linear then angular (D = 6 N).
        dt: Control time step (s).
        init_scale: Factor on the output layer's initial weights.
    """

    def __init__(self, num_bodies: int, revolute: Tensor, hidden: Sequence[int], local_norm: Normalizer,
                 target_norm: Normalizer, accel_norm: Normalizer, dt: float,
                 init_scale: float = 1.0) -> None:  # fmt: skip
        super().__init__()
        self.num_bodies, self.dt = num_bodies, dt
        self.register_buffer("revolute", revolute.clone())
        self.local_norm, self.target_norm, self.accel_norm = local_norm, target_norm, accel_norm
        self.net = mlp(local_norm.size + target_norm.size, hidden, accel_norm.size, out_scale=init_scale)

    def accelerations(self, state: BodyState, target_rot: Tensor) -> tuple[Tensor, Tensor]:
        """World-frame accelerations of every body.

        Args:
            state: P_i, leading shape (B,).
            target_rot: PD target joint rotations T_i. Shape: (B, J, 4).

        Returns:
            Linear and angular accelerations, each (B, N, 3).
        """
        return self.accelerations_from_features(state, self.local_norm.normalize(state.local()), target_rot)

    def accelerations_from_features(self, state: BodyState, local_features: Tensor,
                                    target_rot: Tensor) -> tuple[Tensor, Tensor]:  # fmt: skip
        """:meth:`accelerations` with Local(P_i) already normalised by ``self.local_norm``. Shape: (B, D)."""
        x = torch.cat([local_features, self.target_norm.normalize(target_features(target_rot, self.revolute))], dim=-1)
        acc = self.accel_norm.denormalize(self.net(x)).reshape(*x.shape[:-1], 2, self.num_bodies, 3)
        world = R.quat_rotate(state.rot[..., None, :1, :], acc)
        return world[..., 0, :, :], world[..., 1, :, :]

    def forward(self, state: BodyState, target_rot: Tensor) -> BodyState:
        """P_{i+1} = integrate(P_i, W(Local(P_i), T_i)). Shapes as :meth:`accelerations`."""
        return integrate(state, *self.accelerations(state, target_rot), self.dt)

    def step_from_features(self, state: BodyState, local_features: Tensor, target_rot: Tensor) -> BodyState:
        """:meth:`forward` with Local(P_i) already normalised by ``self.local_norm`` (shared with the policy)."""
        return integrate(state, *self.accelerations_from_features(state, local_features, target_rot), self.dt)


class Policy(nn.Module):
    """The tracking policy: offsets o (before noise) from the simulated state and the next reference state.

    Args:
        num_joints: J.
        hidden: Hidden layer widths.
        local_norm: Normaliser of Local() (shared by both inputs).
        init_scale: Factor on the output layer's initial weights, so that training starts near o = 0
            (open-loop playback of the reference).
    """

    def __init__(self, num_joints: int, hidden: Sequence[int], local_norm: Normalizer, init_scale: float) -> None:
        super().__init__()
        self.num_joints = num_joints
        self.local_norm = local_norm
        self.net = mlp(2 * local_norm.size, hidden, 3 * num_joints, out_scale=init_scale)

    def forward(self, sim: BodyState, kin_next: BodyState) -> Tensor:
        """o_i = Pi([Local(P_i), Local(K_{i+1})]).

        Args:
            sim: P_i (or S_i in the gym), leading shape (B,).
            kin_next: K_{i+1}, leading shape (B,).

        Returns:
            Offsets. Shape: (B, J, 3).
        """
        return self.from_features(self.features(sim), self.features(kin_next))

    def features(self, state: BodyState) -> Tensor:
        """Normalised Local() of a state: (..., N, k) fields -> (..., D)."""
        return self.local_norm.normalize(state.local())

    def from_features(self, sim_features: Tensor, kin_next_features: Tensor) -> Tensor:
        """Offsets from precomputed :meth:`features` (a rollout computes the reference's once). (B, D) -> (B, J, 3)."""
        x = torch.cat([sim_features, kin_next_features], dim=-1)
        return self.net(x).reshape(*x.shape[:-1], self.num_joints, 3)
