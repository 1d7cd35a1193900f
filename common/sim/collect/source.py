"""The collector's parts that run in any process: the spec, the actor protocol, a block, one gym source, and the
in-process collector (``collect.processes = 0``). See :mod:`common.sim.collect`."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np
import torch

from common.character.humanoid import Humanoid
from common.motion.library import MotionLibrary
from common.sim.buffer import BOOKKEEPING_FIELDS
from common.sim.gym import GymConfig, StepResult, TrackingGym

FieldLayout = Mapping[str, tuple[tuple[int, ...], np.dtype | str]]
Weights = Mapping[str, torch.Tensor]
CHART_KEYS = ("reward_sum", "steps", "episodes", "episode_frames", "terminated", "collect_s")


class CollectorError(RuntimeError):
    """A collector process failed (its traceback is in the message) or died."""


class FrameActor(Protocol):
    """What a learner gives the collector to act with (built in the collecting process)."""

    def load_weights(self, weights: Weights) -> None:
        """Takes the learner's current policy weights (a state dict)."""

    def __call__(self, res: StepResult, rng: np.random.Generator) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """PD targets (N, nu) for the step from ``res`` (noise drawn from ``rng``) and the learner's frame fields
        {name: (N, *shape)} for the frame that starts at ``res``."""


ActorFactory = Callable[[Humanoid], FrameActor]


@dataclass(frozen=True)
class CollectorSpec:
    """Everything a collecting process needs (picklable).

    Attributes:
        gym: The gym of all N characters (its seed already offset by the run's seed).
        library: The reference clips.
        humanoid: The model.
        actor_factory: Builds the actor from the humanoid (a module-level callable or a ``functools.partial``).
        fields: The actor's per-frame fields, name -> (shape, dtype).
        noise_seed: Seed of the exploration-noise generators.
        max_steps: The longest block asked for (gym steps).
        clip_weights: RSI weight per clip (None: uniform).
        torch_threads: Torch threads of a worker process (acting is a small forward pass).
    """

    gym: GymConfig
    library: MotionLibrary
    humanoid: Humanoid
    actor_factory: ActorFactory
    fields: FieldLayout
    noise_seed: int
    max_steps: int
    clip_weights: np.ndarray | None = None
    torch_threads: int = 1

    def layout(self) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
        """The block's fields: the actor's plus the buffer's bookkeeping fields."""
        return {**{k: (tuple(s), np.dtype(d)) for k, (s, d) in self.fields.items()}, **BOOKKEEPING_FIELDS}


@dataclass
class Block:
    """Frames of every character over ``steps`` gym steps.

    Attributes:
        frames: Field -> (T, N, *shape); views valid until the collector's next :meth:`next_block`.
        charts: Sums over the block: ``reward_sum``, ``steps`` (character steps), ``episodes`` (ended),
            ``episode_frames`` (their lengths), ``terminated``, ``collect_s`` (seconds the workers spent stepping,
            summed over workers).
        version: The tag sent with the weights that collected it (e.g. the learner's update count).
    """

    frames: dict[str, np.ndarray]
    charts: dict[str, float]
    version: int

    @property
    def steps(self) -> int:
        return int(self.frames["episode_id"].shape[0])


def character_ranges(num_envs: int, parts: int) -> list[tuple[int, int]]:
    """Character ranges [lo, hi) of ``parts`` workers, as even as possible."""
    edges = np.linspace(0, num_envs, parts + 1).round().astype(int)
    return list(zip(edges[:-1].tolist(), edges[1:].tolist(), strict=True))


class FrameSource:
    """One gym (characters [lo, hi) of the spec's N) and one actor: the unit a worker runs.

    Args:
        spec: The collector spec.
        part: This source's index p.
        parts: Number of sources K.
    """

    def __init__(self, spec: CollectorSpec, part: int = 0, parts: int = 1) -> None:
        lo, hi = character_ranges(spec.gym.num_envs, parts)[part]
        if hi <= lo:
            raise ValueError(f"collect.processes ({parts}) exceeds gym.num_envs ({spec.gym.num_envs})")
        self.part, self.parts = part, parts
        cfg = replace(spec.gym, num_envs=hi - lo, seed=spec.gym.seed + part)
        self.gym = TrackingGym(cfg, spec.library, spec.humanoid, clip_weights=spec.clip_weights)
        self.res = self.gym.reset()
        self.actor = spec.actor_factory(spec.humanoid)
        self.rng = np.random.default_rng([spec.noise_seed, part])

    def collect(self, weights: Weights, steps: int, out: Mapping[str, np.ndarray]) -> dict[str, float]:
        """Steps the gym ``steps`` times with ``weights``, writing rows 0 .. steps - 1 of ``out`` (T, n, *shape)."""
        start = time.perf_counter()
        self.actor.load_weights(weights)
        charts = dict.fromkeys(CHART_KEYS, 0.0)
        for t in range(steps):
            prev = self.res
            targets, fields = self.actor(prev, self.rng)
            res = self.gym.step(targets)
            for name, value in fields.items():
                out[name][t] = value
            out["episode_id"][t] = prev.episode_id * self.parts + self.part
            out["terminated"][t], out["truncated"][t] = res.terminated, res.truncated
            done = res.terminated | res.truncated
            charts["reward_sum"] += float(res.reward.sum())
            charts["steps"] += len(done)
            charts["episodes"] += float(done.sum())
            charts["episode_frames"] += float((prev.episode_frame[done] + 1).sum())
            charts["terminated"] += float(res.terminated.sum())
            self.res = res
        charts["collect_s"] = time.perf_counter() - start
        return charts

    def state_dict(self) -> dict[str, Any]:
        """The gym's state and the noise generator's: all needed to continue exactly."""
        return {"gym": self.gym.state_dict(), "rng": self.rng.bit_generator.state}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        self.res = self.gym.load_state_dict(state["gym"])
        self.rng.bit_generator.state = state["rng"]

    def close(self) -> None:
        self.gym.close()


def check_sources(state: Mapping[str, Any], parts: int) -> None:
    sources = state.get("sources")
    if not isinstance(sources, list) or len(sources) != parts:
        have = len(sources) if isinstance(sources, list) else None
        raise ValueError(f"collector state holds {have} gym states, this collector runs {parts}")


def sum_charts(charts: list[dict[str, float]]) -> dict[str, float]:
    return {k: float(sum(c[k] for c in charts)) for k in CHART_KEYS}


class LocalCollector:
    """``processes = 0``: one :class:`FrameSource` in the learner's process, stepped when a block is asked for."""

    def __init__(self, spec: CollectorSpec) -> None:
        self.spec = spec
        self.source = FrameSource(spec)
        n = spec.gym.num_envs
        self._out = {k: np.zeros((spec.max_steps, n, *s), dtype=d) for k, (s, d) in spec.layout().items()}

    def next_block(self, weights: Weights, version: int, steps: int, next_steps: int) -> Block:
        """``steps`` gym steps now, with ``weights`` (``next_steps`` is for the pipelined collector only)."""
        if not 1 <= steps <= self.spec.max_steps:
            raise ValueError(f"a block of {steps} steps: must be 1 .. {self.spec.max_steps}")
        charts = self.source.collect(weights, steps, self._out)
        return Block({k: v[:steps] for k, v in self._out.items()}, charts, version)

    def state_dict(self) -> dict[str, Any]:
        return {"sources": [self.source.state_dict()], "pending": None}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        check_sources(state, 1)
        if state.get("pending") is not None:
            raise ValueError("collector state holds a block in flight (written with collect.processes >= 1)")
        self.source.load_state_dict(state["sources"][0])

    def close(self) -> None:
        self.source.close()
