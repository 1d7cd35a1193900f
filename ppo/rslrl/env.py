"""The tracking gym as rsl_rl's ``VecEnv`` (``rsl_rl/env/vec_env.py``, 5.x): what rsl_rl's PPO sees of it.

One ``step(actions)``: PD targets = the reference's hinge angles one frame ahead + scale * clip(a) (our PPO's
:func:`ppo.actor.pd_targets`), one gym step (rewards, termination, RSI resets of the characters whose episode ended),
then the observation of every character's current state (after its reset where one happened) as the observation
group ``policy``, the rewards, ``dones`` = terminated or truncated, and ``extras["time_outs"]`` = truncated (a time
limit or a one-shot clip's end), which rsl_rl bootstraps. The episodes that ended go into the per-clip failure rates
(:class:`common.sim.motion_weights.MotionWeights`); :meth:`GymVecEnv.refresh_clip_weights`, called by the learner at
the start of every rollout, hands their RSI weights to the gym, as our PPO's collector does with every block.

The gym runs on the CPU in float64; rsl_rl receives float32 tensors on ``device``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from common.config import to_dict
from common.sim.collect.charts import add_step, chart_metrics, new_charts
from common.sim.gym import StepResult, TrackingGym
from common.sim.motion_weights import MotionWeights
from common.sim.observation import Observer
from ppo.actor import pd_targets
from ppo.config import NetworkConfig
from ppo.rslrl.config import OBS_GROUP, ActionConfig


class GymVecEnv(VecEnv):
    """N characters of a :class:`common.sim.gym.TrackingGym` as rsl_rl's vectorised environment.

    Args:
        gym: The gym (its first reset is done here).
        observe: The tracking observation (our PPO's, :mod:`common.sim.observation`).
        actions: How an action becomes PD targets.
        motion_weights: The per-clip failure rates the ended episodes update (the gym's RSI weights come from them).
        device: Where rsl_rl's tensors live.
    """

    def __init__(self, gym: TrackingGym, observe: Observer, actions: ActionConfig, motion_weights: MotionWeights,
                 device: str | torch.device = "cpu") -> None:  # fmt: skip
        self.gym, self.observe, self.motion_weights = gym, observe, motion_weights
        self.num_envs, self.num_actions = gym.num_envs, gym.nu
        self.device = torch.device(device)
        frames = gym.config.termination.max_episode_frames
        # rsl_rl reads it only to randomise the first episodes' lengths (which the learner does not ask for); no time
        # limit (looped clips run on): the largest int32.
        self.max_episode_length = int(frames) if frames is not None else int(np.iinfo(np.int32).max)
        self.cfg: dict[str, Any] = to_dict(gym.config)
        # pd_targets reads the action scale and clip of a network section: ours, with rsl_rl's values.
        self._targets = NetworkConfig(action_scale=actions.scale, action_clip=actions.clip)
        self.hinge_qpos = gym.humanoid.hinge_qpos
        self.result: StepResult = gym.reset()
        self.episode_length_buf = self._tensor(self.result.episode_frame, torch.long)
        self.charts = new_charts()

    def _tensor(self, x: np.ndarray, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        return torch.as_tensor(x, dtype=dtype, device=self.device)

    def get_observations(self) -> TensorDict:
        """The observation of every character's current state: group ``policy``, shape (N, D_obs), float32."""
        obs = self._tensor(self.observe(self.result))
        return TensorDict({OBS_GROUP: obs}, batch_size=[self.num_envs], device=self.device)

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict[str, Any]]:
        """One control step of every character.

        Args:
            actions: rsl_rl's actions, unclipped. Shape: (N, A).

        Returns:
            The observations after the step (after RSI where an episode ended), the rewards (N,) float32, ``dones``
            (N,) long (terminated or truncated), and extras: ``time_outs`` (N,) bool (truncated: rsl_rl adds
            gamma V(s_t) to such a step's reward) and ``log`` (the step's mean reward terms, ``/reward/<term>``).
        """
        prev = self.result
        action = actions.detach().to("cpu", torch.float64).numpy()
        res = self.gym.step(pd_targets(prev.ref_next.qpos[:, self.hinge_qpos], action, self._targets))
        self.motion_weights.record(prev.clip, res.terminated, res.truncated)
        add_step(self.charts, res, prev.episode_frame)
        self.result = res
        self.episode_length_buf = self._tensor(res.episode_frame, torch.long)
        extras = {"time_outs": self._tensor(res.truncated, torch.bool),
                  "log": {f"/reward/{k}": float(v.mean()) for k, v in res.reward_terms.items()}}  # fmt: skip
        return self.get_observations(), self._tensor(res.reward), self._tensor(res.done, torch.long), extras

    def refresh_clip_weights(self) -> None:
        """Hands the gym the RSI weights of the failure rates so far (once per rollout, as our PPO)."""
        self.gym.set_clip_weights(self.motion_weights.gym_weights())

    def pop_charts(self) -> dict[str, float]:
        """The shared chart keys (:func:`common.sim.collect.charts.chart_metrics`) of the steps since the last call."""
        charts, self.charts = self.charts, new_charts()
        return chart_metrics(charts)

    def state_dict(self) -> dict[str, Any]:
        """The gym's state (physics, episodes, RNG, clip weights); the failure rates are the learner's to save."""
        return {"gym": self.gym.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.result = self.gym.load_state_dict(state["gym"])
        self.episode_length_buf = self._tensor(self.result.episode_frame, torch.long)
        self.charts = new_charts()

    def close(self) -> None:
        self.gym.close()
