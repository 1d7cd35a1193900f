"""``export-policy``: the ONNX graph of each learner is its evaluation policy, checked on real gym states."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import onnx
import onnxruntime
import pytest
import torch

from common.character.humanoid import Humanoid, hinges_to_joint_rotations, joint_rotations_to_hinges
from common.motion.dataset import load_motions
from common.motion.library import MotionLibrary
from common.sim.gym import GymConfig, StepResult, TrackingGym
from common.sim.observation import Observer
from ppo.export import load_actor
from ppo.train import main as train_ppo
from report.export_policy import main, sidecar_path
from report.runs import export_module, load_run
from supertrack.state import pack_character_state
from supertrack.train import run as train_supertrack

ROOT = Path(__file__).resolve().parents[2]
# onnxruntime against torch, both float32: the same operations in another order differ by a few float32 ulps.
ORT_TOL = 1e-5
# The exported PPO graph normalises in float32, the evaluation policy in float64 before casting (rad).
PPO_EVAL_TOL = 1e-5


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Path]]:
    """{learner: (run directory, ONNX file)} of two tiny runs; SuperTrack's reads the root offset features too."""
    torch.set_num_threads(1)
    base = tmp_path_factory.mktemp("export")
    train_supertrack(["--config", str(ROOT / "configs/supertrack/debug.yaml"), "--out", str(base / "st"),
                      "--max-iterations", "2", "--set", "policy.root_offset=true"])  # fmt: skip
    train_ppo(["--config", str(ROOT / "configs/ppo/debug.yaml"), "--out", str(base / "ppo"), "--max-iterations", "2"])
    out = {}
    for learner, run_dir in (("supertrack", base / "st"), ("ppo", base / "ppo")):
        assert main([str(run_dir), "--onnx", str(base / f"{learner}.onnx")]) == 0
        out[learner] = (run_dir, base / f"{learner}.onnx")
    return out


def _gym_states(policy: Callable[[StepResult], np.ndarray], library: MotionLibrary, humanoid: Humanoid,
                steps: int = 6) -> list[StepResult]:  # fmt: skip
    """The states of 8 characters over ``steps`` control steps of ``policy`` on walk (reset states excluded)."""
    gym = TrackingGym(GymConfig(num_envs=8, threads=1, physics=humanoid.physics), library, humanoid)
    res, out = gym.reset(), []
    for _ in range(steps):
        res = gym.step(policy(res))
        out.append(res)
    return out


def _run_both(session: onnxruntime.InferenceSession, module: torch.nn.Module,
              inputs: dict[str, np.ndarray]) -> tuple[list[np.ndarray], list[np.ndarray]]:  # fmt: skip
    """(onnxruntime's outputs, torch's outputs) on the same float32 inputs."""
    ort = session.run(None, inputs)
    with torch.no_grad():
        ref = [t.numpy() for t in module(*(torch.as_tensor(x) for x in inputs.values()))]
    return ort, ref


def _load(learner: str, run_dir: Path) -> tuple[Humanoid, MotionLibrary, torch.nn.Module, dict, Callable]:
    run = load_run(run_dir)
    humanoid = Humanoid(run.physics())
    library = load_motions(["walk"], humanoid)
    module, spec = export_module(learner).onnx_module(run.path, run.checkpoint, humanoid)
    policy = export_module(learner).load_eval_policy(run.path, run.checkpoint, humanoid, library)
    return humanoid, library, module, spec, policy


def test_supertrack_graph_is_the_eval_policy(exported: dict[str, tuple[Path, Path]]) -> None:
    run_dir, path = exported["supertrack"]
    humanoid, library, module, spec, policy = _load("supertrack", run_dir)
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    states = _gym_states(policy, library, humanoid)
    for res in states:
        inputs = {
            "sim_state": pack_character_state(res.sim), "kin_next_state": pack_character_state(res.ref_next),
            "kin_next_joint_rot": hinges_to_joint_rotations(humanoid, res.ref_next.qpos).astype(np.float32),
        }  # fmt: skip
        (ort_offsets, ort_target), (offsets, target) = _run_both(session, module, inputs)
        assert np.abs(ort_offsets - offsets).max() < ORT_TOL and np.abs(ort_target - target).max() < ORT_TOL
        assert np.abs(offsets).max() > 1e-3  # a policy that acts, not the zero offsets of an empty graph
        # The actor's own last step: hinge angles of the target rotations, nearest the reference's.
        hinges = joint_rotations_to_hinges(humanoid, target.astype(np.float64), near_qpos=res.ref_next.qpos)
        np.testing.assert_array_equal(hinges, policy(res))
    one = {k: v[:1] for k, v in inputs.items()}  # a free batch axis: one character, as an engine runs it
    ort, ref = _run_both(session, module, one)
    assert ort[1].shape == (1, len(humanoid.joint_groups), 4) and np.abs(ort[1] - ref[1]).max() < ORT_TOL


def test_ppo_graph_is_the_eval_policy(exported: dict[str, tuple[Path, Path]]) -> None:
    run_dir, path = exported["ppo"]
    humanoid, library, module, spec, policy = _load("ppo", run_dir)
    observe = Observer(load_actor(run_dir, load_run(run_dir).checkpoint, humanoid)[0].observation, humanoid, library)
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    states = _gym_states(policy, library, humanoid)
    obs = np.concatenate([observe(res) for res in states]).astype(np.float32)
    ref_hinges = np.concatenate([res.ref_next.qpos[:, humanoid.hinge_qpos] for res in states]).astype(np.float32)
    (ort_action, ort_targets), (action, targets) = _run_both(
        session, module, {"observation": obs, "ref_next_hinges": ref_hinges}
    )
    assert np.abs(ort_action - action).max() < ORT_TOL and np.abs(ort_targets - targets).max() < ORT_TOL
    assert np.abs(action).max() > 1e-3
    expected = np.concatenate([policy(res) for res in states])
    assert np.abs(targets - expected).max() < PPO_EVAL_TOL
    np.testing.assert_allclose(targets, ref_hinges + spec["policy"]["action_scale_rad"] * action, rtol=0, atol=1e-6)


@pytest.mark.parametrize("learner", ["supertrack", "ppo"])
def test_sidecar_describes_the_graph(exported: dict[str, tuple[Path, Path]], learner: str) -> None:
    run_dir, path = exported[learner]
    sidecar = json.loads(sidecar_path(path).read_text())
    model = onnx.load(str(path))
    assert (sidecar["learner"], sidecar["iteration"], sidecar["opset"]) == (learner, 2, 18)
    assert {o.version for o in model.opset_import if o.domain in ("", "ai.onnx")} == {18}
    assert sidecar["check"]["max_abs_diff_onnxruntime_torch"] < ORT_TOL
    for described, actual in ((sidecar["inputs"], model.graph.input), (sidecar["outputs"], model.graph.output)):
        assert [t["name"] for t in described] == [t.name for t in actual]
        for t, value in zip(described, actual, strict=True):
            dims = [d.dim_param or d.dim_value for d in value.type.tensor_type.shape.dim]
            assert dims == t["shape"] and t["meaning"]
    if learner == "ppo":
        features = sidecar["inputs"][0]["layout"]["features"]
        assert sum(f["width"] for f in features) == sidecar["inputs"][0]["shape"][1]
        assert features[0]["name"] == "sim_pos" and sidecar["inputs"][1]["layout"]["actuators"][0] == "chest_x"
    else:
        assert sidecar["inputs"][0]["layout"]["fields"] == {"pos": 3, "rot": 4, "vel": 3, "angvel": 3}
        assert sidecar["policy"]["averaged_weights"] and sidecar["policy"]["root_offset"]


def _fake_run(path: Path, info: dict) -> Path:
    path.mkdir()
    (path / "config.yaml").write_text("train: {}\n")
    (path / "run_info.json").write_text(json.dumps(info))
    return path


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("missing", "not a directory"),
        ("unknown", "unknown learner 'dreamer'"),
        ("samcon", "SAMCON has no network policy to export"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str,
                                         message: str) -> None:  # fmt: skip
    if case == "missing":
        run_dir = tmp_path / "nothing"
    elif case == "unknown":
        run_dir = _fake_run(tmp_path / "run", {"learner": "dreamer"})
    else:
        run_dir = _fake_run(tmp_path / "run", {"learner": "samcon", "policy_file": "samcon.h5"})
        (run_dir / "samcon.h5").write_bytes(b"")
    assert main([str(run_dir), "--onnx", str(tmp_path / "p.onnx")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and message in err
    assert not (tmp_path / "p.onnx").exists() and not sidecar_path(tmp_path / "p.onnx").exists()


def test_lower_opset_is_converted_or_refused(exported: dict[str, tuple[Path, Path]], tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Engines with older runtimes ask for older opsets: 15 converts (and runs), 9 cannot and nothing is written."""
    run_dir, _ = exported["ppo"]
    assert main([str(run_dir), "--onnx", str(tmp_path / "p15.onnx"), "--opset", "15"]) == 0
    model = onnx.load(str(tmp_path / "p15.onnx"))
    assert {o.version for o in model.opset_import if o.domain in ("", "ai.onnx")} == {15}
    assert json.loads(sidecar_path(tmp_path / "p15.onnx").read_text())["opset"] == 15
    capsys.readouterr()
    assert main([str(run_dir), "--onnx", str(tmp_path / "p9.onnx"), "--opset", "9"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "could not be converted to opset 9" in err
    assert not (tmp_path / "p9.onnx").exists() and not sidecar_path(tmp_path / "p9.onnx").exists()
