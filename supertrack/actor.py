"""The policy acting in the real simulator: gym StepResult -> offsets -> PD target rotations -> hinge targets.

The target rotation is computed by the same torch function as in training
(:func:`supertrack.state.target_rotations`); only the conversion to hinge angles is numpy. On terrain the policy's
heightmap is sampled by the same torch function as in training too (:class:`supertrack.terrain.TerrainInputs`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import torch

from common.character.humanoid import Humanoid, hinges_to_joint_rotations, joint_rotations_to_hinges
from common.sim.gym import StepResult
from supertrack.models import Policy
from supertrack.state import BodyState, pack_character_state, target_rotations
from supertrack.terrain import TerrainInputs


@dataclass
class Action:
    """One control step of N characters.

    Attributes:
        hinge_targets: PD target angle of every actuated hinge, actuator order. Shape: (N, nu).
        target_rot: Target joint rotations T_i as applied (noise included), float32. Shape: (N, J, 4).
        kin_next_joint_rot: Reference joint rotations k_{i+1}, float32. Shape: (N, J, 4).
        kin_contacts: The reference's contact labels the policy read (``terrain.contact_frames``), or None.
            Shape: (N, K, bodies).
    """

    hinge_targets: np.ndarray
    target_rot: np.ndarray
    kin_next_joint_rot: np.ndarray
    kin_contacts: np.ndarray | None = None


class Actor:
    """Runs the current policy on gym states (no gradient).

    Args:
        humanoid: The model.
        policy: The policy network.
        alpha: Offset scale (rad).
        bf16: Run the network under bf16 autocast (its outputs and the targets stay float32).
        terrain: The terrain inputs of the clips the gym's ``clip`` indices refer to, when the policy reads them
            (moved to the policy's device).
    """

    def __init__(self, humanoid: Humanoid, policy: Policy, alpha: float, bf16: bool = False,
                 terrain: TerrainInputs | None = None) -> None:  # fmt: skip
        self.humanoid, self.policy, self.alpha, self.bf16 = humanoid, policy, alpha, bf16
        self.terrain = None if terrain is None else terrain.to(next(policy.parameters()).device)

    @torch.no_grad()
    def __call__(self, res: StepResult, noise: np.ndarray | None = None) -> Action:
        """Targets for the step from ``res.sim`` (S_i) towards ``res.ref_next`` (K_{i+1}).

        Args:
            res: The gym's current state.
            noise: Exploration noise already scaled by sigma, or None for the deterministic policy. Shape: (N, J, 3).
        """
        device = next(self.policy.parameters()).device
        kin_joint_rot = hinges_to_joint_rotations(self.humanoid, res.ref_next.qpos).astype(np.float32)
        sim = BodyState.from_character(res.sim, device)
        kin_contacts, terrain = None, None
        if self.terrain is not None:
            kin_contacts = self.terrain.reference_contacts(res)
            contacts = None if kin_contacts is None else torch.as_tensor(kin_contacts, device=device)
            heightmap = self.terrain.heightmap(sim, torch.as_tensor(res.clip, device=device))
            terrain = self.terrain.policy_inputs(heightmap, contacts)
        with torch.autocast(device.type, torch.bfloat16) if self.bf16 else contextlib.nullcontext():
            offsets = self.policy(sim, BodyState.from_character(res.ref_next, device), terrain).float()
        if noise is not None:
            offsets = offsets + torch.as_tensor(noise, dtype=offsets.dtype, device=device) * self.policy.dof_mask
        target = target_rotations(offsets, torch.as_tensor(kin_joint_rot, device=device), self.alpha).cpu().numpy()
        hinges = joint_rotations_to_hinges(self.humanoid, target.astype(np.float64), near_qpos=res.ref_next.qpos)
        return Action(hinge_targets=hinges, target_rot=target, kin_next_joint_rot=kin_joint_rot,
                      kin_contacts=kin_contacts)  # fmt: skip

    def deterministic(self, res: StepResult) -> np.ndarray:
        """The evaluator's policy: hinge targets without exploration noise. Shape: (N, nu)."""
        return self(res).hinge_targets


class GymActor:
    """SuperTrack's :class:`common.sim.collect.FrameActor`: a CPU copy of the policy plus noise, and its frame fields.

    The frame that starts at gym state i holds S_i (``sim``), K_{i+1} (``kin_next``), k_{i+1}
    (``kin_next_joint_rot``) and the applied targets T_i (``target_rot``): see :mod:`supertrack.learner`; on terrain
    also S_i's contacts (``sim_contacts``) and the reference's contact labels the policy read (``kin_contacts``), as
    :func:`supertrack.terrain.terrain_fields` lists them.

    Args:
        humanoid: The model.
        policy: A policy network of the learner's sizes (its weights are replaced by :meth:`load_weights`).
        alpha: Offset scale (rad).
        sigma: Exploration noise std (units of o).
        bf16: Act under bf16 autocast.
        terrain: The terrain inputs and fields, when the config has any.
    """

    def __init__(self, humanoid: Humanoid, policy: Policy, alpha: float, sigma: float, bf16: bool = False,
                 terrain: TerrainInputs | None = None) -> None:  # fmt: skip
        self.actor = Actor(humanoid, policy.cpu(), alpha, bf16, terrain)
        self.sigma = sigma

    def load_weights(self, weights: Mapping[str, torch.Tensor]) -> None:
        self.actor.policy.load_state_dict(weights)

    def __call__(self, res: StepResult, rng: np.random.Generator) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Hinge targets (N, nu) and the frame's fields {name: (N, ...)}."""
        n, n_joints = res.sim.qpos.shape[0], self.actor.policy.num_joints
        action = self.actor(res, self.sigma * rng.standard_normal((n, n_joints, 3)))
        fields = {
            "sim": pack_character_state(res.sim), "kin_next": pack_character_state(res.ref_next),
            "kin_next_joint_rot": action.kin_next_joint_rot, "target_rot": action.target_rot,
        }  # fmt: skip
        terrain = self.actor.terrain
        if terrain is not None and terrain.config.contact_weight > 0:
            fields["sim_contacts"] = terrain.simulated_contacts(res)
        if action.kin_contacts is not None:
            fields["kin_contacts"] = action.kin_contacts
        return action.hinge_targets, fields
