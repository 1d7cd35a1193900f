"""Gym frames for a learner's buffer: collected in the learner's process, or by worker processes beside it.

The collector knows no learner. It gets a picklable factory that builds a :class:`FrameActor` (the learner's policy
copy plus exploration noise, turning a gym state into PD targets and the learner's per-frame fields), the layout of
those fields and the policy's weights, and it hands back whole blocks of frames, (T, N, *shape) per field, with the
bookkeeping fields of :mod:`common.sim.buffer` (``episode_id``, ``terminated``, ``truncated``) and the frame's ``clip``
(:data:`EPISODE_FIELDS`: the clip of the frame's episode, which a learner's buffer may keep so that a window's clip,
and so its terrain, is known) filled in.

- ``processes = 0`` (:class:`LocalCollector`): the gym steps in the learner's process when a block is asked for,
  with the weights given then: the learner's classic collect-then-update loop.
- ``processes = K >= 1`` (:class:`ProcessCollector`): K worker processes, each with its own gym of about N / K
  characters, forked by a clean ``forkserver`` (the learner's own process is never forked: torch's threads and fork
  do not mix; the server imports torch and the gym once, so a worker starts in about a second). Pipelined
  lockstep: :meth:`ProcessCollector.next_block` returns the block collected during the learner's previous update
  and at once asks for the next one with the weights given now, so block k + 1 is collected with the weights
  update k starts from while update k runs. What a worker computes depends only on its gym state, its noise
  generator and the weights and step counts it was sent, never on timing: one seed gives one result, and
  :meth:`ProcessCollector.state_dict` (which waits for the block in flight and keeps it) lets ``--resume``
  continue exactly. Frames and weights travel through shared memory (two frame slots, used in turn, so a returned
  block stays valid until the next call); only small commands, chart sums and the actors' block reports are
  pickled. With ``pipeline=False`` (an on-policy learner, e.g. PPO) :meth:`ProcessCollector.next_block` instead
  collects the block it is asked for there and then, with the weights given then, and waits for it: no block is
  ever in flight between calls, and the learner's update and the workers' stepping take turns.

Besides the weights a block may carry the learner's per-step inputs (``CollectorSpec.inputs``, e.g. PPO's exploration
noise, drawn by the learner so that the frames do not depend on the split among processes) and new RSI clip weights
for the gym; an actor may add frame fields that need the step's result (``after_step``) and report what it learned
over a block (``block_report``, e.g. PPO's observation statistics). Every source also sums charts while it steps
(:mod:`common.sim.collect.charts`: reward, reward terms, termination events, episode lengths), from which both learners
log the same keys.

Gym seeds: worker p's gym uses ``gym.seed + p`` and its noise generator ``[noise_seed, p]``, so ``processes = 1``
gives frame for frame what ``processes = 0`` gives with the same weights (and inputs); a data-parallel run's rank r
continues the count (``CollectorSpec.first_source`` = r K, :mod:`common.train.distributed`). Episode ids become
``id * K + p`` so that they stay unique across workers.
"""

from common.sim.collect.charts import chart_metrics
from common.sim.collect.process import Collector, ProcessCollector, make_collector
from common.sim.collect.source import (
    EPISODE_FIELDS,
    ActorFactory,
    Block,
    CollectorError,
    CollectorSpec,
    FieldLayout,
    FrameActor,
    FrameSource,
    Inputs,
    LocalCollector,
)

__all__ = [
    "EPISODE_FIELDS",
    "ActorFactory",
    "Block",
    "Collector",
    "CollectorError",
    "CollectorSpec",
    "FieldLayout",
    "FrameActor",
    "FrameSource",
    "Inputs",
    "LocalCollector",
    "ProcessCollector",
    "chart_metrics",
    "make_collector",
]
