"""The PPO tracker as a :class:`common.train.training.Learner`: one iteration = collect() a rollout, update() on it.

collect(): ``rollout_length`` gym steps of N characters. Each step observes the state (:mod:`common.sim.observation`),
updates the normaliser's statistics, samples a ~ N(mu, sigma) and sends PD targets = reference hinge angles of the
next frame + action_scale * clip(a); the row pushed to the cyclic buffer holds the normalised observation, the
action, its log-probability, V(s), the reward, the done flags and, for truncated episodes, V of the state the step
reached (the bootstrap). Finished episodes update the per-clip failure rates, whose weights go to the gym.

update(): GAE on ``buffer.latest(rollout_length)``, then ``epochs`` x ``minibatches`` Adam steps on the PPO loss, the
normalised observations being exactly those the policy acted on (the ratio starts at 1).
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import torch

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import Policy
from common.motion.library import MotionLibrary
from common.sim.buffer import CyclicBuffer
from common.sim.gym import StepResult, TrackingGym
from common.sim.observation import Observer
from common.train.training import NanGuard, gym_config
from ppo.config import PPOTrackerConfig
from ppo.gae import gae
from ppo.losses import ppo_loss
from ppo.motion_weights import MotionWeights
from ppo.networks import ActorCritic
from ppo.normalizer import RunningNormalizer, normalized_mask

_LOG_CLIP_LIMIT = 20  # clips whose failure rates are logged one by one


class PPOLearner:
    """DeepMimic / PARC-style PPO motion tracker.

    Args:
        config: The full config.
        library: Clips to track.
        humanoid: The model.
        rng: The learner's numpy generator (exploration noise, minibatch order); the trainer saves and restores it.
    """

    def __init__(self, config: PPOTrackerConfig, library: MotionLibrary, humanoid: Humanoid,
                 rng: np.random.Generator) -> None:  # fmt: skip
        self.config, self.library, self.humanoid, self.rng = config, library, humanoid, rng
        self.device = torch.device(config.train.device)
        gym_cfg = gym_config(config)
        self.motion_weights = MotionWeights(library.num_clips, config.motion_weights)
        self.gym = TrackingGym(gym_cfg, library, humanoid, clip_weights=self._clip_weights())
        self.result = self.gym.reset()
        self.num_envs, self.action_size = self.gym.num_envs, humanoid.nu
        self.hinge_qpos = humanoid.hinge_qpos
        self.observe = Observer(config.observation, humanoid, library)
        layout = self.observe.layout(self.result)
        n = config.normalizer
        self.normalizer = RunningNormalizer(normalized_mask(layout, n.exclude), n.clip, n.epsilon, n.max_samples)
        self.obs_size = self.normalizer.size
        self.net = ActorCritic(self.obs_size, self.action_size, config.network).to(self.device)
        p = config.ppo
        self.optimizer = torch.optim.Adam(
            [{"params": self.net.actor_parameters(), "lr": p.actor_lr},
             {"params": list(self.net.critic.parameters()), "lr": p.critic_lr}]
        )  # fmt: skip
        self.nan_guard = NanGuard({"net": self.net, "optimizer": self.optimizer})
        fields = {
            "obs": ((self.obs_size,), "float32"), "action": ((self.action_size,), "float32"),
            "log_prob": ((), "float32"), "value": ((), "float32"), "reward": ((), "float32"),
            "bootstrap_value": ((), "float32"),
        }  # fmt: skip
        self.buffer = CyclicBuffer(p.rollout_length * self.num_envs, self.num_envs, fields)
        self.last_value = np.zeros(self.num_envs)
        self.episode_return = np.zeros(self.num_envs)
        self.rollout_stats: dict[str, float] = {}

    # ----------------------------------------------------------------------------------------------- acting
    def _clip_weights(self) -> np.ndarray | None:
        return self.motion_weights.weights() if self.config.motion_weights.enabled else None

    def _tensor(self, x: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(x, dtype=torch.float32, device=self.device)

    def _pd_targets(self, reference: np.ndarray, action: np.ndarray) -> np.ndarray:
        """targets = reference + action_scale * clip(action). Shapes: (N, A), (N, A) -> (N, A)."""
        net = self.config.network
        if net.action_clip is not None:
            action = np.clip(action, -net.action_clip, net.action_clip)
        return reference + net.action_scale * action

    @torch.no_grad()
    def _values(self, norm_obs: np.ndarray) -> np.ndarray:
        """V of normalised observations. (M, D) -> (M,)."""
        return self.net.value(self._tensor(norm_obs)).double().cpu().numpy()

    def collect(self) -> int:
        """Runs one rollout into the buffer; returns the number of samples (rollout_length x N)."""
        T, N = self.config.ppo.rollout_length, self.num_envs
        lengths, returns, failed = [], [], []
        terms = {k: 0.0 for k in self.config.gym.reward.weights}
        reward_sum = 0.0
        events: dict[str, float] = {}
        for _ in range(T):
            res = self.result
            raw = self.observe(res)
            self.normalizer.update(raw)
            norm_obs = self.normalizer.normalize(raw)
            noise = self._tensor(self.rng.standard_normal((N, self.action_size)))
            with torch.no_grad():
                out = self.net.act(self._tensor(norm_obs), noise)
            action = out.action.cpu().numpy()
            step = self.gym.step(self._pd_targets(self.gym.reference_targets(), action.astype(np.float64)))
            bootstrap = np.zeros(N)
            cut = np.flatnonzero(step.truncated)
            if len(cut):
                bootstrap[cut] = self._values(self.normalizer.normalize(self.observe.final(step, cut)))
            self.buffer.push(
                obs=norm_obs, action=action, log_prob=out.log_prob.cpu().numpy(), value=out.value.cpu().numpy(),
                reward=step.reward, bootstrap_value=bootstrap, episode_id=res.episode_id,
                terminated=step.terminated, truncated=step.truncated,
            )  # fmt: skip
            self.motion_weights.record(res.clip, step.terminated, step.truncated)
            self.episode_return += step.reward
            done = np.flatnonzero(step.done)
            lengths += (res.episode_frame[done] + 1).tolist()
            returns += self.episode_return[done].tolist()
            failed += step.terminated[done].tolist()
            self.episode_return[done] = 0.0
            reward_sum += float(step.reward.mean())
            for k in terms:
                terms[k] += float(step.reward_terms[k].mean())
            for k, v in step.info.items():
                events[k] = events.get(k, 0.0) + v
            self.result = step
        self.last_value = self._values(self.normalizer.normalize(self.observe(self.result)))
        if self.config.motion_weights.enabled:
            self.gym.set_clip_weights(self.motion_weights.weights())
        self.rollout_stats = {"charts/mean_reward": reward_sum / T, **{f"reward/{k}": v / T for k, v in terms.items()}}
        # Episode ends per rule (term/<rule>) and blown-up simulations, per 1000 samples.
        self.rollout_stats.update({f"charts/{k}_per_1k": 1000.0 * v / (T * N) for k, v in events.items()})
        if lengths:
            self.rollout_stats.update({"charts/episode_length": float(np.mean(lengths)),
                                       "charts/episode_return": float(np.mean(returns)),
                                       "charts/episode_fail_rate": float(np.mean(failed))})  # fmt: skip
        return T * N

    # ----------------------------------------------------------------------------------------------- learning
    def _rollout_batch(self) -> dict[str, torch.Tensor]:
        """The latest rollout with advantages and returns, flattened to (T * N, ...) tensors."""
        p = self.config.ppo
        data = self.buffer.latest(p.rollout_length)
        advantages, returns = gae(
            data["reward"].astype(np.float64), data["value"].astype(np.float64), self.last_value,
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
        for _ in range(p.epochs):
            order = torch.as_tensor(self.rng.permutation(size), device=self.device)
            epoch_kl = []
            for idx in order.split(p.minibatch_size):
                log_prob, entropy, mean = self.net.evaluate(batch["obs"][idx], batch["action"][idx])
                values = self.net.value(batch["obs"][idx])
                loss, metrics = ppo_loss(
                    log_prob, entropy, mean, values, batch["log_prob"][idx], batch["value"][idx],
                    batch["advantage"][idx], batch["return"][idx], p,
                )  # fmt: skip
                checked = {"total": loss, "policy": metrics["policy"], "value": metrics["value"]}
                stats = {"return_mean": float(batch["return"][idx].mean()), "adv_std": float(batch["advantage"].std())}
                if not self.nan_guard.check(checked, stats):
                    continue
                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                if p.max_grad_norm is not None:
                    # Each network on its own, so that a spike in the critic's gradient (returns of tens) does not
                    # scale down the policy's step.
                    groups = {"actor": self.net.actor_parameters(), "critic": list(self.net.critic.parameters())}
                    for name, params in groups.items():
                        metrics[f"grad_norm_{name}"] = torch.nn.utils.clip_grad_norm_(params, p.max_grad_norm)
                self.optimizer.step()
                for k, v in metrics.items():
                    sums[k] = sums.get(k, 0.0) + float(v)
                steps += 1
                epoch_kl.append(float(metrics["approx_kl"]))
            if p.target_kl is not None and epoch_kl and np.mean(epoch_kl) > p.target_kl:
                break
        out = {f"losses/{k}": v / max(steps, 1) for k, v in sums.items()}
        out["losses/steps"] = float(steps)
        out["charts/action_std"] = float(torch.exp(self.net.log_std).mean())
        out.update(self.rollout_stats)
        out.update(self._weight_charts())
        return out

    def _weight_charts(self) -> dict[str, float]:
        rate, weights = self.motion_weights.failure_rate, self.motion_weights.weights()
        return {
            "charts/failure_rate_mean": float(rate.mean()), "charts/failure_rate_max": float(rate.max()),
            "charts/clip_weight_min": float(weights.min()), "charts/clip_weight_max": float(weights.max()),
        }  # fmt: skip

    # ----------------------------------------------------------------------------------------------- evaluation
    def policy(self) -> Policy:
        """A frozen snapshot of the deterministic policy: the mean action under frozen normaliser statistics."""
        actor = copy.deepcopy(self.net.actor).eval()
        normalizer = copy.deepcopy(self.normalizer)
        hinge_qpos, device, observe = self.hinge_qpos, self.device, self.observe

        def act(result: StepResult) -> np.ndarray:
            norm_obs = normalizer.normalize(observe(result))
            with torch.no_grad():
                mean = actor(torch.as_tensor(norm_obs, device=device)).double().cpu().numpy()
            return self._pd_targets(result.ref_next.qpos[:, hinge_qpos], mean)

        return act

    def diagnostics(self) -> dict[str, float]:
        """Failure rate of each clip (of the first 20) at evaluation time."""
        rates, names = self.motion_weights.failure_rate, self.library.names[:_LOG_CLIP_LIMIT]
        return {f"charts/failure_rate/{name}": float(rates[i]) for i, name in enumerate(names)}

    # ----------------------------------------------------------------------------------------------- state
    def state_dict(self) -> dict[str, Any]:
        """Networks, optimiser, normaliser, failure rates, the gym and per-character episode returns."""
        return {
            "sizes": {"obs": self.obs_size, "action": self.action_size, "num_envs": self.num_envs},
            "net": self.net.state_dict(), "optimizer": self.optimizer.state_dict(),
            "normalizer": self.normalizer.state_dict(), "motion_weights": self.motion_weights.state_dict(),
            "gym": self.gym.state_dict(), "episode_return": self.episode_return.copy(),
        }  # fmt: skip

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restores :meth:`state_dict`.

        Raises:
            ValueError: If the checkpoint was written for other observation/action sizes or character counts.
        """
        sizes = {"obs": self.obs_size, "action": self.action_size, "num_envs": self.num_envs}
        if state.get("sizes") != sizes:
            raise ValueError(f"checkpoint is for sizes {state.get('sizes')}, this learner has {sizes}")
        try:
            self.net.load_state_dict(state["net"])
            self.optimizer.load_state_dict(state["optimizer"])
        except (RuntimeError, ValueError, KeyError) as e:
            raise ValueError(f"checkpoint networks do not match this config: {e}") from e
        self.normalizer.load_state_dict(state["normalizer"])
        self.motion_weights.load_state_dict(state["motion_weights"])
        self.result = self.gym.load_state_dict(state["gym"])
        self.episode_return = np.asarray(state["episode_return"], dtype=np.float64).copy()
        self.nan_guard = NanGuard({"net": self.net, "optimizer": self.optimizer})

    def close(self) -> None:
        self.gym.close()
