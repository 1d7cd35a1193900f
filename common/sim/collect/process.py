"""Worker processes beside the learner (``collect.processes >= 1``), in pipelined lockstep or (for an on-policy
learner) in plain lockstep. See :mod:`common.sim.collect`."""

from __future__ import annotations

import signal
import traceback
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
import torch.multiprocessing as mp

from common.sim.collect.charts import sum_charts
from common.sim.collect.source import (
    Block,
    CollectorError,
    CollectorSpec,
    FrameSource,
    Inputs,
    LocalCollector,
    Weights,
    character_ranges,
    check_sources,
)

# Seconds a worker may take to start (it builds its gym) or to answer a command.
START_TIMEOUT_S = 300.0


def _worker(spec: CollectorSpec, part: int, parts: int, conn: Any, slots: list[dict[str, torch.Tensor]],
            weights: dict[str, torch.Tensor], inputs: dict[str, torch.Tensor]) -> None:  # fmt: skip
    """A worker process: builds its source, then serves collect / state / load / stop commands until told to stop
    or the learner is gone."""
    # Ctrl-C (and torchrun's SIGTERM to a rank's process group) reaches the workers too: the learner shuts them down
    # in order, they do not die first.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    source = None
    try:
        torch.set_num_threads(spec.torch_threads)
        source = FrameSource(spec, part, parts)
        lo, hi = character_ranges(spec.gym.num_envs, parts)[part]
        views = [{k: t.numpy()[:, lo:hi] for k, t in slot.items()} for slot in slots]
        input_views = {k: t.numpy()[:, lo:hi] for k, t in inputs.items()}
        conn.send(("ready", None))
        while True:
            command, arg = conn.recv()
            if command == "collect":
                slot, steps, clip_weights = arg
                conn.send(("block", source.collect(weights, steps, views[slot], input_views, clip_weights)))
            elif command == "state":
                conn.send(("state", source.state_dict()))
            elif command == "load":
                source.load_state_dict(arg)
                conn.send(("loaded", None))
            else:
                break
    except (EOFError, BrokenPipeError):
        pass  # the learner is gone: nothing to report to
    except BaseException:  # noqa: BLE001 - every failure goes back to the learner, with its traceback
        try:
            conn.send(("error", traceback.format_exc()))
        except (OSError, ValueError):
            pass
    finally:
        if source is not None:
            source.close()
        conn.close()


_TORCH_DTYPES = {np.dtype(np.float32): torch.float32, np.dtype(np.float64): torch.float64,
                 np.dtype(np.int64): torch.int64, np.dtype(np.bool_): torch.bool}  # fmt: skip


class ProcessCollector:
    """``processes = K >= 1``: K worker processes in pipelined (or, with ``pipeline=False``, plain) lockstep (see
    the module docstring).

    Args:
        spec: The collector spec.
        processes: K.
        weights: The policy's state dict: its layout sizes the shared weights (values are sent with each block).
        pipeline: Collect the next block while the learner works, with the weights of its previous call (True); or
            collect each block when it is asked for, with the weights given then (False: an on-policy learner).

    Raises:
        CollectorError: If a worker fails to start (with its traceback).
        ValueError: On a bad process count, or block inputs with ``pipeline``.
    """

    def __init__(self, spec: CollectorSpec, processes: int, weights: Weights, pipeline: bool = True) -> None:
        if processes < 1:
            raise ValueError(f"ProcessCollector needs processes >= 1, got {processes}")
        if pipeline and spec.inputs:
            raise ValueError("block inputs (CollectorSpec.inputs) need a collector that does not pipeline")
        self.spec, self.processes, self.pipeline = spec, processes, pipeline
        n = spec.gym.num_envs
        layout = spec.layout()
        self._slots = [{k: torch.zeros((spec.max_steps, n, *s), dtype=_TORCH_DTYPES[d]).share_memory_()
                        for k, (s, d) in layout.items()} for _ in range(2)]  # fmt: skip
        self._views = [{k: t.numpy() for k, t in slot.items()} for slot in self._slots]
        self._weights = {k: v.detach().to("cpu", copy=True).share_memory_() for k, v in weights.items()}
        self._inputs = {k: torch.zeros((spec.max_steps, n, *s), dtype=_TORCH_DTYPES[d]).share_memory_()
                        for k, (s, d) in spec.input_layout().items()}  # fmt: skip
        self._next_slot = 0
        self._in_flight: tuple[int, int, int] | None = None  # (slot, steps, version)
        self._ready: Block | None = None
        ctx = mp.get_context("forkserver")
        # The fork server imports torch, MuJoCo and the gym once; every worker then starts as a cheap fork of it.
        ctx.set_forkserver_preload(["common.sim.collect.process"])
        self._conns, self._procs = [], []
        try:
            for p in range(processes):
                parent, child = ctx.Pipe()
                proc = ctx.Process(target=_worker, daemon=True, name=f"collector-{p}",
                                   args=(spec, p, processes, child, self._slots, self._weights, self._inputs))
                proc.start()
                child.close()  # the worker holds the only other end: its exit shows here as EOF
                self._conns.append(parent)
                self._procs.append(proc)
            self._receive_all("ready", START_TIMEOUT_S)
        except BaseException:
            self.close()
            raise

    # The pipeline ------------------------------------------------------------------------------------------

    def next_block(self, weights: Weights, version: int, steps: int, next_steps: int, inputs: Inputs | None = None,
                   clip_weights: np.ndarray | None = None) -> Block:  # fmt: skip
        """Pipelined: the block collected since the last call (on the first call: ``steps`` steps, collected now),
        then a request for ``next_steps`` steps with ``weights``, tagged ``version``, and, if given, these RSI
        ``clip_weights``, to be collected while the caller works. Not pipelined: ``steps`` steps collected now with
        ``weights``, ``inputs`` (steps, N, *shape) and ``clip_weights``."""
        if not self.pipeline:
            self.spec.check_inputs(inputs, steps)
            self._request(weights, version, steps, inputs, clip_weights)
            return self._wait()
        if self._ready is None:
            if self._in_flight is None:
                self._request(weights, version, steps, None, clip_weights)
            self._ready = self._wait()
        block, self._ready = self._ready, None
        self._request(weights, version, next_steps, None, clip_weights)
        return block

    def _request(self, weights: Weights, version: int, steps: int, inputs: Inputs | None,
                 clip_weights: np.ndarray | None) -> None:  # fmt: skip
        if not 1 <= steps <= self.spec.max_steps:
            raise ValueError(f"a block of {steps} steps: must be 1 .. {self.spec.max_steps}")
        with torch.no_grad():
            for k, v in weights.items():
                self._weights[k].copy_(v)
            for k, v in (inputs or {}).items():
                self._inputs[k][:steps].copy_(torch.as_tensor(v))
        slot = self._next_slot
        self._next_slot = 1 - slot
        clip_weights = None if clip_weights is None else np.asarray(clip_weights, dtype=np.float64)
        self._send_all(("collect", (slot, steps, clip_weights)))
        self._in_flight = (slot, steps, version)

    def _wait(self) -> Block:
        assert self._in_flight is not None
        slot, steps, version = self._in_flight
        answers = self._receive_all("block", None)
        self._in_flight = None
        return Block({k: v[:steps] for k, v in self._views[slot].items()}, sum_charts([c for c, _ in answers]),
                     version, [r for _, r in answers])  # fmt: skip

    # Checkpoints -------------------------------------------------------------------------------------------

    def state_dict(self) -> dict[str, Any]:
        """Each worker's gym and noise state after the block in flight, and that block (kept for the next call)."""
        if self._ready is None and self._in_flight is not None:
            self._ready = self._wait()
        self._send_all(("state", None))
        sources = self._receive_all("state", START_TIMEOUT_S)
        pending = None
        if self._ready is not None:
            b = self._ready
            pending = {"frames": {k: v.copy() for k, v in b.frames.items()}, "charts": dict(b.charts),
                       "version": b.version, "reports": list(b.reports)}  # fmt: skip
        return {"sources": sources, "pending": pending}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restores :meth:`state_dict`; the block saved in flight is the next one :meth:`next_block` returns.

        Raises:
            ValueError: If the state is for another number of workers or its block has other fields.
        """
        check_sources(state, self.processes)
        pending = state.get("pending")
        if pending is not None and not self.pipeline:
            raise ValueError("collector state holds a block in flight (written by a pipelined collector)")
        if pending is not None:
            layout = self.spec.layout()
            if set(pending["frames"]) != set(layout):
                have = sorted(pending["frames"])
                raise ValueError(f"collector state: block fields {have}, expected {sorted(layout)}")
        if self._in_flight is not None:
            self._wait()
        for conn, source in zip(self._conns, state["sources"], strict=True):
            self._send(conn, ("load", source))
        self._receive_all("loaded", START_TIMEOUT_S)
        # A block saved before reports existed has none: one None per worker, as from actors without a report.
        self._ready = None if pending is None else Block(
            {k: np.array(v) for k, v in pending["frames"].items()}, dict(pending["charts"]), int(pending["version"]),
            list(pending.get("reports", [None] * self.processes)))

    # Messages and shutdown ---------------------------------------------------------------------------------

    def _send(self, conn: Any, message: tuple[str, Any]) -> None:
        try:
            conn.send(message)
        except (BrokenPipeError, OSError):
            self._died(self._conns.index(conn))

    def _send_all(self, message: tuple[str, Any]) -> None:
        for conn in self._conns:
            self._send(conn, message)

    def _receive_all(self, expected: str, timeout: float | None) -> list[Any]:
        return [self._receive(p, expected, timeout) for p in range(self.processes)]

    def _receive(self, p: int, expected: str, timeout: float | None) -> Any:
        conn = self._conns[p]
        try:
            if timeout is not None and not conn.poll(timeout):
                self._fail(f"collector process {p} did not answer within {timeout:.0f} s")
            kind, payload = conn.recv()
        except (EOFError, OSError):
            self._died(p)
        if kind == "error":
            self._fail(f"collector process {p} failed:\n{payload.rstrip()}")
        if kind != expected:
            self._fail(f"collector process {p} answered {kind!r}, expected {expected!r}")
        return payload

    def _died(self, p: int) -> None:
        proc = self._procs[p]
        proc.join(timeout=5.0)
        self._fail(f"collector process {p} (pid {proc.pid}) died with exit code {proc.exitcode}")

    def _fail(self, message: str) -> None:
        self.close()
        raise CollectorError(message)

    def close(self) -> None:
        """Stops the workers (asks, then terminates any that do not stop); safe to call more than once."""
        for conn in self._conns:
            try:
                conn.send(("stop", None))
            except (BrokenPipeError, OSError, ValueError):
                pass
        for proc in self._procs:
            proc.join(timeout=10.0)
            if proc.is_alive():
                proc.terminate()
                proc.join(timeout=5.0)
            if proc.is_alive():
                proc.kill()
                proc.join()
        for conn in self._conns:
            conn.close()
        self._conns, self._procs = [], []


Collector = LocalCollector | ProcessCollector


def make_collector(spec: CollectorSpec, processes: int, weights: Weights, pipeline: bool = True) -> Collector:
    """The collector for ``collect.processes``: in-process for 0, K worker processes otherwise (pipelined or not:
    see :class:`ProcessCollector`; the in-process collector always collects with the weights given now)."""
    return LocalCollector(spec) if processes == 0 else ProcessCollector(spec, processes, weights, pipeline)
