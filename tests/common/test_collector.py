"""The collector: worker frames equal the in-process loop's, pipelined lockstep, exact state round trip, failures."""

from __future__ import annotations

import os
import signal
from collections.abc import Mapping

import numpy as np
import pytest
import torch

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from common.sim.collect import CollectorError, CollectorSpec, LocalCollector, ProcessCollector
from common.sim.gym import GymConfig, StepResult
from common.sim.rewards import TerminationConfig

FIELDS = {"qpos": ((35,), "float32"), "noise": ((28,), "float64")}


class NoisyPlayback:
    """A test actor: reference targets plus ``scale`` x N(0, 1) noise, ``scale`` being the one weight it is sent.

    A scale of -1 makes it raise (a worker failure).
    """

    def __init__(self, humanoid: Humanoid) -> None:
        self.scale = 0.0

    def load_weights(self, weights: Mapping[str, torch.Tensor]) -> None:
        self.scale = float(weights["scale"])

    def __call__(self, res: StepResult, rng: np.random.Generator) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        if self.scale < 0:
            raise ValueError("a negative noise scale")
        noise = self.scale * rng.standard_normal((res.sim.qpos.shape[0], 28))
        return res.ref_next.qpos[:, 7:] + noise, {"qpos": res.sim.qpos.astype(np.float32), "noise": noise}


def _w(scale: float) -> dict[str, torch.Tensor]:
    return {"scale": torch.tensor(scale)}


@pytest.fixture(scope="module")
def spec() -> CollectorSpec:
    humanoid = Humanoid()
    # Episodes of 4 frames: several resets per block, so the episode bookkeeping is exercised.
    gym = GymConfig(num_envs=4, threads=1, seed=3, termination=TerminationConfig(max_episode_frames=4))
    return CollectorSpec(gym=gym, library=load_motions(["walk", "run"], humanoid), humanoid=humanoid,
                         actor_factory=NoisyPlayback, fields=FIELDS, noise_seed=7, max_steps=6)  # fmt: skip


def _copy(block: object) -> dict[str, np.ndarray]:
    return {k: v.copy() for k, v in block.frames.items()}  # type: ignore[attr-defined]


def _assert_equal(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_a_worker_writes_the_in_process_loops_frames_one_block_later(spec: CollectorSpec) -> None:
    local = LocalCollector(spec)
    # The in-process loop: each block with the weights given when it is asked for.
    expected = [_copy(local.next_block(_w(s), v, n, 3)) for v, (s, n) in enumerate([(0.1, 5), (0.1, 3), (0.3, 3)])]
    local.close()
    assert expected[0]["qpos"].shape == (5, 4, 35) and not np.array_equal(expected[1]["noise"], expected[2]["noise"])
    ids = np.concatenate([e["episode_id"] for e in expected])
    assert (np.diff(ids, axis=0) >= 0).all() and ids.max() >= 4  # episodes of 4 frames ended and new ones began
    done = np.concatenate([e["truncated"] | e["terminated"] for e in expected])
    np.testing.assert_array_equal(done.sum(axis=0), [2, 2, 2, 2])  # 11 frames: ends after frames 4 and 8
    worker = ProcessCollector(spec, 1, _w(0.0))
    try:
        # Pipelined: each call returns the block asked for by the call before, so the weights run one call ahead.
        blocks = [worker.next_block(_w(0.1), 0, 5, 3)]
        got = [_copy(blocks[0])]  # a block's views stay valid until the next call only
        for v, s in ((1, 0.3), (2, 0.5)):
            blocks.append(worker.next_block(_w(s), v, 3, 3))
            got.append(_copy(blocks[-1]))
        assert [b.version for b in blocks] == [0, 0, 1]
        for e, g in zip(expected, got, strict=True):
            _assert_equal(e, g)
    finally:
        worker.close()


def test_a_resumed_worker_continues_exactly_and_ignores_ctrl_c(spec: CollectorSpec) -> None:
    first = ProcessCollector(spec, 2, _w(0.0))
    try:
        first.next_block(_w(0.2), 0, 5, 2)
        state = first.state_dict()  # the block in flight is kept: state after it, and the block itself
        os.kill(first._procs[0].pid, signal.SIGINT)  # Ctrl-C reaches every process; the learner stops the workers
        later = [_copy(first.next_block(_w(s), v, 2, 2)) for v, s in ((1, 0.4), (2, 0.6), (3, 0.8))]
    finally:
        first.close()
    ids = later[0]["episode_id"]
    np.testing.assert_array_equal(ids[0] % 2, [0, 0, 1, 1])  # characters 0-1 in worker 0, 2-3 in worker 1
    second = ProcessCollector(spec, 2, _w(0.0))
    try:
        second.load_state_dict(state)
        for expected, (v, s) in zip(later, ((1, 0.4), (2, 0.6), (3, 0.8)), strict=True):
            _assert_equal(expected, dict(second.next_block(_w(s), v, 2, 2).frames))
        with pytest.raises(ValueError, match="collector state holds 2 gym states, this collector runs 1"):
            LocalCollector(spec).load_state_dict(state)
    finally:
        second.close()


def test_a_failing_worker_is_reported_with_its_traceback_and_leaves_no_process(spec: CollectorSpec) -> None:
    collector = ProcessCollector(spec, 2, _w(0.0))
    procs = list(collector._procs)
    with pytest.raises(CollectorError, match=r"(?s)collector process 0 failed:\nTraceback.*ValueError: a negative"):
        collector.next_block(_w(-1.0), 0, 2, 2)
    assert not any(p.is_alive() for p in procs)
    collector.close()  # a second close is harmless


def test_a_killed_worker_stops_the_collector_with_a_clear_error(spec: CollectorSpec) -> None:
    collector = ProcessCollector(spec, 1, _w(0.0))
    proc = collector._procs[0]
    os.kill(proc.pid, signal.SIGKILL)
    proc.join()
    with pytest.raises(CollectorError, match=rf"collector process 0 \(pid {proc.pid}\) died with exit code -9"):
        collector.next_block(_w(0.1), 0, 2, 2)
    collector.close()
