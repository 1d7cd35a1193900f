"""Data-parallel training (``common.train.distributed``) through torchrun on the CPU (gloo), with the debug presets:
identical parameters on every rank, exact resume after a SIGKILL, one rank equal to the plain command, a refused
resume with another number of ranks, rank 0 alone writing."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from common.run.directory import numbered_checkpoints, read_checkpoint
from common.run.logs import read_metrics
from common.train.distributed import DistributedError, World, from_environment

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = {"supertrack": ROOT / "configs" / "supertrack" / "debug.yaml", "ppo": ROOT / "configs" / "ppo" / "debug.yaml"}
# Every iteration checkpointed, evaluated every other one (the kill test needs checkpoints to resume from).
OFTEN = ("--set", "train.checkpoint_every_minutes=0", "--set", "train.eval_every_iterations=2")


def _command(learner: str, ranks: int | None, out: Path, *extra: str) -> list[str]:
    """The training command: plain (``ranks`` None) or through torchrun with ``ranks`` processes."""
    args = ["-m", f"{learner}.train", "--config", str(CONFIGS[learner]), "--out", str(out), *extra]
    if ranks is None:
        return [sys.executable, *args]
    return [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={ranks}", *args]


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("WORLD_SIZE", "RANK", "LOCAL_RANK")}
    return {**env, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}


def _train(learner: str, ranks: int | None, out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(_command(learner, ranks, out, *extra), cwd=ROOT, env=_env(), capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    return done


def _assert_same(a: object, b: object, where: str = "") -> None:
    """Every tensor, array and number of two nested states equal, exactly."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            _assert_same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, torch.Tensor):
        assert torch.equal(a, b), where
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert a == b, where


def _generators(state: dict) -> dict:
    """The generators training draws from (python's ``random``, unseeded and unused, is left out)."""
    return {k: state["rng"][k] for k in ("numpy", "torch")}


def _descendants(pid: int) -> list[int]:
    """Process ids of every descendant of ``pid`` (from /proc)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


# What must agree across ranks: the networks and optimisers (SuperTrack also its weight average), the adaptive
# clip weights' failure rates and (PPO) the observation normaliser.
SHARED = {"supertrack": ("world_model", "policy", "world_optimizer", "policy_optimizer", "policy_average",
                         "motion_weights", "updates"),
          "ppo": ("net", "optimizer", "normalizer", "motion_weights", "updates")}  # fmt: skip


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """SuperTrack: 8 iterations on 2 ranks straight; the same killed (SIGKILL to every process) once a checkpoint
    of iteration 2 or later exists and resumed to 8; 6 iterations with one rank through torchrun and plainly. PPO:
    4 iterations on 2 ranks straight, and 2 resumed to 4."""
    root = tmp_path_factory.mktemp("distributed")
    out = {name: root / name for name in ("straight", "killed", "one_rank", "plain", "ppo", "ppo_resumed")}
    _train("supertrack", 2, out["straight"], "--max-iterations", "8", *OFTEN)
    proc = subprocess.Popen(_command("supertrack", 2, out["killed"], "--max-iterations", "8", *OFTEN), cwd=ROOT,
                            env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    deadline = time.monotonic() + 240
    while not any(i >= 2 for i, _ in numbered_checkpoints(out["killed"] / "checkpoints")):
        assert proc.poll() is None and time.monotonic() < deadline, "the run ended before its second checkpoint"
        time.sleep(0.01)
    for pid in [*_descendants(proc.pid), proc.pid]:
        os.kill(pid, signal.SIGKILL)
    proc.wait()
    assert not (out["killed"] / "checkpoints" / "ckpt_00000008.pt").exists(), "killed after the run ended"
    _train("supertrack", 2, out["killed"], "--resume", "--max-iterations", "8")
    _train("supertrack", 1, out["one_rank"])
    _train("supertrack", None, out["plain"])
    _train("ppo", 2, out["ppo"])
    _train("ppo", 2, out["ppo_resumed"], "--max-iterations", "2")
    _train("ppo", 2, out["ppo_resumed"], "--resume", "--max-iterations", "4")
    return out


@pytest.mark.parametrize(("learner", "run"), [("supertrack", "straight"), ("ppo", "ppo")])
def test_two_ranks_hold_identical_parameters_and_their_own_gyms(runs: dict[str, Path], learner: str,
                                                                run: str) -> None:  # fmt: skip
    state = read_checkpoint(runs[run])[1]
    assert state["world_size"] == 2 and len(state["ranks"]) == 1
    main, other = state["learner"], state["ranks"][0]["learner"]
    for key in SHARED[learner]:
        _assert_same(main[key], other[key], key)
    # Each rank steps its own characters from its own seed: their gyms and noise generators differ.
    gyms = [s["collector"]["sources"][0] for s in (main, other)]
    assert not np.array_equal(gyms[0]["gym"]["sim_state"], gyms[1]["gym"]["sim_state"])
    assert gyms[0]["rng"] != gyms[1]["rng"]
    assert state["rng"]["numpy"] != state["ranks"][0]["rng"]["numpy"]


def test_samples_count_every_rank(runs: dict[str, Path]) -> None:
    two, one = (read_checkpoint(runs[k])[1] for k in ("ppo", "ppo_resumed"))
    assert two["samples"] == 4 * 2 * 8 * 8  # iterations x ranks x rollout length x characters (debug: 8 x 8)
    assert one["samples"] == two["samples"]


@pytest.mark.parametrize(("learner", "straight", "resumed"),
                         [("supertrack", "straight", "killed"), ("ppo", "ppo", "ppo_resumed")])  # fmt: skip
def test_a_stopped_two_rank_run_resumes_exactly(runs: dict[str, Path], learner: str, straight: str,
                                                resumed: str) -> None:  # fmt: skip
    """SuperTrack's was killed with SIGKILL part-way; PPO's stopped at its budget and continued."""
    a, b = (read_checkpoint(runs[k])[1] for k in (straight, resumed))
    assert a["iteration"] == b["iteration"] and a["samples"] == b["samples"]
    for part_a, part_b in zip([a, *a["ranks"]], [b, *b["ranks"]], strict=True):
        _assert_same(part_a["learner"], part_b["learner"])  # networks, optimisers, buffers, gyms
        _assert_same(_generators(part_a), _generators(part_b))


def test_one_rank_through_torchrun_equals_the_plain_command(runs: dict[str, Path]) -> None:
    a, b = (read_checkpoint(runs[k])[1] for k in ("one_rank", "plain"))
    assert "world_size" not in a and "ranks" not in a
    _assert_same(a["learner"], b["learner"])
    _assert_same(_generators(a), _generators(b))
    ma, mb = (read_metrics(runs[k] / "metrics.jsonl") for k in ("one_rank", "plain"))
    assert [r.get("eval/mpjpe_g") for r in ma] == [r.get("eval/mpjpe_g") for r in mb]


def test_only_rank_zero_writes(runs: dict[str, Path]) -> None:
    """One events file, one metrics line per logged iteration, one record of the start; every rank's state is in
    rank 0's checkpoint, so the other ranks need no files of their own."""
    run = runs["straight"]
    assert len(list((run / "tb").iterdir())) == 1
    iterations = [r["iteration"] for r in read_metrics(run / "metrics.jsonl")]
    logged = [i for i in iterations if i != iterations[-1]]
    assert logged == sorted(set(logged)) and iterations[-1] == 8
    info = json.loads((run / "run_info.json").read_text())
    assert info["world_size"] == 2 and info["command"].startswith("torchrun --nproc_per_node=2 -m supertrack.train --")
    files = sorted(p.relative_to(run).as_posix() for p in run.rglob("*") if p.is_file() and p.parent.name != "tb")
    assert files == ["checkpoints/ckpt_00000007.pt", "checkpoints/ckpt_00000008.pt", "checkpoints/latest.json",
                     "config.yaml", "metrics.jsonl", "run_info.json"]  # fmt: skip


def test_resume_with_another_number_of_ranks_is_refused_in_one_line(runs: dict[str, Path]) -> None:
    done = subprocess.run(_command("supertrack", None, runs["straight"], "--resume", "--max-iterations", "9"),
                          cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "written by a run of 2 rank(s), this run has 1" in lines[0], done.stderr
    assert "--nproc_per_node=2" in lines[0]
    assert read_checkpoint(runs["straight"])[1]["iteration"] == 8  # nothing written


def test_a_single_process_world_calls_no_collective() -> None:
    world = World()
    loss = torch.tensor(2.5)
    param = torch.nn.Parameter(torch.ones(3))
    param.grad = torch.full((3,), 0.5)
    assert world.average_gradients([param], loss, "policy") is loss and torch.equal(param.grad, torch.full((3,), 0.5))
    assert world.decide(any_request=False, budget=True) == {"any_request": False, "budget": True}
    assert world.all_gather({"a": 1}) == [{"a": 1}] and world.from_main(3) == 3 and world.mean(0.25) == 0.25
    assert world.generator(7).integers(1000) == np.random.default_rng(7).integers(1000)
    assert world.device("cuda") == "cuda" and world.first_source(3) == 0


def test_rank_seeds_and_devices() -> None:
    world = World(rank=1, size=2, local_rank=1)
    assert world.device("cuda") == "cuda:1" and world.device("cuda:0") == "cuda:0" and world.device("cpu") == "cpu"
    assert world.first_source(0) == 1 and world.first_source(3) == 3  # rank 1's sources follow rank 0's
    assert world.generator(7).integers(1000) == np.random.default_rng([7, 1]).integers(1000)


@pytest.mark.parametrize(("env", "message"), [
    ({"WORLD_SIZE": "two"}, "WORLD_SIZE='two' is not an integer"),
    ({"WORLD_SIZE": "2", "RANK": "2"}, "need 0 <= RANK < WORLD_SIZE"),
    ({"WORLD_SIZE": "0"}, "need 0 <= RANK < WORLD_SIZE"),
])  # fmt: skip
def test_a_bad_torchrun_environment_is_named(env: dict[str, str], message: str) -> None:
    with pytest.raises(DistributedError, match=message):
        from_environment(env)
    assert from_environment({"WORLD_SIZE": "4", "RANK": "3", "LOCAL_RANK": "1"}) == World(rank=3, size=4, local_rank=1)
