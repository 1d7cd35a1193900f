"""The ``train-supertrack`` config: frozen dataclasses loaded from ``configs/supertrack/*.yaml``.

Paper values (Fussell et al. 2021, Table 1 and section 5) are the defaults here and in ``paper.yaml``; the CPU
default and the debug preset shrink networks, batches and the gym.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from common.sim.gym import GymConfig
from common.sim.motion_weights import MotionWeightConfig
from common.train.training import TrainConfig


@dataclass(frozen=True)
class WorldLossWeights:
    """Weights of the world model's L1 world-space terms (paper: tuned so that they start about equal).

    Attributes:
        pos: Per metre of body position error.
        vel: Per m/s of body linear velocity error.
        rot: Per radian of body rotation error (components of log(q_pred * inv(q_true))).
        angvel: Per rad/s of body angular velocity error.
    """

    pos: float = 20.0
    vel: float = 1.0
    rot: float = 5.0
    angvel: float = 0.25


@dataclass(frozen=True)
class PolicyLossWeights:
    """Weights of the policy's L1 local-space tracking terms and of the offset regularisers.

    Attributes:
        pos: Per metre of root-relative body position error.
        vel: Per m/s of root-frame body velocity error.
        rot: Per unit of two-axis rotation error.
        angvel: Per rad/s of root-frame angular velocity error.
        height: Per metre of body height error.
        up: Per unit of root-frame up vector error.
        offset_l1: Weight of mean |o| (o: the network's offsets before noise).
        offset_l2: Weight of mean o^2.
        offset_rate: Weight of mean |o_{i+1} - o_i| over the window (not in the paper; 0 turns it off): keeps the
            PD targets from chattering frame to frame.
        root_pos: Per metre of world-space root position error (not in the paper, whose loss is local only and so
            lets the character drift; 0 turns it off).
        root_rot: Per radian of world-space root rotation error (components of log(q_pred * inv(q_ref))).
        root_heading: Per radian of its vertical component alone, the turn about world +Z (not in the paper). Local()
            cannot see heading, and root_rot gives it a third of its mean: on run (session 6) the root turned 3-5 deg
            off within 16 frames and went 13 cm sideways by frame 30 (``benchmarks/root_drift.py``).
    """

    pos: float = 10.0
    vel: float = 1.0
    rot: float = 3.0
    angvel: float = 0.1
    height: float = 10.0
    up: float = 3.0
    offset_l1: float = 0.01
    offset_l2: float = 0.01
    offset_rate: float = 0.0
    root_pos: float = 0.0
    root_rot: float = 0.0
    root_heading: float = 0.0


@dataclass(frozen=True)
class WorldModelConfig:
    """The world model W and its training (Algorithm 1).

    Attributes:
        hidden: Hidden layer widths (ELU).
        batch: Windows per step.
        window: Frames per window (the rollout predicts window - 1 frames from the first).
        lr: RAdam learning rate.
        grad_clip: Maximum gradient norm; None disables clipping.
        init_scale: Scale of the output layer's initial weights (small: W starts at the mean reference acceleration
            instead of random accelerations of a few normaliser stds).
        steps_per_iteration: W steps per iteration (the paper: 1).
        weights: Loss weights.
        compile: Run the rollout step through ``torch.compile`` (about 2x faster on a CPU; needs a C++ compiler
            there; it compiles before the training clock starts, a minute or two, logged as ``perf/compile_s``).
        bf16: Run W's layers under bf16 autocast in its update step (integration, loss and optimiser stay float32).
    """

    hidden: tuple[int, ...] = (1024, 1024, 1024, 1024, 1024)
    batch: int = 2048
    window: int = 8
    lr: float = 1e-3
    grad_clip: float | None = 1.0
    init_scale: float = 0.01
    steps_per_iteration: int = 1
    weights: WorldLossWeights = field(default_factory=WorldLossWeights)
    compile: bool = False
    bf16: bool = False

    def __post_init__(self) -> None:
        if self.window < 2 or self.batch < 1 or not self.hidden or self.steps_per_iteration < 1:
            raise ValueError("world_model needs window >= 2, batch >= 1, steps_per_iteration >= 1 and a hidden layer")


@dataclass(frozen=True)
class PolicyConfig:
    """The policy and its training through W (Algorithm 2).

    Attributes:
        hidden: Hidden layer widths (ELU).
        batch: Windows per step.
        window: Frames rolled out through W per window.
        lr: RAdam learning rate.
        grad_clip: Maximum gradient norm; None disables clipping.
        sigma: Exploration noise std added to the offsets o, in the gym and in training.
        alpha_deg: Offset scale alpha in degrees: target = quat_from_rotvec(alpha * o_hat) * k_next.
        init_scale: Scale of the output layer's initial weights (small: start near open-loop playback).
        start_iteration: Iterations of world-model-only training before the first policy step (the paper: 0), so
            that the policy does not learn from, and exploit, a world model that knows nothing yet.
        weights: Loss weights.
        root_offset: The policy also reads where the reference root is relative to the simulated one
            (``supertrack.models.root_offset_features``); the paper's policy does not, and cannot correct drift.
        compile: Run the rollout step through ``torch.compile`` (as ``world_model.compile``).
        bf16: Run the networks' layers under bf16 autocast in the policy's update step (the policy and W's forward
            through which it learns) and in the gym's actor (on the CPU only with AVX-512 BF16 or AMX); the rollout's
            integration, the loss and the optimiser stay float32.
        step_decay: Weight decay^i of rollout step i in the tracking loss (ControlVAE: 0.95; the paper: 1, a plain
            mean), so that the later steps, where W's error has compounded, pull less.
        average_decay: Decay of an exponential moving average of the policy's weights (Polyak averaging,
            :class:`common.train.averaging.WeightAverage`) that evaluation, the report and export use instead of the
            live weights; the gym still acts with the live ones. 0 (the paper): no average, the live weights are
            evaluated.
        concurrent: Run the policy step in a second thread beside the iteration's W steps, through a copy of W taken
            at the start of the iteration (so the policy learns through W one iteration old; the paper's loop and
            the default step them one after the other, through the newest W). Uses a second core for the updates;
            with ``torch_threads`` 1 each step runs on its own core.
    """

    hidden: tuple[int, ...] = (1024, 1024, 1024, 1024, 1024)
    batch: int = 1024
    window: int = 32
    lr: float = 1e-4
    grad_clip: float | None = 1.0
    sigma: float = 0.1
    alpha_deg: float = 120.0
    init_scale: float = 0.01
    start_iteration: int = 0
    weights: PolicyLossWeights = field(default_factory=PolicyLossWeights)
    root_offset: bool = False
    compile: bool = False
    bf16: bool = False
    step_decay: float = 1.0
    average_decay: float = 0.0
    concurrent: bool = False

    def __post_init__(self) -> None:
        if self.window < 1 or self.batch < 1 or not self.hidden:
            raise ValueError("policy needs window >= 1, batch >= 1 and at least one hidden layer")
        if not 0.0 < self.step_decay <= 1.0:
            raise ValueError(f"policy.step_decay must be in (0, 1], got {self.step_decay}")
        if not 0.0 <= self.average_decay < 1.0:
            raise ValueError(f"policy.average_decay must be in [0, 1), got {self.average_decay}")
        if self.sigma < 0 or self.alpha_deg <= 0:
            raise ValueError("policy.sigma must be >= 0 and policy.alpha_deg > 0")

    @property
    def alpha(self) -> float:
        """Offset scale in radians."""
        return math.radians(self.alpha_deg)


@dataclass(frozen=True)
class BufferConfig:
    """Replay storage.

    Attributes:
        capacity: Frames kept for training (paper: about 150k).
        val_envs: Characters whose frames go to a small held-back buffer for world-model diagnostics only.
        val_capacity: Frames of the held-back buffer.
        normalizer_min_std: Floor of every feature's std in the normalisers (units of the feature).
    """

    capacity: int = 150_000
    val_envs: int = 8
    val_capacity: int = 16_384
    normalizer_min_std: float = 0.05

    def __post_init__(self) -> None:
        if self.val_envs < 1:
            raise ValueError("buffer.val_envs must be >= 1 (the diagnostics need held-back frames)")


@dataclass(frozen=True)
class CollectConfig:
    """How the gym feeds the buffer.

    Attributes:
        steps_per_iteration: Gym control steps of all characters per training iteration.
        warmup_steps: Gym control steps before the first update (at least both windows).
        clip_weights: Sampling weight of a clip when an episode starts, by clip name (clips not named: 1; empty:
            uniform). The paper oversampled walk 10x in its locomotion set: ``{walk: 10}``.
        processes: Collector processes beside the learner (:mod:`common.sim.collect`), each stepping about
            gym.num_envs / processes characters with a copy of the policy; iteration k + 1's frames are collected
            with the weights update k starts from while update k runs (deterministic: one seed, one result). 0: the
            gym steps in the learner's process between updates, with the newest weights.
    """

    steps_per_iteration: int = 1
    warmup_steps: int = 64
    clip_weights: dict[str, float] = field(default_factory=dict)
    processes: int = 0

    def __post_init__(self) -> None:
        if self.steps_per_iteration < 1 or self.warmup_steps < 0 or self.processes < 0:
            raise ValueError("collect.steps_per_iteration must be >= 1, warmup_steps >= 0 and processes >= 0")


@dataclass(frozen=True)
class TerrainConfig:
    """What SuperTrack observes and predicts of the ground (issue 59; PARC's tracker's features, off by default).
    Both inputs are raw (not normalised), as PPO's ``parc`` observation leaves them (:mod:`supertrack.terrain`).

    Attributes:
        heightmap_extent: W and the policy read the root's height above the ground at a square grid of points out to
            this distance (m) along the root's heading and across it (PARC: 1.0), each sampled where its input state
            puts the root (in W's rollout, the predicted state); None: no heightmap.
        heightmap_spacing: Distance between the heightmap's points (m; PARC's 0.1).
        contact_weight: W also predicts, per body, whether the next state touches the ground (a logit per body,
            binary cross-entropy against the simulated contacts, weighted by this); 0: no contact output.
        contact_frames: The policy reads the reference's contact labels at t + k dt for every offset k here,
            increasing; empty: none.
        contact_height: A body whose collision geom comes within this height (m) of its clip's ground is in contact
            (the simulated contacts W predicts and the reference's labels: the rule of PPO's labels).
    """

    heightmap_extent: float | None = None
    heightmap_spacing: float = 0.1
    contact_weight: float = 0.0
    contact_frames: tuple[int, ...] = ()
    contact_height: float = 0.03

    def __post_init__(self) -> None:
        c = self.contact_frames
        if c and (min(c) < 1 or list(c) != sorted(set(c))):
            raise ValueError(f"terrain.contact_frames must be distinct positive offsets in increasing order, got "
                             f"{list(c)}")  # fmt: skip
        if not (self.heightmap_spacing > 0 and self.contact_height > 0 and self.contact_weight >= 0):
            raise ValueError(f"terrain.heightmap_spacing and contact_height must be > 0 (m) and contact_weight >= 0, "
                             f"got {self.heightmap_spacing}, {self.contact_height}, {self.contact_weight}")  # fmt: skip
        e = self.heightmap_extent
        if e is not None and not e >= self.heightmap_spacing:
            raise ValueError(f"terrain.heightmap_extent must be >= heightmap_spacing ({self.heightmap_spacing} m), "
                             f"got {e}")  # fmt: skip

    @property
    def enabled(self) -> bool:
        """Any terrain input or output is on."""
        return self.heightmap_extent is not None or self.contact_weight > 0 or bool(self.contact_frames)


@dataclass(frozen=True)
class DiagnosticsConfig:
    """Open-loop world-model error against the simulator, logged with every evaluation.

    Attributes:
        horizons: Frames predicted from a recorded state with the recorded targets.
        batch: Held-back windows measured.
        seed: Seed of the window draw (its own generator, so diagnostics never move the training RNG).
    """

    horizons: tuple[int, ...] = (1, 8, 32)
    batch: int = 256
    seed: int = 12345

    def __post_init__(self) -> None:
        if not self.horizons or min(self.horizons) < 1:
            raise ValueError("diagnostics.horizons must be positive frame counts")


@dataclass(frozen=True)
class SuperTrackConfig:
    """Everything ``train-supertrack`` reads.

    Attributes:
        train: Run length, seed, device, logging, evaluation.
        gym: The characters in the simulator (the gym's seed is offset by train.seed).
        world_model: W.
        policy: The policy.
        buffer: Replay storage.
        collect: Gym steps per iteration.
        motion_weights: PARC's adaptive clip weights for the gym's starts (:mod:`common.sim.motion_weights`, the
            implementation PPO uses), multiplied with ``collect.clip_weights``; off by default.
        diagnostics: World-model error measurement.
        terrain: The heightmap W and the policy read, W's contact prediction and the reference's contact labels the
            policy reads; off by default.
    """

    train: TrainConfig = field(default_factory=TrainConfig)
    gym: GymConfig = field(default_factory=lambda: GymConfig(num_envs=256))
    world_model: WorldModelConfig = field(default_factory=WorldModelConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    buffer: BufferConfig = field(default_factory=BufferConfig)
    collect: CollectConfig = field(default_factory=CollectConfig)
    motion_weights: MotionWeightConfig = field(default_factory=lambda: MotionWeightConfig(enabled=False))
    diagnostics: DiagnosticsConfig = field(default_factory=DiagnosticsConfig)
    terrain: TerrainConfig = field(default_factory=TerrainConfig)

    def __post_init__(self) -> None:
        train_envs = self.gym.num_envs - self.buffer.val_envs
        if train_envs < 1:
            raise ValueError(f"gym.num_envs ({self.gym.num_envs}) must exceed buffer.val_envs ({self.buffer.val_envs})")
        longest = max(self.world_model.window, self.policy.window)
        if self.buffer.capacity // train_envs < 2 * longest:
            raise ValueError(
                f"buffer.capacity ({self.buffer.capacity} frames) holds {self.buffer.capacity // train_envs} steps of "
                f"{train_envs} training characters: fewer than twice the longest window ({longest})"
            )
        if self.buffer.val_capacity // self.buffer.val_envs <= max(self.diagnostics.horizons):
            raise ValueError(
                "buffer.val_capacity must hold more steps per held-back character than the longest horizon"
            )
        if self.collect.processes > self.gym.num_envs:
            raise ValueError(f"collect.processes ({self.collect.processes}) exceeds gym.num_envs ({self.gym.num_envs})")
        if self.collect.warmup_steps < longest:
            raise ValueError(f"collect.warmup_steps must be >= the longest window ({longest})")

    @property
    def train_envs(self) -> int:
        """Characters whose frames train the networks."""
        return self.gym.num_envs - self.buffer.val_envs
