"""SuperTrack's two networks: the world model W and the policy (Fussell et al. 2021, sections 4.1-4.2).

W maps [Local(P_i), T_i] to per-body accelerations in the root frame (normalised), which are rotated to the world
and integrated by :func:`supertrack.state.integrate`. The policy maps [Local(P_i), Local(K_{i+1})] to axis-angle
offsets o of the reference joint rotations. On terrain (``terrain`` config, :mod:`supertrack.terrain`) W also reads
the heightmap around P_i's root and may predict each body's contact with the ground; the policy reads the heightmap
and the reference's contact labels. Those inputs are raw, appended after the normalised ones.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from common.maths import torch_rotations as R
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
        heightmap_size: Width P of the raw heightmap read beside Local(P_i) (0: none).
        contacts: Also output a contact logit per body for P_{i+1} (:meth:`predict`).
    """

    def __init__(self, num_bodies: int, revolute: Tensor, hidden: Sequence[int], local_norm: Normalizer,
                 target_norm: Normalizer, accel_norm: Normalizer, dt: float, init_scale: float = 1.0,
                 heightmap_size: int = 0, contacts: bool = False) -> None:  # fmt: skip
        super().__init__()
        self.num_bodies, self.dt = num_bodies, dt
        self.heightmap_size, self.contacts = heightmap_size, contacts
        self.register_buffer("revolute", revolute.clone())
        self.local_norm, self.target_norm, self.accel_norm = local_norm, target_norm, accel_norm
        self.net = mlp(local_norm.size + heightmap_size + target_norm.size, hidden,
                       accel_norm.size + (num_bodies if contacts else 0), out_scale=init_scale)  # fmt: skip

    def accelerations(self, state: BodyState, target_rot: Tensor,
                      heightmap: Tensor | None = None) -> tuple[Tensor, Tensor]:  # fmt: skip
        """World-frame accelerations of every body.

        Args:
            state: P_i, leading shape (B,).
            target_rot: PD target joint rotations T_i. Shape: (B, J, 4).
            heightmap: The heightmap around P_i's root, raw (m), when W reads one. Shape: (B, P).

        Returns:
            Linear and angular accelerations, each (B, N, 3).
        """
        return self.predict(state, self.local_norm.normalize(state.local()), target_rot, heightmap)[:2]

    def predict(self, state: BodyState, local_features: Tensor, target_rot: Tensor,
                heightmap: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor | None]:  # fmt: skip
        """:meth:`accelerations` with Local(P_i) already normalised by ``self.local_norm`` (B, D), and the contact
        logits of P_{i+1}'s bodies (B, N) (None without ``contacts``)."""
        parts = [local_features, self.target_norm.normalize(target_features(target_rot, self.revolute))]
        if self.heightmap_size:
            if heightmap is None:
                raise ValueError("this W reads a heightmap (terrain.heightmap_extent): pass the terrain inputs")
            parts.insert(1, heightmap)
        x = torch.cat(parts, dim=-1)
        out = self.net(x)
        n_acc = self.accel_norm.size
        acc = self.accel_norm.denormalize(out[..., :n_acc]).reshape(*x.shape[:-1], 2 * self.num_bodies, 3)
        # Root frame -> world: M a for column vectors, i.e. a M^T for the rows here.
        world = R.rows_times_matrix(acc, R.quat_to_matrix(state.rot[..., 0, :]).transpose(-1, -2)[..., None, :, :])
        contacts = out[..., n_acc:] if self.contacts else None
        return world[..., : self.num_bodies, :], world[..., self.num_bodies :, :], contacts

    def forward(self, state: BodyState, target_rot: Tensor, heightmap: Tensor | None = None) -> BodyState:
        """P_{i+1} = integrate(P_i, W(Local(P_i), T_i)). Shapes as :meth:`accelerations`."""
        return integrate(state, *self.accelerations(state, target_rot, heightmap), self.dt)

    def step_from_features(self, state: BodyState, local_features: Tensor, target_rot: Tensor,
                           heightmap: Tensor | None = None) -> tuple[BodyState, Tensor | None]:  # fmt: skip
        """:meth:`forward` with Local(P_i) already normalised by ``self.local_norm`` (shared with the policy), and
        the contact logits of :meth:`predict`."""
        lin, ang, contacts = self.predict(state, local_features, target_rot, heightmap)
        return integrate(state, lin, ang, self.dt), contacts


# Scales of the root-offset features (fixed: the kinematic database, where they are all zero, cannot supply them).
ROOT_OFFSET_POS_SCALE = 0.25  # m per unit
ROOT_OFFSET_SIZE = 9  # 3 position + 6 two-axis


def root_offset_features(sim: BodyState, kin: BodyState) -> Tensor:
    """Where the reference's root is as seen from the simulated root: the drift that Local() cannot show.

    Local(S) and Local(K) are each relative to their own root, so a policy reading only them cannot tell that the
    simulated character has drifted away from the reference in the world. These 9 values can: the reference root's
    position in the simulated root's frame (/ 0.25 m) and the two-axis of inv(sim root) * reference root minus the
    identity's (zero when the roots coincide).

    Args:
        sim: P_i (or S_i), leading shape (...,).
        kin: K_{i+1}, same leading shape.

    Returns:
        Shape: (..., 9).
    """
    m = R.quat_to_matrix(sim.rot[..., 0, :])
    pos = R.rows_times_matrix(kin.pos[..., 0, :] - sim.pos[..., 0, :], m) / ROOT_OFFSET_POS_SCALE
    rel = R.quat_to_two_axis(R.quat_mul(R.quat_conj(sim.rot[..., 0, :]), kin.rot[..., 0, :]))
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0, 1.0, 0.0], dtype=rel.dtype, device=rel.device)
    return torch.cat([pos, rel - identity], dim=-1)


class Policy(nn.Module):
    """The tracking policy: offsets o (before noise) from the simulated state and the next reference state.

    Args:
        num_joints: J.
        hidden: Hidden layer widths.
        local_norm: Normaliser of Local() (shared by both inputs).
        init_scale: Factor on the output layer's initial weights, so that training starts near o = 0
            (open-loop playback of the reference).
        root_offset: Also read :func:`root_offset_features` (the paper's policy does not; without them the policy
            cannot correct drift in the world).
        revolute: True for each joint driven by a single hinge (about +y). Those joints get an offset about +y only:
            the other two components would not move the joint (the hinge keeps only its own part of a rotation)
            yet would bend the hinge angle it does get, ill-conditioned near 180 degrees, and nothing but the
            regularisers would hold them back. None: every joint spherical.
        terrain_size: Width of the raw terrain inputs read last (the heightmap and the reference's contact labels,
            :meth:`supertrack.terrain.TerrainInputs.policy_inputs`); 0: none.
    """

    def __init__(self, num_joints: int, hidden: Sequence[int], local_norm: Normalizer, init_scale: float,
                 root_offset: bool = False, revolute: Tensor | None = None, terrain_size: int = 0) -> None:  # fmt: skip
        super().__init__()
        self.num_joints, self.root_offset, self.terrain_size = num_joints, root_offset, terrain_size
        mask = torch.ones(num_joints, 3)
        if revolute is not None:
            mask[revolute] = torch.tensor([0.0, 1.0, 0.0])
        # Not saved: derived from the character, so checkpoints written before it existed still load.
        self.register_buffer("dof_mask", mask, persistent=False)
        self.local_norm = local_norm
        in_size = 2 * local_norm.size + (ROOT_OFFSET_SIZE if root_offset else 0) + terrain_size
        self.net = mlp(in_size, hidden, 3 * num_joints, out_scale=init_scale)

    def forward(self, sim: BodyState, kin_next: BodyState, terrain: Tensor | None = None) -> Tensor:
        """o_i = Pi([Local(P_i), Local(K_{i+1})] (+ root offset) (+ terrain inputs)).

        Args:
            sim: P_i (or S_i in the gym), leading shape (B,).
            kin_next: K_{i+1}, leading shape (B,).
            terrain: The raw terrain inputs when the policy reads them. Shape: (B, terrain_size).

        Returns:
            Offsets. Shape: (B, J, 3).
        """
        return self.from_features(self.features(sim), self.features(kin_next), sim, kin_next, terrain)

    def features(self, state: BodyState) -> Tensor:
        """Normalised Local() of a state: (..., N, k) fields -> (..., D)."""
        return self.local_norm.normalize(state.local())

    def from_features(self, sim_features: Tensor, kin_next_features: Tensor, sim: BodyState, kin_next: BodyState,
                      terrain: Tensor | None = None) -> Tensor:  # fmt: skip
        """Offsets from precomputed :meth:`features` (a rollout computes the reference's once). (B, D) -> (B, J, 3).

        ``sim`` and ``kin_next`` are read only for the root offset; ``terrain`` (B, terrain_size) only when the policy
        reads terrain inputs.
        """
        parts = [sim_features, kin_next_features]
        if self.root_offset:
            parts.append(root_offset_features(sim, kin_next))
        if self.terrain_size:
            if terrain is None:
                raise ValueError("this policy reads terrain inputs (terrain.heightmap_extent, contact_frames): "
                                 "pass them")  # fmt: skip
            parts.append(terrain)
        x = torch.cat(parts, dim=-1)
        return self.net(x).reshape(*x.shape[:-1], self.num_joints, 3) * self.dof_mask
