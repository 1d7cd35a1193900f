"""The PPO tracker as a :class:`common.train.training.Learner`: one iteration = collect() a rollout, update() on it.

collect(): ``rollout_length`` gym steps of N characters through the collector (:mod:`common.sim.collect`, in this
process or in ``collect.processes`` worker processes), with the current weights and normaliser statistics and
exploration noise drawn here: the actor (:class:`ppo.actor.GymActor`) observes each state, adds it to the
normaliser's statistics, samples a ~ N(mu, sigma) and sends PD targets = reference hinge angles of the next frame +
action_scale * clip(a). Each row pushed to the cyclic buffer holds the normalised observation, the action, its
log-probability, V(s), the reward, the done flags and, for truncated episodes, V of the state the step reached (the
bootstrap). The learner then adds the rollout's observation statistics to its normaliser, step by step, and the
finished episodes to the per-clip failure rates, whose weights go to the gym with the next rollout.

update(): GAE on ``buffer.latest(rollout_length)``, then ``epochs`` x ``minibatches`` Adam steps on the PPO loss, the
normalised observations being exactly those the policy acted on (the ratio starts at 1).

AMP (``amp.weight`` > 0, :mod:`ppo.amp`): the frames also hold the discriminator's features of each transition; the
rollout goes to the AMP's normaliser and replay buffer with the rollout, GAE reads r_task + weight * r_amp (the AMP
reward under the discriminator as it stands), and the discriminator takes its steps after PPO's. With weight 0 no
discriminator is built and GAE reads the task reward.
"""

from __future__ import annotations

import copy
import functools
from typing import Any

import numpy as np
import torch

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import Policy
from common.motion.library import MotionLibrary
from common.sim.buffer import CyclicBuffer
from common.sim.collect import Block, CollectorSpec, chart_metrics, make_collector
from common.sim.gym import StepResult
from common.sim.motion_weights import MotionWeights
from common.sim.observation import Observer
from common.train.distributed import World
from common.train.training import NanGuard, gym_config
from ppo.actor import GymActor, actor_weights, frame_fields, observation_layout, pd_targets
from ppo.amp import AMP
from ppo.amp_data import AMPFeatures
from ppo.config import PPOTrackerConfig
from ppo.gae import gae
from ppo.losses import adapted_learning_rate, gaussian_kl, ppo_loss
from ppo.networks import ActorCritic
from ppo.normalizer import RunningNormalizer, combine_moments, normalized_mask


class PPOLearner:
    """DeepMimic / PARC-style PPO motion tracker.

    Args:
        config: The full config.
        library: Clips to track.
        humanoid: The model.
        rng: The learner's numpy generator (exploration noise, minibatch order); the trainer saves and restores it.
        world: This process's rank in a data-parallel run (:mod:`common.train.distributed`); default: a single
            process. Each rank collects its own rollout with its own gym and updates on it; the gradients of every
            minibatch step (and the approximate KL of an epoch, with ``ppo.target_kl``) are averaged over the ranks,
            every rank's observation statistics go into the normaliser and its finished episodes into the adaptive
            clip weights, in rank order.

    Raises:
        ValueError: On a config the collector refuses (e.g. more collector processes than characters), or AMP with
            more than one rank.
    """

    def __init__(self, config: PPOTrackerConfig, library: MotionLibrary, humanoid: Humanoid,
                 rng: np.random.Generator, world: World | None = None) -> None:  # fmt: skip
        self.config, self.library, self.humanoid, self.rng = config, library, humanoid, rng
        self.world = World() if world is None else world
        if self.world.distributed and config.amp.enabled:
            raise ValueError("amp.enabled with more than one rank: the AMP discriminator does not train data-parallel "
                             "yet (run AMP in one process)")  # fmt: skip
        self.device = torch.device(config.train.device)
        self.motion_weights = MotionWeights(library.num_clips, config.motion_weights)
        self.num_envs, self.action_size = config.gym.num_envs, humanoid.nu
        self.hinge_qpos = humanoid.hinge_qpos
        self.observe = Observer(config.observation, humanoid, library)
        layout = observation_layout(self.observe, library)
        n = config.normalizer
        self.normalizer = RunningNormalizer(normalized_mask(layout, n.exclude), n.clip, n.epsilon, n.max_samples)
        self.obs_size = self.normalizer.size
        self.net = ActorCritic(self.obs_size, self.action_size, config.network).to(self.device)
        self.world.broadcast_modules(self.net)
        p = config.ppo
        self.optimizer = torch.optim.Adam(
            [{"params": self.net.actor_parameters(), "lr": p.actor_lr},
             {"params": list(self.net.critic.parameters()), "lr": p.critic_lr}]
        )  # fmt: skip
        self.nan_guard = NanGuard({"net": self.net, "optimizer": self.optimizer})
        self.amp: AMP | None = None
        self.amp_size = 0
        if config.amp.enabled:
            features = AMPFeatures(humanoid, config.amp.end_effectors)
            self.amp = AMP(config.amp, features, library, n.clip, n.epsilon, self.device, config.train.seed)
            self.amp_size = features.size
        fields = {
            "obs": ((self.obs_size,), "float32"), "action": ((self.action_size,), "float32"),
            "log_prob": ((), "float32"), "value": ((), "float32"), "reward": ((), "float32"),
            "bootstrap_value": ((), "float32"),
        }  # fmt: skip
        if self.amp is not None:
            fields.update({"amp_obs": ((self.amp_size,), "float32"), "amp_next": ((self.amp_size,), "float32")})
        self.buffer = CyclicBuffer(p.rollout_length * self.num_envs, self.num_envs, fields)
        self.last_value = np.zeros(self.num_envs)
        self.episode_return = np.zeros(self.num_envs)
        self.rollout_stats: dict[str, float] = {}
        self.updates = 0
        self.collector = make_collector(self._collector_spec(library, humanoid), config.collect.processes,
                                        actor_weights(self.net, self.normalizer), pipeline=False)  # fmt: skip

    def _collector_spec(self, library: MotionLibrary, humanoid: Humanoid) -> CollectorSpec:
        """The gym and the actor: in this process it acts on ``train.device``, in a worker process on its CPU."""
        c = self.config
        device = str(self.device) if c.collect.processes == 0 else "cpu"
        factory = functools.partial(GymActor, net=copy.deepcopy(self.net).cpu(),
                                    normalizer=copy.deepcopy(self.normalizer), observation=c.observation,
                                    library=library, network=c.network, device=device,
                                    amp=c.amp if self.amp is not None else None)  # fmt: skip
        return CollectorSpec(gym=gym_config(c), library=library, humanoid=humanoid, actor_factory=factory,
                             fields=frame_fields(self.obs_size, self.action_size, self.amp_size),
                             noise_seed=c.train.seed,
                             max_steps=c.ppo.rollout_length, clip_weights=self._clip_weights(),
                             torch_threads=c.train.torch_threads,
                             inputs={"noise": ((self.action_size,), "float64")},
                             first_source=self.world.first_source(c.collect.processes))  # fmt: skip

    # ----------------------------------------------------------------------------------------------- acting
    def _clip_weights(self) -> np.ndarray | None:
        return self.motion_weights.gym_weights()

    def _tensor(self, x: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(x, dtype=torch.float32, device=self.device)

    def collect(self) -> int:
        """Runs one rollout into the buffer; returns the number of samples (rollout_length x N)."""
        T, N = self.config.ppo.rollout_length, self.num_envs
        # All of the rollout's noise at once: the same draws, in the same order, as one (N, A) draw per step.
        noise = self.rng.standard_normal((T, N, self.action_size))
        block = self.collector.next_block(actor_weights(self.net, self.normalizer), self.updates, T, T,
                                          inputs={"noise": noise}, clip_weights=self._clip_weights())  # fmt: skip
        if block.version != self.updates:
            raise RuntimeError(f"rollout collected with the weights of update {block.version}, not {self.updates}")
        self._store_rollout(block)
        return T * N

    def _store_rollout(self, block: Block) -> None:
        """The rollout into the buffer, its statistics into the normaliser, its ended episodes into the failure
        rates, its transitions into the AMP's statistics and replay buffer, and its charts."""
        f = block.frames
        returns: list[float] = []
        amp_fields = ("amp_obs", "amp_next") if self.amp is not None else ()
        # Every rank's sources' observation moments, in rank then source order (one rank: this block's).
        reports = [report for rank in self.world.all_gather(block.reports) for report in rank]
        for t in range(block.steps):
            self.normalizer.merge(combine_moments([report[t] for report in reports]))
            terminated, truncated = f["terminated"][t], f["truncated"][t]
            self.buffer.push(
                obs=f["obs"][t], action=f["action"][t], log_prob=f["log_prob"][t], value=f["value"][t],
                reward=f["reward"][t], bootstrap_value=f["bootstrap_value"][t], episode_id=f["episode_id"][t],
                terminated=terminated, truncated=truncated, **{k: f[k][t] for k in amp_fields},
            )  # fmt: skip
            self.episode_return += f["reward"][t]
            done = np.flatnonzero(terminated | truncated)
            returns += self.episode_return[done].tolist()
            self.episode_return[done] = 0.0
        self.motion_weights.record_block(self.world.concat_characters(
            {k: f[k] for k in ("clip", "terminated", "truncated")}))
        if self.amp is not None:
            self.amp.add_rollout(f["amp_obs"].reshape(-1, self.amp_size), f["amp_next"].reshape(-1, self.amp_size))
        self.last_value = f["next_value"][-1].astype(np.float64)
        self.rollout_stats = chart_metrics(block.charts)
        if block.charts["episodes"]:
            self.rollout_stats["charts/episode_return"] = float(np.mean(returns))

    # ----------------------------------------------------------------------------------------------- learning
    def rewards(self, data: dict[str, np.ndarray]) -> np.ndarray:
        """The rewards GAE reads for a rollout ``data`` (T, N, ...): the task reward, plus weight x the AMP reward
        of each transition with AMP on (its mean logged as ``amp/reward_mean``). Shape: (T, N), float64."""
        task = data["reward"].astype(np.float64)
        if self.amp is None:
            return task
        d = self.amp_size
        amp = self.amp.reward(data["amp_obs"].reshape(-1, d), data["amp_next"].reshape(-1, d)).reshape(task.shape)
        self.rollout_stats["amp/reward_mean"] = float(amp.mean())
        return task + self.config.amp.weight * amp

    def _rollout_batch(self) -> dict[str, torch.Tensor]:
        """The latest rollout with advantages and returns, flattened to (T * N, ...) tensors."""
        p = self.config.ppo
        data = self.buffer.latest(p.rollout_length)
        advantages, returns = gae(
            self.rewards(data), data["value"].astype(np.float64), self.last_value,
            data["terminated"], data["truncated"], data["bootstrap_value"].astype(np.float64), p.gamma, p.lam,
        )  # fmt: skip
        self.rollout_stats["charts/explained_variance"] = float(
            1.0 - np.var(returns - data["value"]) / max(float(np.var(returns)), 1e-12)
        )
        adv = advantages.reshape(-1)
        if p.normalize_advantages:
            adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        if p.advantage_clip is not None:
            adv = np.clip(adv, -p.advantage_clip, p.advantage_clip)
        flat = {
            "obs": data["obs"].reshape(-1, self.obs_size), "action": data["action"].reshape(-1, self.action_size),
            "log_prob": data["log_prob"].reshape(-1), "value": data["value"].reshape(-1), "advantage": adv,
            "return": returns.reshape(-1),
        }  # fmt: skip
        return {k: self._tensor(v) for k, v in flat.items()}

    def update(self) -> dict[str, float]:
        """epochs x minibatches PPO steps on the latest rollout; returns ``losses/...`` and ``charts/...``."""
        p = self.config.ppo
        batch = self._rollout_batch()
        size = batch["obs"].shape[0]
        sums: dict[str, float] = {}
        steps = 0
        # The Gaussians of the policy that collected the rollout (the weights of this update's start), for the exact
        # KL of each minibatch; the adaptive schedule reads it.
        with torch.no_grad():
            old_mean, old_log_std = self.net.actor(batch["obs"]), self.net.log_std.detach().clone()
        for _ in range(p.epochs):
            order = torch.as_tensor(self.rng.permutation(size), device=self.device)
            epoch_kl = []
            for idx in order.split(p.minibatch_size):
                log_prob, entropy, mean = self.net.evaluate(batch["obs"][idx], batch["action"][idx])
                values = self.net.value(batch["obs"][idx])
                with torch.no_grad():
                    kl = float(gaussian_kl(old_mean[idx], old_log_std, mean, self.net.log_std).mean())
                if p.schedule == "adaptive":
                    # rsl_rl: the KL averaged over the ranks, so that every rank keeps the same rates
                    self._scale_learning_rates(adapted_learning_rate(self.actor_lr, self.world.mean(kl), p))
                loss, metrics = ppo_loss(
                    log_prob, entropy, mean, values, batch["log_prob"][idx], batch["value"][idx],
                    batch["advantage"][idx], batch["return"][idx], p,
                )  # fmt: skip
                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                # Data-parallel: gradients and losses averaged over the ranks (a single process: unchanged), so that
                # a non-finite loss on any rank skips the step on every rank.
                checked = dict(zip(("total", "policy", "value"), self.world.average_gradients(
                    self.net.parameters(), torch.stack([loss, metrics["policy"], metrics["value"]]), "policy"),
                    strict=True))  # fmt: skip
                stats = {"return_mean": float(batch["return"][idx].mean()), "adv_std": float(batch["advantage"].std())}
                if not self.nan_guard.check(checked, stats):
                    continue
                if p.max_grad_norm is not None:
                    # Each network on its own, so that a spike in the critic's gradient (returns of tens) does not
                    # scale down the policy's step.
                    groups = {"actor": self.net.actor_parameters(), "critic": list(self.net.critic.parameters())}
                    for name, params in groups.items():
                        metrics[f"grad_norm_{name}"] = torch.nn.utils.clip_grad_norm_(params, p.max_grad_norm)
                self.optimizer.step()
                for k, v in metrics.items():
                    sums[k] = sums.get(k, 0.0) + float(v)
                sums["kl"] = sums.get("kl", 0.0) + kl
                steps += 1
                epoch_kl.append(float(metrics["approx_kl"]))
            if p.target_kl is not None and self.world.mean(float(np.mean(epoch_kl)) if epoch_kl else 0.0) > p.target_kl:
                break
        self.updates += 1
        out = {f"losses/{k}": v / max(steps, 1) for k, v in sums.items()}
        if self.amp is not None:
            out.update(self.amp.update())
        out["losses/steps"] = float(steps)
        out["charts/action_std"] = float(torch.exp(self.net.log_std).mean())
        out["charts/learning_rate"] = self.actor_lr
        out.update(self.rollout_stats)
        out.update(self.motion_weights.charts())
        return out

    @property
    def actor_lr(self) -> float:
        """The actor's learning rate now (the optimiser's first group; saved with the optimiser's state)."""
        return float(self.optimizer.param_groups[0]["lr"])

    def _scale_learning_rates(self, actor_lr: float) -> None:
        """Sets the actor's rate to ``actor_lr`` and the critic's to keep its configured ratio to the actor's."""
        p = self.config.ppo
        self.optimizer.param_groups[0]["lr"] = actor_lr
        self.optimizer.param_groups[1]["lr"] = actor_lr * p.critic_lr / p.actor_lr

    # ----------------------------------------------------------------------------------------------- evaluation
    def policy(self) -> Policy:
        """A frozen snapshot of the deterministic policy: the mean action under frozen normaliser statistics."""
        actor = copy.deepcopy(self.net.actor).eval()
        normalizer = copy.deepcopy(self.normalizer)
        hinge_qpos, device, observe, network = self.hinge_qpos, self.device, self.observe, self.config.network

        def act(result: StepResult) -> np.ndarray:
            norm_obs = normalizer.normalize(observe(result))
            with torch.no_grad():
                mean = actor(torch.as_tensor(norm_obs, device=device)).double().cpu().numpy()
            return pd_targets(result.ref_next.qpos[:, hinge_qpos], mean, network)

        return act

    def diagnostics(self) -> dict[str, float]:
        """Failure rate of each clip (of the first 20) at evaluation time."""
        return self.motion_weights.clip_charts(self.library.names)

    # ----------------------------------------------------------------------------------------------- state
    def state_dict(self) -> dict[str, Any]:
        """Networks, optimiser, normaliser, failure rates, the collector (gyms), per-character episode returns and,
        with AMP on, the discriminator, its optimiser, normaliser, replay buffer and generator (``amp``)."""
        return {
            "sizes": {"obs": self.obs_size, "action": self.action_size, "num_envs": self.num_envs},
            "net": self.net.state_dict(), "optimizer": self.optimizer.state_dict(),
            "normalizer": self.normalizer.state_dict(), "motion_weights": self.motion_weights.state_dict(),
            "collector": self.collector.state_dict(), "episode_return": self.episode_return.copy(),
            "updates": self.updates, "amp": None if self.amp is None else self.amp.state_dict(),
        }  # fmt: skip

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restores :meth:`state_dict`.

        Raises:
            ValueError: If the checkpoint was written for other observation/action sizes or character counts, or
                with another number of collector processes, or with AMP on where it is off here (or off where on).
        """
        sizes = {"obs": self.obs_size, "action": self.action_size, "num_envs": self.num_envs}
        if state.get("sizes") != sizes:
            raise ValueError(f"checkpoint is for sizes {state.get('sizes')}, this learner has {sizes}")
        if "collector" not in state:
            raise ValueError("the checkpoint was written before PPO collected through common/sim/collect (its gym "
                             "state has another form): it cannot be resumed, but compare-trackers, watch-policy and "
                             "export-policy still read its policy")  # fmt: skip
        if (state.get("amp") is None) != (self.amp is None):
            raise ValueError(f"checkpoint has AMP {'off' if state.get('amp') is None else 'on'}, this config has it "
                             f"{'off' if self.amp is None else 'on'}")  # fmt: skip
        try:
            self.net.load_state_dict(state["net"])
            self.optimizer.load_state_dict(state["optimizer"])
        except (RuntimeError, ValueError, KeyError) as e:
            raise ValueError(f"checkpoint networks do not match this config: {e}") from e
        if self.amp is not None:
            self.amp.load_state_dict(state["amp"])
        self.normalizer.load_state_dict(state["normalizer"])
        self.motion_weights.load_state_dict(state["motion_weights"])
        self.collector.load_state_dict(state["collector"])
        self.episode_return = np.asarray(state["episode_return"], dtype=np.float64).copy()
        self.updates = int(state["updates"])
        self.nan_guard = NanGuard({"net": self.net, "optimizer": self.optimizer})

    def close(self) -> None:
        self.collector.close()
