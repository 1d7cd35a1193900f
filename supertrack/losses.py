"""SuperTrack's losses as pure functions returning ``(loss, metrics)`` (Fussell et al. 2021, section 4).

Every term is a mean absolute error (L1) over batch, time, bodies and components, so weights do not depend on
batch or window sizes. Metrics hold the unweighted terms, keyed for the metrics log (``losses/...``).
"""

from __future__ import annotations

import torch
from torch import Tensor

from common.maths import torch_rotations as R
from common.sim.features import local_features
from supertrack.config import PolicyLossWeights, WorldLossWeights
from supertrack.state import BodyState

POLICY_TERMS = ("pos", "vel", "rot", "angvel", "height", "up")


def rotation_error(q_pred: Tensor, q_true: Tensor) -> Tensor:
    """log(q_pred * inv(q_true)) as a rotation vector (shortest path, sign-invariant). (..., 4) -> (..., 3)."""
    return R.quat_to_rotvec(R.quat_mul(q_pred, R.quat_conj(q_true)))


def world_model_loss(
    predicted: BodyState, true: BodyState, weights: WorldLossWeights
) -> tuple[Tensor, dict[str, Tensor]]:
    """L1 world-space loss of a W rollout against the simulator.

    Args:
        predicted: P_1 .. P_{L-1}, fields (B, T, N, k).
        true: S_1 .. S_{L-1}, same shapes.
        weights: Term weights.

    Returns:
        Scalar loss and detached unweighted terms ``losses/world_model_<term>`` plus ``losses/world_model``.
    """
    terms = {
        "pos": (predicted.pos - true.pos).abs().mean(),
        "vel": (predicted.vel - true.vel).abs().mean(),
        "rot": rotation_error(predicted.rot, true.rot).abs().mean(),
        "angvel": (predicted.angvel - true.angvel).abs().mean(),
    }
    loss = sum(getattr(weights, k) * v for k, v in terms.items())
    metrics = {f"losses/world_model_{k}": v.detach() for k, v in terms.items()}
    metrics["losses/world_model"] = loss.detach()
    return loss, metrics


def contact_loss(logits: Tensor, contacts: Tensor) -> tuple[Tensor, dict[str, Tensor]]:
    """W's contact prediction against the simulated contacts: binary cross-entropy per body and frame.

    Args:
        logits: W's contact logits of P_1 .. P_{L-1}. Shape: (B, T, N).
        contacts: The simulated contacts of S_1 .. S_{L-1} (bool or 0/1). Shape: (B, T, N).

    Returns:
        The mean cross-entropy, and detached ``losses/world_model_contact`` (the same) and
        ``losses/world_model_contact_error`` (the fraction of bodies and frames whose logit has the wrong sign).
    """
    target = contacts.to(logits.dtype)
    loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, target)
    error = ((logits > 0) != (target > 0.5)).to(logits.dtype).mean()
    return loss, {"losses/world_model_contact": loss.detach(), "losses/world_model_contact_error": error.detach()}


def step_weights(steps: int, decay: float, like: Tensor) -> Tensor:
    """Per-step loss weights decay^i (i = 0 .. steps - 1) scaled to mean 1, so that decay 1 is the plain mean.

    ControlVAE (Yao et al. 2022) weights its policy loss by 0.95^i along the rollout: the later frames of a
    rollout through the world model carry its compounded error, so they pull less. Shape: (steps,).
    """
    w = decay ** torch.arange(steps, dtype=like.dtype, device=like.device)
    return w / w.mean()


def policy_loss(predicted: BodyState, kin: BodyState, offsets: Tensor, weights: PolicyLossWeights,
                step_decay: float = 1.0) -> tuple[Tensor, dict[str, Tensor]]:  # fmt: skip
    """L1 local-space tracking loss of a policy rollout, world-space root terms and the offset regularisers.

    Args:
        predicted: P_1 .. P_L, fields (B, T, N, k).
        kin: K_1 .. K_L, same shapes.
        offsets: Offsets o before noise. Shape: (B, T, J, 3); the rate term is 0 when T = 1.
        weights: Term weights.
        step_decay: The tracking and root terms of rollout step i weigh step_decay^i (scaled to mean 1,
            :func:`step_weights`); 1 is the paper's plain mean. The offset regularisers are not decayed.

    Returns:
        Scalar loss and detached unweighted terms ``losses/policy_<term>`` plus ``losses/policy``. The logged
        terms are plain means over the window whatever ``step_decay`` is, so that runs stay comparable.
    """
    sim_local = local_features(predicted.pos, predicted.rot, predicted.vel, predicted.angvel)
    kin_local = local_features(kin.pos, kin.rot, kin.vel, kin.angvel)
    per_step = {k: _per_step_mean(sim_local[k] - kin_local[k]) for k in POLICY_TERMS}
    # World-space root terms (weights 0 in the paper's loss): the only terms that see drift.
    per_step["root_pos"] = _per_step_mean(predicted.pos[..., 0, :] - kin.pos[..., 0, :])
    root_error = rotation_error(predicted.rot[..., 0, :], kin.rot[..., 0, :])
    per_step["root_rot"] = _per_step_mean(root_error)
    per_step["root_heading"] = _per_step_mean(root_error[..., 2:])  # the world-frame turn about +Z
    time_w = step_weights(predicted.pos.shape[1], step_decay, predicted.pos)
    terms = {k: v.mean() for k, v in per_step.items()}
    weighted = {k: (time_w * v).mean() for k, v in per_step.items()}
    terms["offset_l1"] = offsets.abs().mean()
    terms["offset_l2"] = offsets.square().mean()
    # Frame-to-frame change of the offsets (not in the paper): a policy that reacts to every wobble of the
    # simulated velocities makes its PD targets chatter, and the chatter shakes the feet where W is blind.
    rate = offsets[:, 1:] - offsets[:, :-1]
    terms["offset_rate"] = rate.abs().mean() if rate.numel() else offsets.new_zeros(())
    loss = sum(getattr(weights, k) * weighted.get(k, v) for k, v in terms.items())
    metrics = {f"losses/policy_{k}": v.detach() for k, v in terms.items()}
    metrics["losses/policy"] = loss.detach()
    return loss, metrics


def _per_step_mean(error: Tensor) -> Tensor:
    """Mean |error| per rollout step: (B, T, ...) -> (T,). Every step has as many values, so its mean is the mean."""
    return error.abs().flatten(2).mean(dim=(0, 2))
