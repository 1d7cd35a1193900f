"""The collector's parts that run in any process: the spec, the actor protocol, a block, one gym source, and the
in-process collector (``collect.processes = 0``). See :mod:`common.sim.collect`."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np
import torch

from common.character.humanoid import Humanoid
from common.motion.library import MotionLibrary
from common.sim.buffer import BOOKKEEPING_FIELDS
from common.sim.collect.charts import add_step, new_charts
from common.sim.gym import GymConfig, StepResult, TrackingGym

FieldLayout = Mapping[str, tuple[tuple[int, ...], np.dtype | str]]
Weights = Mapping[str, torch.Tensor]
Inputs = Mapping[str, np.ndarray]

# Written for every frame besides the buffer's bookkeeping: the clip of the episode the frame belongs to.
EPISODE_FIELDS: dict[str, tuple[tuple[int, ...], np.dtype]] = {"clip": ((), np.dtype(np.int64))}


class CollectorError(RuntimeError):
    """A collector process failed (its traceback is in the message) or died."""


class FrameActor(Protocol):
    """What a learner gives the collector to act with (built in the collecting process).

    Optional, called when the actor has them: ``after_step(res: StepResult, last: bool) -> dict[str, np.ndarray]``,
    frame fields {name: (n, *shape)} that need the step's result ``res`` (e.g. the value of the state a truncated
    episode reached; ``last``: the block's last step), merged into the frame that :meth:`__call__` began; and
    ``block_report() -> Any``, anything picklable the actor learned over the block (e.g. observation statistics),
    handed to the learner as :attr:`Block.reports`.
    """

    def load_weights(self, weights: Weights) -> None:
        """Takes the learner's current policy weights (a state dict)."""

    def __call__(self, res: StepResult, rng: np.random.Generator,
                 **inputs: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:  # fmt: skip
        """PD targets (n, nu) for the step from ``res`` (noise drawn from ``rng``, or given in ``inputs``: this
        step's rows of the block's inputs, {name: (n, *shape)}, see :attr:`CollectorSpec.inputs`) and the learner's
        frame fields {name: (n, *shape)} for the frame that starts at ``res``."""


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
        clip_weights: RSI weight per clip (None: uniform); a block may change them (see ``next_block``).
        torch_threads: Torch threads of a worker process (acting is a small forward pass).
        inputs: Per-step inputs the learner sends with every block, name -> (shape, dtype), given to the actor's
            call as keyword arguments, one step's rows at a time (e.g. exploration noise drawn by the learner, so
            that the frames do not depend on how the characters are split among processes). Needs a collector that
            does not pipeline.
        first_source: Index of this collector's first source among the run's (a data-parallel run's rank r with K
            sources each: r K; :mod:`common.train.distributed`): source p seeds its gym with ``gym.seed +
            first_source + p`` and its noise with ``[noise_seed, first_source + p]``.
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
    inputs: FieldLayout = field(default_factory=dict)
    first_source: int = 0

    def layout(self) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
        """The block's fields: the actor's, the buffer's bookkeeping fields and ``clip`` (the clip of the episode
        the frame belongs to, for adaptive clip weights: :mod:`common.sim.motion_weights`)."""
        return {**_resolved(self.fields), **BOOKKEEPING_FIELDS, **EPISODE_FIELDS}

    def input_layout(self) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
        """The block inputs' fields (without the leading (T, N))."""
        return _resolved(self.inputs)

    def check_inputs(self, inputs: Inputs | None, steps: int) -> None:
        """Raises ValueError unless ``inputs`` has every input of the spec, each (steps, N, *shape)."""
        got = {} if inputs is None else inputs
        if set(got) != set(self.inputs):
            raise ValueError(f"block inputs {sorted(got)}, the collector expects {sorted(self.inputs)}")
        for name, (shape, _) in self.input_layout().items():
            want = (steps, self.gym.num_envs, *shape)
            if tuple(np.shape(got[name])) != want:
                raise ValueError(f"block input {name!r}: shape {tuple(np.shape(got[name]))}, expected {want}")


def _resolved(fields: FieldLayout) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    return {k: (tuple(s), np.dtype(d)) for k, (s, d) in fields.items()}


@dataclass
class Block:
    """Frames of every character over ``steps`` gym steps.

    Attributes:
        frames: Field -> (T, N, *shape); views valid until the collector's next :meth:`next_block`.
        charts: Sums over the block (:mod:`common.sim.collect.charts`): ``reward_sum``, ``steps`` (character
            steps), ``episodes`` (ended), ``episode_frames`` (their lengths), ``terminated``, ``collect_s`` (seconds
            the workers spent stepping, summed over workers), ``reward/<term>`` and ``event/<name>``.
        version: The tag sent with the weights that collected it (e.g. the learner's update count).
        reports: Each source's actor's ``block_report()`` (None where it has none), in source order: one for the
            in-process collector, K for K worker processes (characters split in order).
    """

    frames: dict[str, np.ndarray]
    charts: dict[str, float]
    version: int
    reports: list[Any] = field(default_factory=list)

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
        index = spec.first_source + part
        cfg = replace(spec.gym, num_envs=hi - lo, seed=spec.gym.seed + index)
        self.gym = TrackingGym(cfg, spec.library, spec.humanoid, clip_weights=spec.clip_weights)
        self.res = self.gym.reset()
        self.actor = spec.actor_factory(spec.humanoid)
        self.rng = np.random.default_rng([spec.noise_seed, index])

    def collect(self, weights: Weights, steps: int, out: Mapping[str, np.ndarray], inputs: Inputs | None = None,
                clip_weights: np.ndarray | None = None) -> tuple[dict[str, float], Any]:  # fmt: skip
        """Steps the gym ``steps`` times with ``weights``, writing rows 0 .. steps - 1 of ``out`` (T, n, *shape).

        Args:
            weights: The policy's weights.
            steps: Gym steps T.
            out: The block's fields of this source's characters, (>= T, n, *shape) each.
            inputs: The block's inputs of this source's characters, (>= T, n, *shape) each (see the spec).
            clip_weights: RSI weight per clip from now on (None: keep the gym's).

        Returns:
            The block's chart sums and the actor's report (None if it has none).
        """
        start = time.perf_counter()
        self.actor.load_weights(weights)
        if clip_weights is not None:
            self.gym.set_clip_weights(clip_weights)
        after_step = getattr(self.actor, "after_step", None)
        charts = new_charts()
        for t in range(steps):
            prev = self.res
            step_inputs = {} if inputs is None else {k: v[t] for k, v in inputs.items()}
            targets, fields = self.actor(prev, self.rng, **step_inputs)
            res = self.gym.step(targets)
            if after_step is not None:
                fields = {**fields, **after_step(res, t == steps - 1)}
            for name, value in fields.items():
                out[name][t] = value
            out["episode_id"][t] = prev.episode_id * self.parts + self.part
            out["terminated"][t], out["truncated"][t] = res.terminated, res.truncated
            out["clip"][t] = prev.clip
            add_step(charts, res, prev.episode_frame)
            self.res = res
        charts["collect_s"] = time.perf_counter() - start
        report = getattr(self.actor, "block_report", None)
        return charts, None if report is None else report()

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


class LocalCollector:
    """``processes = 0``: one :class:`FrameSource` in the learner's process, stepped when a block is asked for.

    Args:
        spec: The collector spec.
    """

    def __init__(self, spec: CollectorSpec) -> None:
        self.spec = spec
        self.source = FrameSource(spec)
        n = spec.gym.num_envs
        self._out = {k: np.zeros((spec.max_steps, n, *s), dtype=d) for k, (s, d) in spec.layout().items()}

    def next_block(self, weights: Weights, version: int, steps: int, next_steps: int, inputs: Inputs | None = None,
                   clip_weights: np.ndarray | None = None) -> Block:  # fmt: skip
        """``steps`` gym steps now, with ``weights``, ``inputs`` (steps, N, *shape) and, if given, these RSI
        ``clip_weights`` (``next_steps`` is for the pipelined collector only)."""
        if not 1 <= steps <= self.spec.max_steps:
            raise ValueError(f"a block of {steps} steps: must be 1 .. {self.spec.max_steps}")
        self.spec.check_inputs(inputs, steps)
        charts, report = self.source.collect(weights, steps, self._out, inputs, clip_weights)
        return Block({k: v[:steps] for k, v in self._out.items()}, charts, version, [report])

    def state_dict(self) -> dict[str, Any]:
        return {"sources": [self.source.state_dict()], "pending": None}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        check_sources(state, 1)
        if state.get("pending") is not None:
            raise ValueError("collector state holds a block in flight (written with collect.processes >= 1)")
        self.source.load_state_dict(state["sources"][0])

    def close(self) -> None:
        self.source.close()
