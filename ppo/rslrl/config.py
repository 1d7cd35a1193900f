"""The ``train-rsl-rl`` config: frozen dataclasses loaded from YAML by :mod:`common.config` (unknown keys rejected).

Sections: ``train`` (run length, evaluation; shared with the other learners), ``gym`` (our PPO's gym: characters,
termination, reward), ``observation`` (our PPO's), ``actions`` (how an action becomes PD targets, as our PPO),
``motion_weights`` (PARC's adaptive clip sampling), and rsl_rl's own runner config, section for section:
``runner`` (its top-level keys), ``actor`` and ``critic`` (its ``MLPModel`` arguments) and ``algorithm`` (the arguments
of ``rsl_rl.algorithms.PPO``). Every rsl_rl value is rsl-rl-lib 5.x's default except those marked "differs" here and
in ``configs/rsl_rl/default.yaml`` (why: docs/rsl-rl.md). :func:`runner_config` writes the dict rsl_rl's
``OnPolicyRunner`` takes. Nothing here imports rsl_rl.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from common.config import to_dict
from common.sim.gym import GymConfig
from common.sim.motion_weights import MotionWeightConfig
from common.sim.observation import ObservationConfig
from common.train.training import TrainConfig
from ppo.config import PPOTrackerConfig

# The one observation group the gym gives (rsl_rl's name for the policy's group); actor and critic both read it.
OBS_GROUP = "policy"


@dataclass(frozen=True)
class ActionConfig:
    """How rsl_rl's action a becomes PD targets: reference hinge angles of the next frame + scale * clip(a), as our
    PPO (:func:`ppo.actor.pd_targets`); a zero action plays the clip back open loop. rsl_rl's Gaussian samples a
    unbounded; the stored action and its log-probability stay unclipped.

    Attributes:
        scale: Radians of PD-target offset per action unit (our PPO's ``network.action_scale``).
        clip: Bound of the action before it becomes PD targets (our PPO's ``network.action_clip``); None: none.
    """

    scale: float = 0.5
    clip: float | None = 4.0

    def __post_init__(self) -> None:
        if not self.scale > 0:
            raise ValueError(f"actions.scale must be positive, got {self.scale}")
        if self.clip is not None and not self.clip > 0:
            raise ValueError(f"actions.clip must be positive or null, got {self.clip}")


@dataclass(frozen=True)
class RunnerConfig:
    """rsl_rl's ``OnPolicyRunner`` keys (the others are its defaults or unused here: logging and saving are the
    shared trainer's).

    Attributes:
        num_steps_per_env: Gym steps per character per iteration: samples per update = this x ``gym.num_envs``
            (rsl_rl has no default; its examples use 24). Differs: our PPO's rollout_length, 8.
        check_for_nan: Refuse NaN observations, rewards or dones from the gym (rsl_rl's default).
    """

    num_steps_per_env: int = 8
    check_for_nan: bool = True

    def __post_init__(self) -> None:
        if self.num_steps_per_env < 1:
            raise ValueError(f"runner.num_steps_per_env must be >= 1, got {self.num_steps_per_env}")


@dataclass(frozen=True)
class DistributionConfig:
    """rsl_rl's ``GaussianDistribution``: a state-independent std, learned.

    Attributes:
        init_std: Initial standard deviation, in action units (rsl_rl: 1.0).
        std_type: ``scalar`` (std learned as is) or ``log`` (log-std learned) (rsl_rl: scalar).
        learn_std: Learn the std (rsl_rl: True).
    """

    init_std: float = 1.0
    std_type: Literal["scalar", "log"] = "scalar"
    learn_std: bool = True

    def __post_init__(self) -> None:
        if not self.init_std > 0:
            raise ValueError(f"init_std must be positive, got {self.init_std}")


@dataclass(frozen=True)
class ModelConfig:
    """rsl_rl's ``MLPModel``: the critic's, and the actor's body (:class:`ActorConfig`).

    Attributes:
        hidden_dims: Hidden layer widths (rsl_rl: 256, 256, 256). Differs: 256, 256 as our PPO's networks.
        activation: Hidden activation, a name rsl_rl resolves (rsl_rl: elu).
        obs_normalization: Empirical observation normalisation inside the model (rsl_rl: False). Differs: True, as
            our PPO normalises its observation (the PARC features mix metres, radians and rad/s).
    """

    hidden_dims: tuple[int, ...] = (256, 256)
    activation: str = "elu"
    obs_normalization: bool = True

    def __post_init__(self) -> None:
        if not self.hidden_dims or min(self.hidden_dims) < 1:
            raise ValueError("hidden_dims needs at least one layer of positive width")


@dataclass(frozen=True)
class ActorConfig(ModelConfig):
    """rsl_rl's actor: an ``MLPModel`` (the fields of :class:`ModelConfig`) with a Gaussian output.

    Attributes:
        distribution: The Gaussian's settings.
    """

    distribution: DistributionConfig = field(default_factory=DistributionConfig)


@dataclass(frozen=True)
class AlgorithmConfig:
    """The arguments of ``rsl_rl.algorithms.PPO``, all at rsl_rl's defaults.

    Attributes:
        num_learning_epochs: Passes over the rollout per iteration.
        num_mini_batches: Minibatches per pass (minibatch = samples per update / this).
        clip_param: epsilon of the clipped surrogate, and of the clipped value loss.
        gamma: Discount per control step.
        lam: GAE lambda.
        value_loss_coef: Weight of the value loss (actor and critic share one Adam).
        entropy_coef: Weight of the entropy bonus.
        learning_rate: Initial Adam learning rate (then adapted with ``schedule: adaptive``).
        max_grad_norm: Gradient norm clip of the actor and of the critic, each.
        optimizer: ``adam``, ``adamw``, ``sgd`` or ``rmsprop``.
        use_clipped_value_loss: PPO2's clipped value loss.
        schedule: ``adaptive`` (learning rate / 1.5 when a minibatch's KL > 2 desired_kl, x 1.5 when < desired_kl / 2,
            kept in [1e-5, 1e-2]) or ``fixed``.
        desired_kl: The KL the adaptive schedule aims at.
        normalize_advantage_per_mini_batch: Standardise advantages per minibatch (False: over the rollout).
    """

    num_learning_epochs: int = 5
    num_mini_batches: int = 4
    clip_param: float = 0.2
    gamma: float = 0.99
    lam: float = 0.95
    value_loss_coef: float = 1.0
    entropy_coef: float = 0.01
    learning_rate: float = 1e-3
    max_grad_norm: float = 1.0
    optimizer: Literal["adam", "adamw", "sgd", "rmsprop"] = "adam"
    use_clipped_value_loss: bool = True
    schedule: Literal["adaptive", "fixed"] = "adaptive"
    desired_kl: float = 0.01
    normalize_advantage_per_mini_batch: bool = False

    def __post_init__(self) -> None:
        if self.num_learning_epochs < 1 or self.num_mini_batches < 1:
            raise ValueError("algorithm.num_learning_epochs and num_mini_batches must be >= 1")
        if not (0.0 <= self.gamma <= 1.0 and 0.0 <= self.lam <= 1.0):
            raise ValueError(f"algorithm.gamma and lam must lie in [0, 1], got {self.gamma}, {self.lam}")
        if min(self.clip_param, self.learning_rate, self.max_grad_norm, self.desired_kl) <= 0:
            raise ValueError("algorithm.clip_param, learning_rate, max_grad_norm and desired_kl must be positive")


def _ppo_gym() -> GymConfig:
    """Our PPO's gym: its termination (PARC's) and reward (PARC's), so that both PPO arms train on one task."""
    return PPOTrackerConfig().gym


@dataclass(frozen=True)
class RslRlConfig:
    """Everything ``train-rsl-rl`` reads from its YAML file."""

    train: TrainConfig = field(default_factory=TrainConfig)
    gym: GymConfig = field(default_factory=_ppo_gym)
    observation: ObservationConfig = field(default_factory=ObservationConfig)
    actions: ActionConfig = field(default_factory=ActionConfig)
    motion_weights: MotionWeightConfig = field(default_factory=MotionWeightConfig)
    runner: RunnerConfig = field(default_factory=RunnerConfig)
    actor: ActorConfig = field(default_factory=ActorConfig)
    critic: ModelConfig = field(default_factory=ModelConfig)
    algorithm: AlgorithmConfig = field(default_factory=AlgorithmConfig)

    def __post_init__(self) -> None:
        if self.batch_size % self.algorithm.num_mini_batches:
            # rsl_rl would drop the remainder of every epoch silently.
            raise ValueError(
                f"algorithm.num_mini_batches ({self.algorithm.num_mini_batches}) must divide the "
                f"rollout of runner.num_steps_per_env x gym.num_envs = {self.batch_size} samples"
            )

    @property
    def batch_size(self) -> int:
        """Samples per update (num_steps_per_env x num_envs)."""
        return self.runner.num_steps_per_env * self.gym.num_envs


def _model(model: ModelConfig) -> dict[str, Any]:
    out: dict[str, Any] = {"class_name": "rsl_rl.models:MLPModel", "hidden_dims": list(model.hidden_dims),
                           "activation": model.activation, "obs_normalization": model.obs_normalization}  # fmt: skip
    if isinstance(model, ActorConfig):
        out["distribution_cfg"] = {"class_name": "rsl_rl.modules:GaussianDistribution",
                                   **to_dict(model.distribution)}  # fmt: skip
    return out


def runner_config(cfg: RslRlConfig) -> dict[str, Any]:
    """The ``train_cfg`` dict of rsl_rl's ``OnPolicyRunner`` (its 5.x layout: ``algorithm``, ``actor``, ``critic``,
    ``obs_groups`` and the runner's own keys)."""
    return {
        "num_steps_per_env": cfg.runner.num_steps_per_env,
        "check_for_nan": cfg.runner.check_for_nan,
        "save_interval": 0,  # unused: the shared trainer writes the checkpoints
        "obs_groups": {"actor": [OBS_GROUP], "critic": [OBS_GROUP]},
        "algorithm": {"class_name": "rsl_rl.algorithms:PPO", **to_dict(cfg.algorithm)},
        "actor": _model(cfg.actor),
        "critic": _model(cfg.critic),
    }
