"""PPO acting in the gym: PD targets from actions, and :class:`GymActor`, the :class:`common.sim.collect.FrameActor`
with which the collector steps the characters.

A frame (the step from gym state s_t): the actor observes s_t (:mod:`common.sim.observation`), adds the observations
to its copy of the normaliser's statistics, acts on the normalised observation with the learner's noise eps
(a = mu + sigma * eps, PD targets = reference hinge angles of the next frame + action_scale * clip(a)) and stores the
normalised observation, a, log pi(a) and V(s_t) (the collector adds the clip). After the step it adds the reward,
V of the state a truncated episode reached (``bootstrap_value``, 0 elsewhere) and, at a rollout's last step, V of
every state reached (``next_value``, GAE's value after the rollout; 0 in the other rows). It reports each step's
observation moments (:meth:`GymActor.block_report`); the learner adds them to its own normaliser in the same order,
so that its statistics are the ones the actor used.

With AMP on (``amp``), a frame also holds the discriminator's features (:class:`ppo.amp_data.AMPFeatures`, raw) of
the state s_t the step starts from (``amp_obs``) and of the state it reached, before any reset (``amp_next``, from
the step's ``final_sim``): the policy's transition [s_t, s_t+1] never crosses an episode's end.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

from common.character.humanoid import Humanoid
from common.motion.library import MotionLibrary
from common.sim.gym import StepResult
from common.sim.observation import ObservationConfig, Observer
from ppo.amp_data import AMPFeatures
from ppo.config import AMPConfig, NetworkConfig
from ppo.networks import ActorCritic
from ppo.normalizer import Moments, RunningNormalizer, moments

NET_PREFIX = "net."


def pd_targets(reference: np.ndarray, action: np.ndarray, network: NetworkConfig) -> np.ndarray:
    """targets = reference + action_scale * clip(action). Shapes: (N, A), (N, A) -> (N, A)."""
    if network.action_clip is not None:
        action = np.clip(action, -network.action_clip, network.action_clip)
    return reference + network.action_scale * action


def observation_layout(observe: Observer, library: MotionLibrary) -> dict[str, slice]:
    """Slice of every named feature of the flat observation, measured on clip 0's first frames (the widths depend
    on the model and the observation config only), so that the learner needs no gym of its own."""
    clip, time = np.zeros(1, dtype=np.int64), np.zeros(1)
    features = observe.features(library.query(clip, time), library.query(clip, time + library.dt), time, clip, time)
    out, start = {}, 0
    for key, value in features.items():
        out[key] = slice(start, start + value.shape[-1])
        start += value.shape[-1]
    return out


def frame_fields(obs_size: int, action_size: int, amp_size: int = 0) -> dict[str, tuple[tuple[int, ...], str]]:
    """The fields :class:`GymActor` writes per frame (see the module docstring); ``amp_size``: the width of the AMP
    features (0: AMP off, no AMP fields)."""
    fields = {
        "obs": ((obs_size,), "float32"), "action": ((action_size,), "float32"), "log_prob": ((), "float32"),
        "value": ((), "float32"), "reward": ((), "float64"),
        "bootstrap_value": ((), "float32"), "next_value": ((), "float32"),
    }  # fmt: skip
    if amp_size:
        fields.update({"amp_obs": ((amp_size,), "float32"), "amp_next": ((amp_size,), "float32")})
    return fields


def actor_weights(net: ActorCritic, normalizer: RunningNormalizer) -> dict[str, torch.Tensor]:
    """What a rollout starts from: the network's state dict (keys prefixed ``net.``) and the normaliser's
    statistics (``normalizer.count`` int64, ``normalizer.mean`` and ``normalizer.var`` float64 (D,))."""
    weights = {NET_PREFIX + k: v for k, v in net.state_dict().items()}
    weights["normalizer.count"] = torch.tensor(normalizer.count, dtype=torch.int64)
    weights["normalizer.mean"] = torch.from_numpy(np.asarray(normalizer.mean, dtype=np.float64))
    weights["normalizer.var"] = torch.from_numpy(np.asarray(normalizer.var, dtype=np.float64))
    return weights


class GymActor:
    """PPO's :class:`common.sim.collect.FrameActor`: a copy of the actor-critic and of the normaliser.

    Args:
        humanoid: The model (hinge indices).
        net: An actor-critic of the learner's sizes (its weights are replaced by :meth:`load_weights`).
        normalizer: A normaliser of the learner's settings (its statistics are replaced by :meth:`load_weights`).
        observation: The observation config.
        library: The clips the gym's characters follow (the observation reads future reference frames).
        network: The network config (action scale and clip).
        device: Where the network acts.
        amp: The AMP section when AMP is on (the frames then hold its features); None: off.
    """

    def __init__(self, humanoid: Humanoid, net: ActorCritic, normalizer: RunningNormalizer,
                 observation: ObservationConfig, library: MotionLibrary, network: NetworkConfig,
                 device: str = "cpu", amp: AMPConfig | None = None) -> None:  # fmt: skip
        self.device = torch.device(device)
        self.net = net.to(self.device)
        self.normalizer, self.network = normalizer, network
        self.observe = Observer(observation, humanoid, library)
        self.hinge_qpos = humanoid.hinge_qpos
        self.amp_features = None if amp is None else AMPFeatures(humanoid, amp.end_effectors)
        self._moments: list[Moments] = []

    def load_weights(self, weights: Mapping[str, torch.Tensor]) -> None:
        """Takes :func:`actor_weights` of the learner."""
        net = {k.removeprefix(NET_PREFIX): v for k, v in weights.items() if k.startswith(NET_PREFIX)}
        self.net.load_state_dict(net)
        self.normalizer.count = int(weights["normalizer.count"])
        self.normalizer.mean = weights["normalizer.mean"].cpu().numpy().astype(np.float64, copy=True)
        self.normalizer.var = weights["normalizer.var"].cpu().numpy().astype(np.float64, copy=True)
        self._moments = []

    def _tensor(self, x: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(x, dtype=torch.float32, device=self.device)

    @torch.no_grad()
    def _values(self, norm_obs: np.ndarray) -> np.ndarray:
        """V of normalised observations. (M, D) -> (M,), float32."""
        return self.net.value(self._tensor(norm_obs)).cpu().numpy()

    @torch.no_grad()
    def __call__(self, res: StepResult, rng: np.random.Generator,
                 noise: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:  # fmt: skip
        """PD targets (n, nu) and the frame's fields for the step from ``res`` with standard normal ``noise`` (n, A)
        (drawn by the learner: ``rng`` is not used)."""
        raw = self.observe(res)
        batch = moments(raw)
        self.normalizer.merge(batch)
        self._moments.append(batch)
        norm_obs = self.normalizer.normalize(raw)
        out = self.net.act(self._tensor(norm_obs), self._tensor(noise))
        action = out.action.cpu().numpy()
        targets = pd_targets(res.ref_next.qpos[:, self.hinge_qpos], action.astype(np.float64), self.network)
        fields = {"obs": norm_obs, "action": action, "log_prob": out.log_prob.cpu().numpy(),
                  "value": out.value.cpu().numpy()}  # fmt: skip
        if self.amp_features is not None:
            fields["amp_obs"] = self.amp_features(res.sim)
        return targets, fields

    def after_step(self, res: StepResult, last: bool) -> dict[str, np.ndarray]:
        """The frame's reward, bootstrap value, at the rollout's last step the value after it, and with AMP the
        features of the state the step reached."""
        n = len(res.reward)
        bootstrap = np.zeros(n, dtype=np.float32)
        cut = np.flatnonzero(res.truncated)
        if len(cut):
            bootstrap[cut] = self._values(self.normalizer.normalize(self.observe.final(res, cut)))
        next_value = self._values(self.normalizer.normalize(self.observe(res))) if last else np.zeros(n, np.float32)
        fields = {"reward": res.reward, "bootstrap_value": bootstrap, "next_value": next_value}
        if self.amp_features is not None:
            fields["amp_next"] = self.amp_features(res.final_sim)
        return fields

    def block_report(self) -> list[Moments]:
        """The observation moments of every step of the block, in order (what the normaliser copy added)."""
        out, self._moments = self._moments, []
        return out
