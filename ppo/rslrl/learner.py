"""rsl_rl's PPO as a :class:`common.train.training.Learner`: one iteration = collect() a rollout, update() on it.

rsl_rl's ``OnPolicyRunner`` is built from the config's runner dict (:func:`ppo.rslrl.config.runner_config`) on the
gym's ``VecEnv`` (:mod:`ppo.rslrl.env`): it resolves the observation groups and builds the actor, the critic, the
rollout storage and ``rsl_rl.algorithms.PPO`` exactly as it does for any environment. Its ``learn(n)`` loop cannot
be stepped by the shared trainer (it runs n iterations, times, logs and saves on its own, and hands back no update
statistics), so collect() and update() drive the runner's algorithm the way ``learn()`` does, line for line:
under ``torch.inference_mode()``, ``num_steps_per_env`` times ``alg.act(obs)`` -> ``env.step`` -> ``check_nan`` ->
``alg.process_env_step``, then ``alg.compute_returns(obs)``; outside it, ``alg.update()``. Evaluation, logging,
checkpoints and the clock are the shared trainer's. The learner adds only what the other learners log: the shared
charts, episode returns, and the update's statistics (:class:`UpdateStats`).
"""

from __future__ import annotations

import contextlib
import io
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import torch
from rsl_rl.runners import OnPolicyRunner
from rsl_rl.utils import check_nan

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import Policy
from common.motion.library import MotionLibrary
from common.sim.gym import StepResult, TrackingGym
from common.sim.motion_weights import MotionWeights
from common.sim.observation import Observer
from common.train.distributed import World
from common.train.training import gym_config
from ppo.actor import pd_targets
from ppo.config import NetworkConfig
from ppo.rslrl.config import OBS_GROUP, RslRlConfig, runner_config
from ppo.rslrl.env import GymVecEnv


class UpdateStats:
    """Per-minibatch statistics of rsl_rl's PPO update, which returns only its mean losses: the exact KL from the
    rollout's policy (the one its adaptive schedule reads), the k3 approximate KL and the clip fraction, as our PPO
    logs them (``losses/kl``, ``losses/approx_kl``, ``losses/clip_frac``).

    It observes without changing a number: it wraps the storage's minibatch generator (to see the batch being
    trained on) and the actor's ``get_output_log_prob``, which ``update()`` calls once per minibatch right after the
    actor's forward pass on it; the statistics are computed from that call's result under ``no_grad`` and consume no
    random numbers. Outside :meth:`recording` (e.g. in ``act()``) nothing is computed.

    Args:
        alg: rsl_rl's PPO.
    """

    def __init__(self, alg: Any) -> None:
        self.alg = alg
        self.rows: list[tuple[float, float, float]] = []
        self._batch: Any = None
        self._recording = False
        batches, log_prob = alg.storage.mini_batch_generator, alg.actor.get_output_log_prob

        def tapped_batches(*args: Any, **kwargs: Any) -> Iterator[Any]:
            for batch in batches(*args, **kwargs):
                self._batch = batch
                yield batch
            self._batch = None

        def tapped_log_prob(outputs: torch.Tensor) -> torch.Tensor:
            out = log_prob(outputs)
            if self._recording and self._batch is not None and outputs is self._batch.actions:
                self._record(out)
            return out

        alg.storage.mini_batch_generator = tapped_batches
        alg.actor.get_output_log_prob = tapped_log_prob

    @contextlib.contextmanager
    def recording(self) -> Iterator[None]:
        """Records the minibatches of the update run inside."""
        self.rows, self._recording = [], True
        try:
            yield
        finally:
            self._recording, self._batch = False, None

    @torch.no_grad()
    def _record(self, log_prob: torch.Tensor) -> None:
        actor, batch = self.alg.actor, self._batch
        log_ratio = log_prob - batch.old_actions_log_prob.squeeze(-1)
        ratio = torch.exp(log_ratio)
        kl = actor.get_kl_divergence(batch.old_distribution_params, actor.output_distribution_params)
        self.rows.append((float(kl.mean()), float(((ratio - 1.0) - log_ratio).mean()),
                          float(((ratio - 1.0).abs() > self.alg.clip_param).float().mean())))  # fmt: skip

    def metrics(self) -> dict[str, float]:
        """Means over the recorded minibatches (empty if none)."""
        if not self.rows:
            return {}
        kl, approx_kl, clip_frac = np.mean(np.asarray(self.rows), axis=0)
        return {"losses/kl": float(kl), "losses/approx_kl": float(approx_kl), "losses/clip_frac": float(clip_frac)}


class RslRlLearner:
    """rsl_rl's PPO on the tracking gym.

    Args:
        config: The full config.
        library: Clips to track.
        humanoid: The model.
        rng: The trainer's numpy generator (saved and restored by it; rsl_rl draws from torch's generator, which the
            trainer saves too).
        world: Must be a single process: rsl_rl's own data-parallel mode (NCCL, ``torchrun``) is not wired to the
            shared trainer's.

    Raises:
        ValueError: With more than one rank.
    """

    def __init__(self, config: RslRlConfig, library: MotionLibrary, humanoid: Humanoid, rng: np.random.Generator,
                 world: World | None = None) -> None:  # fmt: skip
        if world is not None and world.distributed:
            raise ValueError("train-rsl-rl runs in one process: its data-parallel mode is rsl_rl's own (NCCL on "
                             "CUDA) and is not wired to the shared trainer; run it without torchrun")  # fmt: skip
        self.config, self.library, self.humanoid, self.rng = config, library, humanoid, rng
        self.device = torch.device(config.train.device)
        self.motion_weights = MotionWeights(library.num_clips, config.motion_weights)
        gym = TrackingGym(gym_config(config), library, humanoid, clip_weights=self.motion_weights.gym_weights())
        self.observe = Observer(config.observation, humanoid, library)
        self.env = GymVecEnv(gym, self.observe, config.actions, self.motion_weights, self.device)
        # The runner prints its models; the resolved config in the run directory says the same.
        with contextlib.redirect_stdout(io.StringIO()):
            self.runner = OnPolicyRunner(self.env, runner_config(config), log_dir=None, device=str(self.device))
        self.alg = self.runner.alg
        self.alg.train_mode()
        self.stats = UpdateStats(self.alg)
        self.obs = self.env.get_observations().to(self.device)
        self.obs_size, self.action_size = int(self.obs[OBS_GROUP].shape[-1]), self.env.num_actions
        self.episode_return = np.zeros(self.env.num_envs)
        self.rollout_stats: dict[str, float] = {}

    # ----------------------------------------------------------------------------------------------- learning
    def collect(self) -> int:
        """One rollout of ``runner.num_steps_per_env`` steps into rsl_rl's storage, then its returns and advantages
        (``OnPolicyRunner.learn``'s rollout); returns the samples (steps x N)."""
        steps, check = self.config.runner.num_steps_per_env, self.config.runner.check_for_nan
        start = time.perf_counter()
        returns: list[float] = []
        self.env.refresh_clip_weights()
        with torch.inference_mode():
            for _ in range(steps):
                actions = self.alg.act(self.obs)
                obs, rewards, dones, extras = self.env.step(actions.to(self.env.device))
                if check:
                    check_nan(obs, rewards, dones)
                obs, rewards, dones = obs.to(self.device), rewards.to(self.device), dones.to(self.device)
                self.alg.process_env_step(obs, rewards, dones, extras)
                self.obs = obs
                self.episode_return += rewards.double().cpu().numpy()
                ended = np.flatnonzero(dones.cpu().numpy())
                returns += self.episode_return[ended].tolist()
                self.episode_return[ended] = 0.0
            self.alg.compute_returns(self.obs)
        self.rollout_stats = self.env.pop_charts()
        self.rollout_stats["perf/collect_s"] = time.perf_counter() - start
        if returns:
            self.rollout_stats["charts/episode_return"] = float(np.mean(returns))
        return steps * self.env.num_envs

    def update(self) -> dict[str, float]:
        """rsl_rl's ``alg.update()`` on the rollout; returns its mean losses as ``losses/value``,
        ``losses/surrogate``, ``losses/entropy``, the minibatch statistics (:class:`UpdateStats`), the learning rate
        after the update (``charts/learning_rate``), the explained variance of the rollout's values, the action std
        and the rollout's charts."""
        storage = self.alg.storage
        values, targets = storage.values.flatten(), storage.returns.flatten()
        explained = 1.0 - float(torch.var(targets - values)) / max(float(torch.var(targets)), 1e-12)
        with self.stats.recording():
            losses = self.alg.update()
        self.runner.current_learning_iteration += 1
        out = {f"losses/{k}": float(v) for k, v in losses.items()}
        out.update(self.stats.metrics())
        out["charts/learning_rate"] = float(self.alg.learning_rate)
        out["charts/explained_variance"] = explained
        out["charts/action_std"] = float(self.alg.get_policy().output_std.detach().mean())
        out.update(self.rollout_stats)
        out.update(self.motion_weights.charts())
        return out

    # ----------------------------------------------------------------------------------------------- evaluation
    def policy(self) -> Policy:
        """A frozen snapshot of the deterministic policy (rsl_rl's export copy: its normaliser and MLP, the mean)."""
        return actor_policy(self.alg.get_policy().as_jit().eval(), self.observe, self.humanoid,
                            NetworkConfig(action_scale=self.config.actions.scale,
                                          action_clip=self.config.actions.clip))  # fmt: skip

    def diagnostics(self) -> dict[str, float]:
        """Failure rate of each clip (of the first 20) at evaluation time."""
        return self.motion_weights.clip_charts(self.library.names)

    # ----------------------------------------------------------------------------------------------- state
    def state_dict(self) -> dict[str, Any]:
        """rsl_rl's saved state (actor with its normaliser and std, critic, optimiser), its learning rate and
        iteration, the gym, the failure rates and per-character episode returns. Torch's generator (rsl_rl's
        sampling and minibatch order) is saved by the trainer."""
        return {
            "sizes": {"obs": self.obs_size, "action": self.action_size, "num_envs": self.env.num_envs},
            "actor": self.alg.get_policy().state_dict(), "alg": self.alg.save(),
            "learning_rate": float(self.alg.learning_rate), "iteration": self.runner.current_learning_iteration,
            "env": self.env.state_dict(), "motion_weights": self.motion_weights.state_dict(),
            "episode_return": self.episode_return.copy(),
        }  # fmt: skip

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restores :meth:`state_dict`.

        Raises:
            ValueError: If the checkpoint was written for other observation/action sizes or character counts, or its
                networks do not fit this config.
        """
        sizes = {"obs": self.obs_size, "action": self.action_size, "num_envs": self.env.num_envs}
        if state.get("sizes") != sizes:
            raise ValueError(f"checkpoint is for sizes {state.get('sizes')}, this learner has {sizes}")
        try:
            self.alg.load(state["alg"], load_cfg=None, strict=True)
        except (RuntimeError, ValueError, KeyError) as e:
            raise ValueError(f"checkpoint networks do not match this config: {e}") from e
        self.alg.learning_rate = float(state["learning_rate"])
        self.runner.current_learning_iteration = int(state["iteration"])
        self.env.load_state_dict(state["env"])
        self.motion_weights.load_state_dict(state["motion_weights"])
        self.episode_return = np.asarray(state["episode_return"], dtype=np.float64).copy()
        self.obs = self.env.get_observations().to(self.device)

    def close(self) -> None:
        self.env.close()


def actor_policy(actor: torch.nn.Module, observe: Observer, humanoid: Humanoid, targets: NetworkConfig) -> Policy:
    """The evaluator's policy of an rsl_rl actor's deterministic copy: PD targets = reference hinge angles one frame
    ahead + scale * clip(mean action).

    Args:
        actor: Flat observation (B, D) -> mean action (B, A) (rsl_rl's ``as_jit()`` copy: normaliser and MLP).
        observe: The run's observation.
        humanoid: The model.
        targets: The action scale and clip (a network section of our PPO's, as :func:`ppo.actor.pd_targets` reads).
    """
    hinge_qpos = humanoid.hinge_qpos
    device = next(actor.parameters()).device

    def act(result: StepResult) -> np.ndarray:
        obs = torch.as_tensor(observe(result), dtype=torch.float32, device=device)
        with torch.no_grad():
            mean = actor(obs).double().cpu().numpy()
        return pd_targets(result.ref_next.qpos[:, hinge_qpos], mean, targets)

    return act
