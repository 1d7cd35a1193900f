"""Data-parallel training on torch.distributed: one run, N ranks, each with its own gym, buffer and collector.

Launched by ``torchrun`` (``torchrun --nproc_per_node=N -m supertrack.train ...``), which sets WORLD_SIZE, RANK and
LOCAL_RANK and the rendezvous; without it (or with one rank) a run is a plain single process and nothing here calls
a collective. Every rank builds the same networks from the same seed and receives rank 0's parameters at the start;
after each backward pass the gradients (flattened into one buffer, as rsl_rl does) are summed by an all-reduce and
divided by N, so every rank takes the same optimiser step and holds the same parameters and optimiser state. The
loss rides in the same buffer: a rank whose loss or gradient is not finite makes the averaged buffer non-finite on
every rank, so a non-finite step is skipped by every rank or by none.

What else must agree across ranks is agreed here with small collectives between iterations: the observation
normaliser's moments and the finished episodes (adaptive clip weights) are all-gathered and merged in rank order, and
rank 0 decides when to stop and when to checkpoint (its training clock; a stop signal on any rank stops all at the
same iteration). Rank 0 alone evaluates, logs, writes TensorBoard and checkpoints; a checkpoint holds every rank's
gym, buffer and random state (gathered to rank 0), so an N-rank run resumes exactly with N ranks.

Backends: gloo on the CPU, NCCL on CUDA (``--device cuda`` takes LOCAL_RANK's GPU); the control collectives always
run on a gloo group. Seeds: rank r's gyms and noise continue the sequence of collector sources (:mod:`common.sim.
collect`: rank r with K sources per rank seeds sources r K ... r K + K - 1), its learner generator is seeded with
``[seed, r]`` (rank 0: ``seed``, as a single process).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from datetime import timedelta
from typing import Any

import numpy as np
import torch
import torch.distributed as dist

# Ranks wait for rank 0 while it evaluates (minutes on a large motion set): a collective must not time out then.
# A rank that dies ends the others through torchrun, not through this timeout.
TIMEOUT = timedelta(hours=2)

# Gradient groups: each stream of gradient all-reduces gets its own process group, so that two threads of one rank
# (SuperTrack's policy.concurrent: W's steps beside the policy's) never interleave collectives on one group.
GRADIENT_GROUPS = ("world_model", "policy")
_COUNTING = threading.Lock()


class DistributedError(RuntimeError):
    """The torchrun environment is unusable (a bad WORLD_SIZE, RANK or LOCAL_RANK)."""


@dataclass
class World:
    """This process's place in a data-parallel run.

    Attributes:
        rank: Global rank (0 speaks for the run).
        size: Number of ranks (1: a plain single-process run, no collectives).
        local_rank: Rank on this machine (picks the GPU).
        groups: Process groups: ``control`` (gloo: flags, objects, checkpoints) and one per gradient stream.
    """

    rank: int = 0
    size: int = 1
    local_rank: int = 0
    groups: dict[str, Any] = field(default_factory=dict, repr=False)
    # Gradient all-reduces since the last :meth:`pop_metrics`: calls, seconds (waiting for the slowest rank
    # included), bytes of this rank's buffer.
    _reduced: dict[str, float] = field(default_factory=lambda: {"calls": 0.0, "seconds": 0.0, "bytes": 0.0},
                                       repr=False, compare=False)  # fmt: skip

    @property
    def is_main(self) -> bool:
        """Whether this process evaluates, logs and writes (rank 0)."""
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.size > 1

    # Start and end ----------------------------------------------------------------------------------------------

    def device(self, device: str) -> str:
        """The torch device of this rank: ``cuda`` without an index becomes ``cuda:<local_rank>``."""
        kind = torch.device(device)
        if kind.type == "cuda" and kind.index is None and self.distributed:
            return f"cuda:{self.local_rank}"
        return device

    def init(self, device: str) -> None:
        """Joins the process group (NCCL for a CUDA device, else gloo) and makes the control and gradient groups;
        returns once every rank has joined. Nothing for a single process."""
        if not self.distributed or dist.is_initialized():
            return
        cuda = torch.device(device).type == "cuda"
        if cuda:
            torch.cuda.set_device(torch.device(device))
        dist.init_process_group("nccl" if cuda else "gloo", timeout=TIMEOUT)
        self.groups = {"control": dist.new_group(backend="gloo", timeout=TIMEOUT)}
        for name in GRADIENT_GROUPS:
            self.groups[name] = dist.new_group(timeout=TIMEOUT)
        self.barrier()

    def close(self) -> None:
        if self.distributed and dist.is_initialized():
            dist.destroy_process_group()

    def barrier(self) -> None:
        if self.distributed:
            dist.barrier(group=self.groups["control"])

    # Seeds ---------------------------------------------------------------------------------------------------------

    def generator(self, seed: int) -> np.random.Generator:
        """The learner's numpy generator: ``seed`` on rank 0 (a single process's), ``[seed, rank]`` elsewhere."""
        return np.random.default_rng(seed if self.rank == 0 else [seed, self.rank])

    def seed_torch(self, seed: int) -> None:
        """Gives ranks other than 0 their own torch stream (rank 0 keeps the one seeded with ``seed``); called once
        the networks are built, so that they start equal everywhere."""
        if self.rank > 0:
            torch.manual_seed(int(np.random.SeedSequence([seed, self.rank]).generate_state(1)[0]))

    def first_source(self, sources_per_rank: int) -> int:
        """Index of this rank's first collector source among the run's (seeds gym.seed + index, noise
        [noise_seed, index])."""
        return self.rank * max(1, sources_per_rank)

    # Parameters and gradients ------------------------------------------------------------------------------------

    def broadcast_modules(self, *modules: torch.nn.Module) -> None:
        """Rank 0's parameters and buffers to every rank."""
        if not self.distributed:
            return
        for module in modules:
            for tensor in module.state_dict().values():
                dist.broadcast(tensor, 0, group=self.groups["policy"])

    def average_gradients(self, params: Iterable[torch.nn.Parameter], losses: torch.Tensor,
                          stream: str) -> torch.Tensor:  # fmt: skip
        """Replaces every gradient with its mean over the ranks; returns the mean of ``losses`` (any shape).

        One all-reduce of one flat buffer (gradients, then the losses) on the stream's group. A parameter without a
        gradient counts as a zero gradient. Single process: returns ``losses`` and changes nothing.
        """
        if not self.distributed:
            return losses
        params = [p for p in params if p.requires_grad]
        grads = [torch.zeros_like(p) if p.grad is None else p.grad for p in params]
        flat = torch.cat([g.reshape(-1) for g in grads] + [losses.detach().reshape(-1).to(grads[0].dtype)])
        start = time.perf_counter()
        dist.all_reduce(flat, group=self.groups[stream])
        with _COUNTING:  # SuperTrack's two threads both count
            r = self._reduced
            r["calls"], r["bytes"] = r["calls"] + 1, r["bytes"] + flat.numel() * flat.element_size()
            r["seconds"] += time.perf_counter() - start
        flat /= self.size
        offset = 0
        for p, g in zip(params, grads, strict=True):
            n = g.numel()
            if p.grad is None:
                p.grad = flat[offset : offset + n].view_as(p).clone()
            else:
                p.grad.copy_(flat[offset : offset + n].view_as(p))
            offset += n
        return flat[offset:].view_as(losses).to(losses.dtype)

    def pop_metrics(self, iterations: int) -> dict[str, float]:
        """The gradient all-reduces per iteration over the last ``iterations`` (``perf/allreduce_...``: calls,
        seconds, MB of this rank's buffer), then zeroed; empty in a single process."""
        if not self.distributed or iterations < 1:
            return {}
        r, self._reduced = self._reduced, {"calls": 0.0, "seconds": 0.0, "bytes": 0.0}
        return {"perf/allreduce_calls": r["calls"] / iterations, "perf/allreduce_s": r["seconds"] / iterations,
                "perf/allreduce_mb": r["bytes"] / iterations / 1e6}  # fmt: skip

    # Control -------------------------------------------------------------------------------------------------------

    def decide(self, **flags: bool) -> dict[str, bool]:
        """The run's decision on each flag: rank 0's value, or-ed with any rank's for the names starting ``any_``
        (e.g. a stop signal that reached one rank). Every rank passes the same names in the same order."""
        if not self.distributed:
            return dict(flags)
        names = list(flags)
        mine = [float(flags[k]) if (self.is_main or k.startswith("any_")) else 0.0 for k in names]
        values = torch.tensor(mine, dtype=torch.float64)
        dist.all_reduce(values, op=dist.ReduceOp.MAX, group=self.groups["control"])
        return {k: bool(v) for k, v in zip(names, values.tolist(), strict=True)}

    def mean(self, value: float) -> float:
        """The mean of a number over the ranks."""
        if not self.distributed:
            return value
        t = torch.tensor([value], dtype=torch.float64)
        dist.all_reduce(t, group=self.groups["control"])
        return float(t.item()) / self.size

    def all_gather(self, obj: Any) -> list[Any]:
        """Every rank's ``obj`` (picklable), in rank order; ``[obj]`` in a single process."""
        if not self.distributed:
            return [obj]
        out: list[Any] = [None] * self.size
        dist.all_gather_object(out, obj, group=self.groups["control"])
        return out

    def gather_to_main(self, obj: Any) -> list[Any] | None:
        """Every rank's ``obj`` on rank 0, in rank order (None elsewhere)."""
        if not self.distributed:
            return [obj]
        out: list[Any] | None = [None] * self.size if self.is_main else None
        dist.gather_object(obj, out, dst=0, group=self.groups["control"])
        return out

    def from_main(self, obj: Any) -> Any:
        """Rank 0's ``obj`` on every rank."""
        if not self.distributed:
            return obj
        box = [obj if self.is_main else None]
        dist.broadcast_object_list(box, src=0, group=self.groups["control"])
        return box[0]

    def concat_characters(self, frames: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Per-character fields (T, N, ...) of every rank side by side, (T, N x ranks, ...), in rank order: the
        finished episodes as one gym of all ranks' characters would have reported them."""
        if not self.distributed:
            return dict(frames)
        parts = self.all_gather({k: np.asarray(v) for k, v in frames.items()})
        return {k: np.concatenate([p[k] for p in parts], axis=1) for k in frames}


def from_environment(environ: Mapping[str, str] | None = None) -> World:
    """The world torchrun describes in the environment (WORLD_SIZE, RANK, LOCAL_RANK); a single process without it.

    Raises:
        DistributedError: Naming the variable if one is not a valid rank or size.
    """
    env = os.environ if environ is None else environ
    values = {}
    for name, default in (("WORLD_SIZE", 1), ("RANK", 0), ("LOCAL_RANK", 0)):
        text = env.get(name)
        try:
            values[name] = default if text is None else int(text)
        except ValueError:
            raise DistributedError(f"environment variable {name}={text!r} is not an integer") from None
    size, rank, local = values["WORLD_SIZE"], values["RANK"], values["LOCAL_RANK"]
    if size < 1 or not 0 <= rank < size or local < 0:
        raise DistributedError(f"WORLD_SIZE={size}, RANK={rank}, LOCAL_RANK={local}: need 0 <= RANK < WORLD_SIZE")
    return World(rank=rank, size=size, local_rank=local)
