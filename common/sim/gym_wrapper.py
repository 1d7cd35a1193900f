"""A ``gymnasium.vector.VectorEnv`` view of the tracking gym, so that other RL libraries can drive it.

Optional: needs ``pip install gymnasium`` (the ``gym`` extra). Observations are those of the PPO tracker
(:mod:`common.sim.observation`): by default ``parc``, simulated-minus-reference features in the simulated root's
heading frame with reference frames 1, 2, 4, 8 and 16 steps ahead; ``ObservationConfig(kind="local")`` gives the
flattened :func:`common.sim.features.tracking_observation` (Local() of both characters, the reference one frame
ahead, the phase). Actions are PD-target offsets from the reference's next-frame hinge angles, scaled by
``action_scale`` (``action_mode="offset"``, a zero action follows the reference) or absolute hinge targets
(``"absolute"``). Episodes reset in the same step (``AutoresetMode.SAME_STEP``): a finished character's returned
observation is its new episode's first, and ``infos["final_obs"]`` holds the last one.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np

try:
    import gymnasium
    from gymnasium.vector import AutoresetMode, VectorEnv
    from gymnasium.vector.utils import batch_space
except ImportError as e:  # pragma: no cover - exercised only without the optional dependency
    raise ImportError("common.sim.gym_wrapper needs gymnasium: pip install 'mimictrack[gym]'") from e

from common.motion.library import MotionLibrary
from common.sim.gym import GymConfig, StepResult, TrackingGym
from common.sim.observation import ObservationConfig, Observer


class TrackingVectorEnv(VectorEnv):
    """N tracking characters as a gymnasium vector environment.

    Args:
        config: Gym settings (``num_envs`` is the vector size).
        library: Reference clips.
        action_mode: ``offset`` (from the reference, scaled) or ``absolute`` hinge targets (rad).
        action_scale: Radians per unit action in ``offset`` mode.
        observation: Which observation (default: ``parc`` with the PPO default's future frames).
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, config: GymConfig, library: MotionLibrary, action_mode: Literal["offset", "absolute"] = "offset",
                 action_scale: float = 0.5, observation: ObservationConfig | None = None) -> None:  # fmt: skip
        self.gym = TrackingGym(config, library)
        self.observe = Observer(observation or ObservationConfig(), self.gym.humanoid, library)
        self._all = np.arange(config.num_envs)
        self.num_envs = config.num_envs
        self.action_mode = action_mode
        self.action_scale = action_scale
        res = self.gym.reset()
        obs_dim = self.observe(res).shape[1]
        self.single_observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float64)
        bound = 1.0 if action_mode == "offset" else np.pi
        self.single_action_space = gymnasium.spaces.Box(-bound, bound, (self.gym.nu,), np.float64)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._last: StepResult = res

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            self.gym.rng = np.random.default_rng(seed)
        self._last = self.gym.reset()
        res = self._last
        return self.observe(res), {"clip": res.clip, "episode_id": res.episode_id}

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        actions = np.asarray(actions, dtype=np.float64)
        if self.action_mode == "offset":
            targets = self.gym.reference_targets() + self.action_scale * actions
        else:
            targets = actions
        res = self.gym.step(targets)
        self._last = res
        obs = self.observe(res)
        infos: dict[str, Any] = {
            "final_obs": self.observe.final(res, self._all),
            "clip": res.clip,
            "episode_id": res.episode_id,
            **{f"reward/{k}": v for k, v in res.reward_terms.items()},
        }
        return obs, res.reward, res.terminated, res.truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        self.gym.close()
