"""The ``train-ppo`` config: frozen dataclasses loaded from YAML by :mod:`common.config` (unknown keys rejected).

Sections: ``train`` (run length, evaluation; shared with SuperTrack), ``gym`` (characters, termination, reward),
``observation`` (what the networks see), ``network`` (actor and critic), ``ppo`` (rollouts and the update),
``normalizer`` (observation statistics), ``motion_weights`` (PARC's adaptive clip sampling), ``collect`` (where the
gym steps) and ``amp`` (an adversarial motion prior's reward, off by default).
``configs/ppo/*.yaml`` document every value with its unit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from common.sim.gym import GymConfig
from common.sim.motion_weights import MotionWeightConfig
from common.sim.observation import ObservationConfig
from common.sim.rewards import RewardConfig, TerminationConfig
from common.train.training import TrainConfig


def _ppo_gym() -> GymConfig:
    """PARC-style early termination (the character has failed as soon as it is far off the reference), measured
    against the reference so that it passes every bundled clip, and PARC's reward."""
    return GymConfig(
        termination=TerminationConfig(
            max_episode_frames=300, grace_frames=0, head_height_error=None, root_pos_error=1.0,
            root_rot_error=1.5708, body_pos_error=0.5, root_height_error=0.3, fall_contact="deepmimic",
            contact_clearance=0.1,
        ),
        reward=RewardConfig(preset="parc"),
    )  # fmt: skip


@dataclass(frozen=True)
class NetworkConfig:
    """Actor and critic.

    Attributes:
        actor_hidden: Hidden layer widths of the policy MLP.
        critic_hidden: Hidden layer widths of the value MLP.
        activation: Hidden activation.
        action_scale: Radians of PD-target offset per unit of action: targets = reference hinge angles of the next
            frame + action_scale * action, so a zero action plays the reference back open loop.
        log_std_init: Initial log standard deviation of the Gaussian, in action units.
        learn_std: Learn the log-std (True) or keep it fixed at ``log_std_init`` (DeepMimic, MimicKit, PHC).
        action_clip: Actions are clipped to [-action_clip, action_clip] before they become PD targets (the stored
            action and its log-probability stay unclipped); None: no clipping.
        init_output_gain: Gain of the orthogonal init of the policy's last layer; small so that the initial policy
            stays near the reference.
    """

    actor_hidden: tuple[int, ...] = (256, 256)
    critic_hidden: tuple[int, ...] = (256, 256)
    activation: Literal["relu", "elu", "tanh"] = "relu"
    action_scale: float = 0.5
    log_std_init: float = -1.6
    learn_std: bool = False
    action_clip: float | None = 4.0
    init_output_gain: float = 0.01

    def __post_init__(self) -> None:
        if not self.actor_hidden or not self.critic_hidden or min(self.actor_hidden + self.critic_hidden) < 1:
            raise ValueError("actor_hidden and critic_hidden need at least one layer of positive width")
        if self.action_scale <= 0:
            raise ValueError(f"action_scale must be positive, got {self.action_scale}")
        if self.action_clip is not None and self.action_clip <= 0:
            raise ValueError(f"action_clip must be positive or null, got {self.action_clip}")


@dataclass(frozen=True)
class PPOConfig:
    """Rollouts and the PPO update (Schulman et al. 2017) with GAE (Schulman et al. 2016).

    Attributes:
        rollout_length: Gym steps per iteration; one rollout is rollout_length x num_envs samples.
        epochs: Passes over the rollout per iteration.
        minibatch_size: Samples per gradient step; must divide rollout_length x num_envs.
        gamma: Discount per control step.
        lam: GAE lambda.
        clip_ratio: epsilon of the clipped surrogate, ratio clipped to [1 - eps, 1 + eps].
        value_clip: Clip the new value to old value +- this (PPO2's value clipping); None: plain squared error.
        normalize_advantages: Standardise the rollout's advantages (zero mean, unit std).
        advantage_clip: Clip the (standardised) advantages to +- this; None: no clipping.
        actor_lr: Adam learning rate of the policy (and the log-std).
        critic_lr: Adam learning rate of the value function.
        value_coef: Weight of the value loss (the critic has its own parameters, so it only scales its gradients).
        entropy_coef: Weight of the entropy bonus (useful with a learned log-std only).
        bound_coef: Weight of the action-bound penalty on the policy mean (MimicKit's action bound loss).
        action_bound: The penalty acts on |mean| beyond this, in action units.
        max_grad_norm: Clip the gradient norm of the policy and of the value network, each, to this; None: no
            clipping.
        target_kl: Stop the epochs of an iteration early once the mean approx. KL exceeds this; None: never.
        schedule: ``fixed`` keeps the learning rates; ``adaptive`` is rsl_rl's KL-adaptive rule: before each
            minibatch step, the mean KL(pi_old || pi) of the minibatch's Gaussians (pi_old: the policy that collected
            the rollout) is compared with ``desired_kl``: above 2 x desired both rates are divided by
            ``lr_factor``, below desired / 2 multiplied by it, the actor's kept in [min_lr, max_lr] (the critic's
            keeps its ratio to the actor's).
        desired_kl: The KL per update the adaptive schedule aims at (rsl_rl: 0.01).
        lr_factor: The adaptive schedule's step (rsl_rl: 1.5).
        min_lr: Lower bound of the actor's adaptive rate (rsl_rl: 1e-5).
        max_lr: Upper bound of the actor's adaptive rate (rsl_rl: 1e-2).
    """

    rollout_length: int = 8
    epochs: int = 5
    minibatch_size: int = 512
    gamma: float = 0.99
    lam: float = 0.95
    clip_ratio: float = 0.2
    value_clip: float | None = None
    normalize_advantages: bool = True
    advantage_clip: float | None = 4.0
    actor_lr: float = 1e-4
    critic_lr: float = 1e-3
    value_coef: float = 0.5
    entropy_coef: float = 0.0
    bound_coef: float = 10.0
    action_bound: float = 2.0
    max_grad_norm: float | None = 1.0
    target_kl: float | None = None
    schedule: Literal["fixed", "adaptive"] = "fixed"
    desired_kl: float = 0.01
    lr_factor: float = 1.5
    min_lr: float = 1e-5
    max_lr: float = 1e-2

    def __post_init__(self) -> None:
        if self.rollout_length < 1 or self.epochs < 1 or self.minibatch_size < 1:
            raise ValueError("rollout_length, epochs and minibatch_size must be >= 1")
        if not (0.0 <= self.gamma <= 1.0 and 0.0 <= self.lam <= 1.0):
            raise ValueError(f"gamma and lam must lie in [0, 1], got {self.gamma}, {self.lam}")
        if self.clip_ratio <= 0 or self.actor_lr <= 0 or self.critic_lr <= 0:
            raise ValueError("clip_ratio, actor_lr and critic_lr must be positive")
        if self.desired_kl <= 0 or self.lr_factor <= 1.0 or not 0 < self.min_lr <= self.max_lr:
            raise ValueError(f"the adaptive schedule needs desired_kl > 0, lr_factor > 1 and 0 < min_lr <= max_lr, got "
                             f"{self.desired_kl}, {self.lr_factor}, {self.min_lr}, {self.max_lr}")  # fmt: skip


@dataclass(frozen=True)
class NormalizerConfig:
    """Running mean/std of the observation.

    Attributes:
        clip: Normalised features are clipped to [-clip, clip].
        epsilon: Floor of the standard deviation (features that never vary are only centred).
        exclude: Observation features (names from :mod:`common.sim.observation`) left as they are because they are
            already bounded, e.g. the ``local`` observation's ``phase`` (sin and cos).
        max_samples: Stop updating the statistics after this many samples (MimicKit's normalizer_samples); None:
            update throughout training. Evaluation always uses frozen statistics.
    """

    clip: float = 5.0
    epsilon: float = 1e-2
    exclude: tuple[str, ...] = ()
    max_samples: int | None = None

    def __post_init__(self) -> None:
        if self.clip <= 0 or self.epsilon <= 0:
            raise ValueError("normalizer clip and epsilon must be positive")


@dataclass(frozen=True)
class CollectConfig:
    """Where the gym steps (:mod:`common.sim.collect`).

    Attributes:
        processes: Collector processes beside the learner, each stepping about gym.num_envs / processes characters
            with a CPU copy of the policy and of the observation normaliser. PPO is on-policy: the learner waits for
            every rollout, collected with the weights of the update that follows it (no pipelining), so the
            processes gain only where several gyms in parallel outrun one gym's own threads. The exploration noise
            is drawn by the learner, so 1 gives the numbers of 0 bit for bit (on the CPU). K > 1 gives other
            numbers, as deterministic: process p's gym has seed gym.seed + p (its own episode starts), and within a
            rollout each process adds only its own characters to its normaliser copy (the learner's statistics,
            which every rollout starts from, count all of them). 0: the gym steps in the learner's process, the
            policy acting on ``train.device``.
    """

    processes: int = 0

    def __post_init__(self) -> None:
        if self.processes < 0:
            raise ValueError(f"collect.processes must be >= 0, got {self.processes}")


@dataclass(frozen=True)
class AMPConfig:
    """An adversarial motion prior (Peng et al. 2021): a discriminator D over state transitions [s, s'], trained to tell
    expert (motion library) from policy transitions, whose score becomes a reward added to the task's before GAE:
    r = r_task + weight * r_amp (:mod:`ppo.amp`; formulas and sources in docs/ppo.md, section AMP).

    Attributes:
        weight: lambda_amp of the AMP reward in the total; 0 turns AMP off (no discriminator is built, the rewards
            are the task's). rsl_rl's guideline: 0.1-0.5.
        hidden: Hidden layer widths of the discriminator MLP.
        activation: Its hidden activation (rsl_rl's AMPNet: ELU).
        output: ``tanh`` (score in [-1, 1], trained with the hinge loss max(0, 1 - tanh(x) label), labels +-1) or
            ``sigmoid`` (score in [0, 1], binary cross-entropy on the logit x, labels 1 and 0).
        label_smoothing: Expert labels 1 - ls, policy labels -1 + ls (tanh) or ls (sigmoid); in [0, 0.5).
        reward: ``rsl_rl`` (the saturated cross-entropy r = max(-log(max(1 - score - label_smoothing,
            reward_epsilon)) - reward_shift, reward_min)) or ``mimickit`` (r = -log(max(1 - sigmoid(x),
            reward_epsilon)) * reward_scale; needs ``output: sigmoid``).
        reward_shift: rsl_rl's shift of the reward (0.45).
        reward_epsilon: Floor of the argument of the log (1e-4 in both forms).
        reward_min: rsl_rl's clamp of the reward from below (-0.1).
        reward_scale: MimicKit's disc_reward_scale (2).
        lr: Adam learning rate of the discriminator.
        lambda_gp: Weight of the gradient penalty E ||d x / d input||^2 on expert inputs (x the raw output).
        logit_reg: Weight of MimicKit's logit regularisation, the squared output layer weights (0.01 there).
        weight_decay: Weight of MimicKit's weight decay, the squared weights of every layer, added to the loss
            (1e-4 there).
        buffer_size: Policy transitions the replay buffer holds.
        replay_samples: Transitions of each rollout the replay buffer takes once it is full (until then, all of
            them; MimicKit's disc_replay_samples).
        batch_size: Policy transitions per discriminator step: half from the latest rollout, half from the replay
            buffer (MimicKit).
        expert_batch: Expert transitions per discriminator step, drawn from the motion library at random clips and
            grid times.
        updates_per_iteration: Discriminator Adam steps per iteration (after PPO's update of the iteration).
        end_effectors: Add the hands' and feet's positions in the root frame to the features.
        still_std: Features whose standard deviation over every frame of the motion library is below this are zeroed
            before the discriminator sees them: the reference holds them still, the simulation cannot, so they alone
            would tell the two apart (walk's neck hinges: std < 0.001 rad/s in the clip, 0.5-0.7 rad/s simulated; see
            ``benchmarks/amp_separability.py``). 0 keeps every feature.
    """

    weight: float = 0.0
    hidden: tuple[int, ...] = (256, 256)
    activation: Literal["relu", "elu", "tanh"] = "elu"
    output: Literal["tanh", "sigmoid"] = "tanh"
    label_smoothing: float = 0.0
    reward: Literal["rsl_rl", "mimickit"] = "rsl_rl"
    reward_shift: float = 0.45
    reward_epsilon: float = 1e-4
    reward_min: float = -0.1
    reward_scale: float = 2.0
    lr: float = 1e-4
    lambda_gp: float = 1.0
    logit_reg: float = 0.0
    weight_decay: float = 0.0
    buffer_size: int = 50_000
    replay_samples: int = 1000
    batch_size: int = 512
    expert_batch: int = 512
    updates_per_iteration: int = 20
    end_effectors: bool = True
    still_std: float = 1e-3

    def __post_init__(self) -> None:
        if not self.still_std >= 0.0:
            raise ValueError(f"amp.still_std must be >= 0, got {self.still_std}")
        if not self.weight >= 0.0:
            raise ValueError(f"amp.weight must be >= 0 (0: off), got {self.weight}")
        if not self.hidden or min(self.hidden) < 1:
            raise ValueError("amp.hidden needs at least one layer of positive width")
        if not 0.0 <= self.label_smoothing < 0.5:
            raise ValueError(f"amp.label_smoothing must lie in [0, 0.5), got {self.label_smoothing}")
        if self.reward == "mimickit" and self.output != "sigmoid":
            raise ValueError("amp.reward: mimickit reads the logit of a sigmoid output; set amp.output: sigmoid")
        if self.reward_epsilon <= 0 or self.lr <= 0:
            raise ValueError("amp.reward_epsilon and amp.lr must be positive")
        if min(self.lambda_gp, self.logit_reg, self.weight_decay) < 0:
            raise ValueError("amp.lambda_gp, amp.logit_reg and amp.weight_decay must be >= 0")
        if min(self.buffer_size, self.replay_samples, self.expert_batch, self.updates_per_iteration) < 1:
            raise ValueError("amp.buffer_size, replay_samples, expert_batch and updates_per_iteration must be >= 1")
        if self.batch_size < 2:
            raise ValueError(f"amp.batch_size must be >= 2 (half rollout, half replay), got {self.batch_size}")

    @property
    def enabled(self) -> bool:
        return self.weight > 0.0


@dataclass(frozen=True)
class PPOTrackerConfig:
    """Everything ``train-ppo`` reads from its YAML file."""

    train: TrainConfig = field(default_factory=TrainConfig)
    gym: GymConfig = field(default_factory=_ppo_gym)
    observation: ObservationConfig = field(default_factory=ObservationConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    normalizer: NormalizerConfig = field(default_factory=NormalizerConfig)
    motion_weights: MotionWeightConfig = field(default_factory=MotionWeightConfig)
    collect: CollectConfig = field(default_factory=CollectConfig)
    amp: AMPConfig = field(default_factory=AMPConfig)

    def __post_init__(self) -> None:
        if self.collect.processes > self.gym.num_envs:
            raise ValueError(f"collect.processes ({self.collect.processes}) exceeds gym.num_envs ({self.gym.num_envs})")
        if self.batch_size % self.ppo.minibatch_size != 0:
            raise ValueError(
                f"ppo.minibatch_size ({self.ppo.minibatch_size}) must divide the rollout of "
                f"ppo.rollout_length x gym.num_envs = {self.ppo.rollout_length} x {self.gym.num_envs} = "
                f"{self.batch_size} samples"
            )

    @property
    def batch_size(self) -> int:
        """Samples per rollout (rollout_length x num_envs)."""
        return self.ppo.rollout_length * self.gym.num_envs

    @property
    def num_minibatches(self) -> int:
        return self.batch_size // self.ppo.minibatch_size
