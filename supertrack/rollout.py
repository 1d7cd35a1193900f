"""Differentiable rollouts through the world model (Algorithms 1 and 2 of Fussell et al. 2021).

Both start from a recorded simulated state and never write into their inputs; gradients flow through every
predicted frame (back-propagation through time over the window). On terrain (:mod:`supertrack.terrain`) every step
samples the heightmap where the predicted state puts the root, on the window's clip's terrain.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from supertrack.config import SuperTrackConfig
from supertrack.models import Policy, WorldModel
from supertrack.state import BodyState, target_rotations
from supertrack.terrain import TerrainInputs


@contextlib.contextmanager
def frozen(module: nn.Module) -> Iterator[None]:
    """Parameters of ``module`` get no gradient inside the block (activations still pass gradients through)."""
    flags = [p.requires_grad for p in module.parameters()]
    for p in module.parameters():
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p, flag in zip(module.parameters(), flags, strict=True):
            p.requires_grad_(flag)


Fields = tuple[Tensor, Tensor, Tensor, Tensor]  # a BodyState as (pos, rot, vel, angvel): what torch.compile sees
WorldOutputs = tuple[Tensor, Tensor, Tensor, Tensor, Tensor | None]  # P_{i+1}'s fields, then its contact logits


def world_model_step(world_model: WorldModel, pos: Tensor, rot: Tensor, vel: Tensor, angvel: Tensor,
                     target_rot: Tensor, terrain: TerrainInputs | None = None,
                     clip: Tensor | None = None) -> WorldOutputs:  # fmt: skip
    """P_{i+1} = W(P_i, T_i) on plain tensors (the unit :func:`compile_steps` compiles), and W's contact logits for
    P_{i+1} (B, N) (None when W predicts none). ``terrain`` and ``clip`` (B,): the heightmap W reads, if any."""
    state = BodyState(pos, rot, vel, angvel)
    heightmap = None if terrain is None else terrain.heightmap(state, clip)
    s, contacts = world_model.step_from_features(state, world_model.local_norm.normalize(state.local()), target_rot,
                                                 heightmap)  # fmt: skip
    return s.pos, s.rot, s.vel, s.angvel, contacts


def policy_world_step(policy: Policy, world_model: WorldModel, sim: Fields, kin_features: Tensor, kin: Fields,
                      kin_joint_rot: Tensor, noise: Tensor, alpha: float, terrain: TerrainInputs | None = None,
                      clip: Tensor | None = None,
                      kin_contacts: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:  # fmt: skip
    """One step of Algorithm 2 on plain tensors: o_i from (P_i, K_{i+1}), T_i, P_{i+1} = W(P_i, T_i).

    On terrain both networks read the heightmap around P_i's root on the clip ``clip`` (B,), and the policy the
    reference's contact labels ``kin_contacts`` (B, K, N).

    Returns:
        P_{i+1} as (pos, rot, vel, angvel), then o_i before noise.
    """
    state, kin_state = BodyState(*sim), BodyState(*kin)
    # Both networks read the same normalised Local(P_i) (and heightmap): computed once per step.
    features = policy.features(state)
    heightmap, terrain_inputs = None, None
    if terrain is not None:
        heightmap = terrain.heightmap(state, clip)
        terrain_inputs = terrain.policy_inputs(heightmap, kin_contacts)
    o = policy.from_features(features, kin_features, state, kin_state, terrain_inputs)
    target = target_rotations(o + noise * policy.dof_mask, kin_joint_rot, alpha)
    s, _ = world_model.step_from_features(state, features, target, heightmap)
    return s.pos, s.rot, s.vel, s.angvel, o


@dataclass
class Steps:
    """The step functions a rollout calls: the plain ones, or their ``torch.compile`` versions."""

    world: Callable[..., WorldOutputs] = world_model_step
    policy: Callable[..., tuple[Tensor, Tensor, Tensor, Tensor, Tensor]] = policy_world_step


def bf16_autocast(step: Callable[..., tuple[Tensor, ...]], device_type: str) -> Callable[..., tuple[Tensor, ...]]:
    """``step`` with the networks' layers in bf16 and float32 outputs.

    Autocast moves only matrix products (``nn.Linear``) to bf16; the rotations, features and the integrator here
    are element-wise, so they stay float32 (a network's bf16 output meets a float32 normaliser and is promoted back).

    Args:
        step: :func:`world_model_step` or :func:`policy_world_step`.
        device_type: ``"cpu"`` or ``"cuda"``.
    """

    def autocast_step(*args: object) -> tuple[Tensor, ...]:
        with torch.autocast(device_type, dtype=torch.bfloat16):
            out = step(*args)
        return tuple(None if x is None else x.float() for x in out)

    return autocast_step


def make_steps(compile_world: bool = False, compile_policy: bool = False, bf16_world: bool = False,
               bf16_policy: bool = False, device_type: str = "cpu", backend: str = "inductor") -> Steps:  # fmt: skip
    """The step functions, each optionally under bf16 autocast and through ``torch.compile``.

    ``torch.compile`` fuses the many small element-wise operations of the rotations, the features and the
    integrator into a few kernels, forward and backward: the policy step runs about twice as fast on a 2-core CPU.
    Shapes are fixed (batch and body counts never change in a run). The first call of each compiles (a minute or
    two on a CPU, seconds with a warm cache; the learner does it before the training clock starts) and needs a C++
    compiler on the CPU.

    Args:
        compile_world, compile_policy: Compile :func:`world_model_step` / :func:`policy_world_step`.
        bf16_world, bf16_policy: Run that step under :func:`bf16_autocast`.
        device_type: The networks' device type (for autocast).
        backend: ``torch.compile`` backend; ``"eager"`` captures the graphs without generating code (tests).
    """
    world: Callable[..., WorldOutputs] = world_model_step
    policy: Callable[..., tuple[Tensor, Tensor, Tensor, Tensor, Tensor]] = policy_world_step
    if bf16_world:
        world = bf16_autocast(world, device_type)
    if bf16_policy:
        policy = bf16_autocast(policy, device_type)
    if compile_world:
        world = torch.compile(world, dynamic=False, backend=backend)
    if compile_policy:
        policy = torch.compile(policy, dynamic=False, backend=backend)
    return Steps(world=world, policy=policy)


def compile_steps(backend: str = "inductor") -> Steps:
    """Both step functions through ``torch.compile`` (see :func:`make_steps`)."""
    return make_steps(compile_world=True, compile_policy=True, backend=backend)


def configured_steps(cfg: SuperTrackConfig) -> Steps:
    """The rollout step functions of a run: under bf16 autocast and compiled where the config asks (warning where
    this machine cannot do either well)."""
    w, p = cfg.world_model, cfg.policy
    compile_world, compile_policy = w.compile, p.compile
    if (
        (compile_world or compile_policy)
        and torch.device(cfg.train.device).type == "cpu"
        and not any(shutil.which(c) for c in (os.environ.get("CXX", "g++"), "g++", "clang++", "c++"))
    ):
        warnings.warn("world_model.compile / policy.compile: no C++ compiler on PATH (torch.compile needs one on "
                      "the CPU); running the rollouts uncompiled, about 2x slower", stacklevel=2)  # fmt: skip
        compile_world = compile_policy = False
    device_type = torch.device(cfg.train.device).type
    if (w.bf16 or p.bf16) and device_type == "cpu" and not native_bf16():
        warnings.warn("world_model.bf16 / policy.bf16: this CPU has neither AVX-512 BF16 nor AMX, so bf16 matrix "
                      "products are emulated (an AVX2-only EPYC here: a 256 x 256 matmul 58x slower than in float32)",
                      stacklevel=2)  # fmt: skip
    return make_steps(compile_world, compile_policy, w.bf16, p.bf16, device_type)


def native_bf16() -> bool:
    """Whether this CPU multiplies bf16 matrices in hardware (torch's own feature checks)."""
    return bool(torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported())


def _fields(state: BodyState) -> Fields:
    return state.pos, state.rot, state.vel, state.angvel


def world_model_rollout(world_model: WorldModel, sim: BodyState, target_rot: Tensor, steps: Steps | None = None,
                        terrain: TerrainInputs | None = None, clip: Tensor | None = None) -> BodyState:  # fmt: skip
    """Open-loop prediction from the first recorded frame with the recorded PD targets (Algorithm 1).

    P_0 = S_0; P_{i+1} = W(P_i, T_i) for i = 0 .. L - 2.

    Args:
        world_model: W.
        sim: Recorded simulated states S_0 .. S_{L-1} (only S_0 is read), fields (B, L, N, k).
        target_rot: Recorded PD target rotations T_0 .. T_{L-1} (the last is unused). Shape: (B, L, J, 4).
        steps: Step functions (default: plain).
        terrain: The terrain inputs, when W reads a heightmap.
        clip: Each window's clip (its terrain). Shape: (B,).

    Returns:
        Predicted P_1 .. P_{L-1}, fields (B, L - 1, N, k).
    """
    return world_model_prediction(world_model, sim, target_rot, steps, terrain, clip).predicted


@dataclass
class WorldRollout:
    """What :func:`world_model_prediction` produced.

    Attributes:
        predicted: P_1 .. P_{L-1}, fields (B, L - 1, N, k).
        contacts: W's contact logits of P_1 .. P_{L-1}, or None when W predicts none. Shape: (B, L - 1, N).
    """

    predicted: BodyState
    contacts: Tensor | None


def world_model_prediction(world_model: WorldModel, sim: BodyState, target_rot: Tensor, steps: Steps | None = None,
                           terrain: TerrainInputs | None = None,
                           clip: Tensor | None = None) -> WorldRollout:  # fmt: skip
    """:func:`world_model_rollout` with W's contact logits of every predicted frame. Arguments as there."""
    step = (steps or Steps()).world
    length = target_rot.shape[1]
    state = _fields(sim.time(0))
    predicted, contacts = [], []
    for i in range(length - 1):
        *state, logits = step(world_model, *state, target_rot[:, i], terrain, clip)
        predicted.append(BodyState(*state))
        contacts.append(logits)
    return WorldRollout(BodyState.stack(predicted), None if contacts[0] is None else torch.stack(contacts, dim=1))


@dataclass
class PolicyRollout:
    """What :func:`policy_rollout` produced.

    Attributes:
        predicted: P_1 .. P_L, fields (B, L, N, k).
        offsets: Offsets o before noise. Shape: (B, L, J, 3).
    """

    predicted: BodyState
    offsets: Tensor


def policy_rollout(policy: Policy, world_model: WorldModel, sim0: BodyState, kin_next: BodyState,
                   kin_next_joint_rot: Tensor, noise: Tensor, alpha: float, steps: Steps | None = None,
                   terrain: TerrainInputs | None = None, clip: Tensor | None = None,
                   kin_contacts: Tensor | None = None) -> PolicyRollout:  # fmt: skip
    """The policy drives W from a recorded state along the recorded reference (Algorithm 2).

    For i = 0 .. L - 1: o_i = Pi(P_i, K_{i+1}); T_i = quat_from_rotvec(alpha (o_i + noise_i)) * k_{i+1} (noise only
    on the components the policy outputs: a revolute joint's +y);
    P_{i+1} = W(P_i, T_i); P_0 = S_0. W's parameters are frozen here, so the loss trains only the policy.

    Args:
        policy: The policy.
        world_model: W.
        sim0: S_0, fields (B, N, k).
        kin_next: K_1 .. K_L, fields (B, L, N, k).
        kin_next_joint_rot: Reference joint rotations k_1 .. k_L. Shape: (B, L, J, 4).
        noise: Exploration noise already scaled by sigma. Shape: (B, L, J, 3).
        alpha: Offset scale (rad).
        steps: Step functions (default: plain).
        terrain: The terrain inputs, when the networks read any.
        clip: Each window's clip (its terrain). Shape: (B,).
        kin_contacts: The reference's contact labels at every step, when the policy reads them. Shape: (B, L, K, N).
    """
    if policy.local_norm is not world_model.local_norm:
        raise ValueError("the policy and the world model must share one Local() normaliser")
    step = (steps or Steps()).policy
    length = kin_next_joint_rot.shape[1]
    kin_features = policy.features(kin_next)
    state = _fields(sim0)
    predicted, offsets = [], []
    with frozen(world_model):
        for i in range(length):
            *state, o = step(policy, world_model, tuple(state), kin_features[:, i], _fields(kin_next.time(i)),
                             kin_next_joint_rot[:, i], noise[:, i], alpha, terrain, clip,
                             None if kin_contacts is None else kin_contacts[:, i])  # fmt: skip
            predicted.append(BodyState(*state))
            offsets.append(o)
    return PolicyRollout(predicted=BodyState.stack(predicted), offsets=torch.stack(offsets, dim=1))
