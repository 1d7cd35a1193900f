"""The collector: worker frames equal the in-process loop's, pipelined and plain lockstep, block inputs, actor hooks,
clip weights, chart sums, exact state round trip, failures."""

from __future__ import annotations

import os
import signal
from collections.abc import Mapping
from dataclasses import replace

import numpy as np
import pytest
import torch

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from common.sim.collect import CollectorError, CollectorSpec, LocalCollector, ProcessCollector, chart_metrics
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


class OffsetPlayback:
    """A test actor with every hook: reference targets plus ``scale`` x the learner's ``offset`` input; after the
    step the reward and whether it was the block's last; its report is the number of steps it took."""

    def __init__(self, humanoid: Humanoid) -> None:
        self.scale, self.steps = 0.0, 0

    def load_weights(self, weights: Mapping[str, torch.Tensor]) -> None:
        self.scale, self.steps = float(weights["scale"]), 0

    def __call__(self, res: StepResult, rng: np.random.Generator,
                 offset: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:  # fmt: skip
        self.steps += 1
        return res.ref_next.qpos[:, 7:] + self.scale * offset, {"noise": self.scale * offset, "clip": res.clip}

    def after_step(self, res: StepResult, last: bool) -> dict[str, np.ndarray]:
        return {"reward": res.reward, "last": np.full(len(res.reward), last)}

    def block_report(self) -> int:
        return self.steps


def _w(scale: float) -> dict[str, torch.Tensor]:
    return {"scale": torch.tensor(scale)}


@pytest.fixture(scope="module")
def spec() -> CollectorSpec:
    humanoid = Humanoid()
    # Episodes of 4 frames: several resets per block, so the episode bookkeeping is exercised.
    gym = GymConfig(num_envs=4, threads=1, seed=3, termination=TerminationConfig(max_episode_frames=4))
    return CollectorSpec(gym=gym, library=load_motions(["walk", "run"], humanoid), humanoid=humanoid,
                         actor_factory=NoisyPlayback, fields=FIELDS, noise_seed=7, max_steps=6)  # fmt: skip


@pytest.fixture(scope="module")
def input_spec(spec: CollectorSpec) -> CollectorSpec:
    fields = {"noise": ((28,), "float64"), "clip": ((), "int64"), "reward": ((), "float64"), "last": ((), "bool")}
    return replace(spec, actor_factory=OffsetPlayback, fields=fields, inputs={"offset": ((28,), "float64")})


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
        assert state["pending"]["reports"] == [None, None]  # this actor has no block_report
        # A checkpoint from before the reports existed (no "reports" in its block in flight) loads too.
        second.load_state_dict({**state, "pending": {k: v for k, v in state["pending"].items() if k != "reports"}})
        for expected, (v, s) in zip(later, ((1, 0.4), (2, 0.6), (3, 0.8)), strict=True):
            block = second.next_block(_w(s), v, 2, 2)
            assert block.reports == [None, None]
            _assert_equal(expected, dict(block.frames))
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


def test_without_pipeline_each_block_is_collected_now_with_its_weights_inputs_and_clip_weights(
    input_spec: CollectorSpec,
) -> None:
    offsets = np.random.default_rng(0).standard_normal((3, 5, 4, 28))
    # Clip 0 (walk) only, then clip 1 (run) only: episodes of 4 frames restart on the clip the weights allow.
    clip_weights = [np.array([1.0, 0.0]), np.array([0.0, 1.0]), None]
    local = LocalCollector(input_spec)
    expected = [_copy(local.next_block(_w(s), v, 5, 5, {"offset": offsets[v]}, clip_weights[v]))
                for v, s in enumerate((0.5, 0.25, 0.125))]  # fmt: skip
    local.close()
    worker = ProcessCollector(input_spec, 1, _w(0.0), pipeline=False)
    try:
        blocks = [worker.next_block(_w(s), v, 5, 5, {"offset": offsets[v]}, clip_weights[v])
                  for v, s in enumerate((0.5, 0.25, 0.125))]  # fmt: skip
        assert blocks[-1].version == 2 and blocks[-1].reports == [5]
        _assert_equal(expected[2], dict(blocks[-1].frames))
        assert worker.state_dict()["pending"] is None  # nothing in flight between calls
    finally:
        worker.close()
    for v, scale in enumerate((0.5, 0.25, 0.125)):  # exact in float32
        np.testing.assert_array_equal(expected[v]["noise"], scale * offsets[v])  # step t's rows of the inputs
        np.testing.assert_array_equal(expected[v]["last"], np.arange(5)[:, None] == np.array([4, 4, 4, 4]))
    # Episodes of 4 frames start at frames 4, 8 and 12 (block 0 row 4, block 1 row 3, block 2 row 2) on the clips
    # that the weights of the block then allow; None keeps the last ones.
    assert (expected[0]["clip"][4] == 0).all() and (expected[1]["clip"][:3] == 0).all()
    assert (expected[1]["clip"][3:] == 1).all() and (expected[2]["clip"] == 1).all()


def test_two_workers_split_the_inputs_and_report_each_and_their_charts_add_up(input_spec: CollectorSpec) -> None:
    offsets = np.random.default_rng(1).standard_normal((4, 4, 28))
    worker = ProcessCollector(input_spec, 2, _w(0.0), pipeline=False)
    try:
        block = worker.next_block(_w(0.5), 0, 4, 4, {"offset": offsets})
        frames, charts = _copy(block), dict(block.charts)
        assert block.reports == [4, 4]  # one per worker, in order
        with pytest.raises(ValueError, match=r"block input 'offset': shape \(3, 4, 28\), expected \(4, 4, 28\)"):
            worker.next_block(_w(0.5), 1, 4, 4, {"offset": offsets[:3]})
    finally:
        worker.close()
    np.testing.assert_array_equal(frames["noise"], 0.5 * offsets)  # characters 2-3 got columns 2-3
    assert charts["steps"] == 16 and charts["episodes"] == 4 and charts["episode_frames"] == 16
    assert charts["reward_sum"] == pytest.approx(frames["reward"].sum(), rel=1e-12)
    assert {"reward/pose", "event/diverged"} <= set(charts)
    with pytest.raises(ValueError, match="block inputs .* need a collector that does not pipeline"):
        ProcessCollector(input_spec, 1, _w(0.0))


def test_chart_metrics_by_hand() -> None:
    charts = {"reward_sum": 6.0, "steps": 12.0, "episodes": 2.0, "episode_frames": 10.0, "terminated": 1.0,
              "collect_s": 0.5, "reward/root_pos": 3.0, "event/term/body_pos": 3.0, "event/diverged": 0.0}  # fmt: skip
    assert chart_metrics(charts) == {
        "charts/reward": 0.5, "reward/root_pos": 0.25, "charts/term/body_pos_per_1k": 250.0,
        "charts/diverged_per_1k": 0.0, "charts/episode_length": 5.0, "charts/terminated_share": 0.5,
        "perf/collect_s": 0.5,
    }  # fmt: skip
    assert "charts/episode_length" not in chart_metrics({**charts, "episodes": 0.0})  # no episode ended
    assert chart_metrics({**charts, "steps": 0.0}) == {}
