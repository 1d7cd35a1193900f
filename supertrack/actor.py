"""The policy acting in the real simulator: gym StepResult -> offsets -> PD target rotations -> hinge targets.

The target rotation is computed by the same torch function as in training
(:func:`supertrack.state.target_rotations`); only the conversion to hinge angles is numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from common.gym import StepResult
from common.humanoid import Humanoid, hinges_to_joint_rotations, joint_rotations_to_hinges
from supertrack.models import Policy
from supertrack.state import BodyState, target_rotations


@dataclass
class Action:
    """One control step of N characters.

    Attributes:
        hinge_targets: PD target angle of every actuated hinge, actuator order. Shape: (N, nu).
        target_rot: Target joint rotations T_i as applied (noise included), float32. Shape: (N, J, 4).
        kin_next_joint_rot: Reference joint rotations k_{i+1}, float32. Shape: (N, J, 4).
    """

    hinge_targets: np.ndarray
    target_rot: np.ndarray
    kin_next_joint_rot: np.ndarray


class Actor:
    """Runs the current policy on gym states (no gradient).

    Args:
        humanoid: The model.
        policy: The policy network (the live one: the gym always acts with the latest weights).
        alpha: Offset scale (rad).
    """

    def __init__(self, humanoid: Humanoid, policy: Policy, alpha: float) -> None:
        self.humanoid, self.policy, self.alpha = humanoid, policy, alpha

    @torch.no_grad()
    def __call__(self, res: StepResult, noise: np.ndarray | None = None) -> Action:
        """Targets for the step from ``res.sim`` (S_i) towards ``res.ref_next`` (K_{i+1}).

        Args:
            res: The gym's current state.
            noise: Exploration noise already scaled by sigma, or None for the deterministic policy. Shape: (N, J, 3).
        """
        device = next(self.policy.parameters()).device
        kin_joint_rot = hinges_to_joint_rotations(self.humanoid, res.ref_next.qpos).astype(np.float32)
        offsets = self.policy(BodyState.from_character(res.sim, device), BodyState.from_character(res.ref_next, device))
        if noise is not None:
            offsets = offsets + torch.as_tensor(noise, dtype=offsets.dtype, device=device) * self.policy.dof_mask
        target = target_rotations(offsets, torch.as_tensor(kin_joint_rot, device=device), self.alpha).cpu().numpy()
        hinges = joint_rotations_to_hinges(self.humanoid, target.astype(np.float64), near_qpos=res.ref_next.qpos)
        return Action(hinge_targets=hinges, target_rot=target, kin_next_joint_rot=kin_joint_rot)

    def deterministic(self, res: StepResult) -> np.ndarray:
        """The evaluator's policy: hinge targets without exploration noise. Shape: (N, nu)."""
        return self(res).hinge_targets
