"""Rebuilds SuperTrack's deterministic policy from a run's checkpoint, for the comparison report.

Only the policy network (with its Local() normaliser, stored as module buffers in the checkpoint) and the actor's
offset scale are needed to act: the world model, optimisers, buffers and the training gym are not rebuilt. A policy
that reads terrain inputs (``terrain`` config) reads those of the motions it is evaluated on.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import Policy as EvalPolicy
from common.motion.library import MotionLibrary
from common.run.directory import load_run_checkpoint
from supertrack.actor import Actor
from supertrack.config import SuperTrackConfig
from supertrack.models import Policy
from supertrack.normalizer import Normalizer
from supertrack.state import STATE_LAYOUT, STATE_WIDTH, BodyState, target_rotations
from supertrack.terrain import TerrainInputs, policy_terrain_size


def load_eval_policy(run_dir: Path, checkpoint: Path, humanoid: Humanoid, library: MotionLibrary,
                     average: bool | None = None) -> EvalPolicy:  # fmt: skip
    """The deterministic SuperTrack policy stored in ``checkpoint``: the one the trainer evaluated.

    Args:
        run_dir: The run directory (its ``config.yaml`` gives the network sizes and alpha).
        checkpoint: A checkpoint written by the trainer.
        humanoid: The model.
        library: The motions to evaluate on: their terrains, when the policy reads terrain inputs (the normaliser
            comes from the checkpoint, not from the evaluation motions, so the policy sees exactly the features it
            was trained on).
        average: Which weights: the averaged ones (``policy.average_decay`` > 0), the live ones (False), or
            None: the averaged ones when the run kept an average (what its trainer evaluated), else the live ones.

    Returns:
        A callable from the gym's StepResult to hinge PD targets (N, nu).

    Raises:
        ValueError: If the checkpoint holds no SuperTrack policy (or no averaged one when ``average`` is True) or
            does not fit the config.
    """
    cfg, net, _ = load_policy_network(run_dir, checkpoint, humanoid, average)
    terrain = TerrainInputs(cfg.terrain, humanoid, library) if net.terrain_size else None
    return Actor(humanoid, net, cfg.policy.alpha, terrain=terrain).deterministic


def load_policy_network(run_dir: Path, checkpoint: Path, humanoid: Humanoid,
                        average: bool | None = None) -> tuple[SuperTrackConfig, Policy, bool]:  # fmt: skip
    """The run's config, the policy network of ``checkpoint`` (eval mode) and whether it holds the averaged weights:
    the network :func:`load_eval_policy` acts with. Arguments and errors as there."""
    cfg, learner = load_run_checkpoint(SuperTrackConfig, run_dir, checkpoint, "policy")
    if average is None:
        average = "policy_average" in learner
    if average and "policy_average" not in learner:
        raise ValueError(f"{checkpoint}: no averaged policy in this checkpoint (its run had policy.average_decay 0)")
    weights = learner["policy_average"]["module"] if average else learner["policy"]
    size = int(weights["local_norm.mean"].shape[0])
    if size != 16 * humanoid.num_bodies + 3:
        raise ValueError(f"{checkpoint}: policy input size {size} does not fit a {humanoid.num_bodies}-body model")
    # Placeholder statistics of the right size; load_state_dict overwrites them with the trained ones.
    net = Policy(len(humanoid.joint_groups), cfg.policy.hidden, Normalizer(np.zeros(size), np.ones(size)),
                 cfg.policy.init_scale, root_offset=cfg.policy.root_offset,
                 revolute=torch.tensor([g.kind == "revolute" for g in humanoid.joint_groups]),
                 terrain_size=policy_terrain_size(cfg.terrain, humanoid.num_bodies))  # fmt: skip
    try:
        net.load_state_dict(weights)
    except RuntimeError as e:
        raise ValueError(f"{checkpoint}: policy weights do not match {run_dir}/config.yaml: {e}") from e
    return cfg, net.eval(), average


class OnnxPolicy(nn.Module):
    """The deterministic policy as one float32 graph: body states -> offsets o and PD target rotations.

    Everything :class:`supertrack.actor.Actor` does in torch, in the same operations: Local() of both states, the
    Local() normaliser, the root offset features (``policy.root_offset``), the MLP, the revolute mask and
    t = quat_from_rotvec(alpha o) * k_{t+1}. Left to the caller, as in the actor: k_{t+1} from the reference's hinge
    angles (``common.character.humanoid.hinges_to_joint_rotations``) and the hinge targets from t
    (``joint_rotations_to_hinges``: a spherical joint's three Euler angles picked nearest the reference's, a
    revolute joint's 2 atan2(t_y, t_w)); both are per-joint conventions of the character, not of the policy.

    Inputs (B characters, N bodies in ``Humanoid.body_names`` order, J joints in ``Humanoid.joint_groups`` order):
        sim_state: Simulated state S_t, per body world position (3), rotation (w, x, y, z) (4), linear velocity (3),
            angular velocity (3), Z up, m and rad. Shape: (B, N, 13).
        kin_next_state: The reference K_{t+1} one control step ahead, same layout. Shape: (B, N, 13).
        kin_next_joint_rot: The reference's local joint rotations k_{t+1} (w, x, y, z). Shape: (B, J, 4).

    Outputs:
        offsets: o, axis-angle per joint in units of alpha (revolute joints: x and z are 0). Shape: (B, J, 3).
        target_rot: PD target joint rotations t (w, x, y, z). Shape: (B, J, 4).

    Args:
        policy: The policy network (eval mode).
        alpha: Offset scale (rad per unit of o).
    """

    def __init__(self, policy: Policy, alpha: float) -> None:
        super().__init__()
        self.policy, self.alpha = policy, alpha

    def forward(self, sim_state: Tensor, kin_next_state: Tensor, kin_next_joint_rot: Tensor) -> tuple[Tensor, Tensor]:
        offsets = self.policy(BodyState.unpack(sim_state), BodyState.unpack(kin_next_state))
        return offsets, target_rotations(offsets, kin_next_joint_rot, self.alpha)


def onnx_module(run_dir: Path, checkpoint: Path, humanoid: Humanoid) -> tuple[nn.Module, dict[str, Any]]:
    """The run's deterministic policy for ONNX export (:class:`OnnxPolicy`) and the description of its inputs and
    outputs for the sidecar file.

    Returns:
        The module (float32, eval mode) and {"inputs": [...], "outputs": [...], "policy": {...}}: per tensor its
        name, shape ("batch" first), meaning and, where it has one, the layout of its last axes.

    Raises:
        ValueError: As :func:`load_eval_policy`, and for a policy that reads terrain inputs (not exported yet).
    """
    cfg, net, averaged = load_policy_network(run_dir, checkpoint, humanoid)
    if net.terrain_size:
        raise ValueError(f"{run_dir}: the policy reads terrain inputs (terrain.heightmap_extent / contact_frames), "
                         "which export-policy does not export yet")  # fmt: skip
    n, joints = humanoid.num_bodies, [g.name for g in humanoid.joint_groups]
    body_layout = {"bodies": list(humanoid.body_names), "fields": {name: width for name, _, width in STATE_LAYOUT}}
    quat = "unit quaternion (w, x, y, z)"
    spec = {
        "inputs": [
            {"name": "sim_state", "shape": ["batch", n, STATE_WIDTH], "layout": body_layout,
             "meaning": f"simulated state S_t: per body world position (m), rotation ({quat}), linear velocity "
                        "(m/s), angular velocity (rad/s); Z up"},
            {"name": "kin_next_state", "shape": ["batch", n, STATE_WIDTH], "layout": body_layout,
             "meaning": "the reference K_{t+1} one control step ahead, same layout"},
            {"name": "kin_next_joint_rot", "shape": ["batch", len(joints), 4], "layout": {"joints": joints},
             "meaning": f"the reference's local joint rotations k_{{t+1}} ({quat}), from its hinge angles"},
        ],
        "outputs": [
            {"name": "offsets", "shape": ["batch", len(joints), 3], "layout": {"joints": joints},
             "meaning": "o: axis-angle offset per joint in units of alpha (revolute joints: about +y only)"},
            {"name": "target_rot", "shape": ["batch", len(joints), 4], "layout": {"joints": joints},
             "meaning": f"PD target joint rotations t = quat_from_rotvec(alpha o) * k_{{t+1}} ({quat}); a revolute "
                        "joint's hinge target is 2 atan2(t_y, t_w)"},
        ],
        "policy": {"alpha_rad": cfg.policy.alpha, "root_offset": cfg.policy.root_offset,
                   "averaged_weights": averaged, "control_hz": humanoid.physics.control_hz},
    }  # fmt: skip
    return OnnxPolicy(net, cfg.policy.alpha).eval(), spec
