"""Policies bundled with the project: a run reduced to its policy reads like the run and acts exactly as it does."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import common.bundled_configs as bundled
from common.character.humanoid import Humanoid
from common.evaluation.evaluate import EvalConfig, evaluate
from common.motion.dataset import load_motions
from ppo.train import main as ppo_main
from report.bundle_policy import bundle
from report.bundle_policy import main as bundle_main
from report.runs import ReportError, export_module, load_run
from supertrack.train import run as supertrack_run

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def _supertrack(out: Path) -> None:
    supertrack_run(["--config", str(CONFIGS / "supertrack" / "debug.yaml"), "--out", str(out)])


def _ppo(out: Path) -> None:
    assert ppo_main(["--config", str(CONFIGS / "ppo" / "debug.yaml"), "--out", str(out)]) == 0


def _judge(path: Path | str) -> dict[str, float]:
    run = load_run(path)
    humanoid = Humanoid(run.physics())
    library = load_motions(["walk", "run"], humanoid)
    policy = export_module(run.learner).load_eval_policy(run.path, run.checkpoint, humanoid, library)
    result = evaluate(policy, library, humanoid, EvalConfig(starts_per_clip=2, max_frames=40, threads=1))
    return {k: float(v) for k, v in result.overall.items()}


@pytest.mark.parametrize("train", [_supertrack, _ppo], ids=["supertrack", "ppo"])
def test_a_bundle_reads_like_its_run_and_acts_exactly_as_it_does(
        train: Callable[[Path], None], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    train(tmp_path / "run")
    monkeypatch.setattr(bundled, "PRETRAINED_ROOT", tmp_path / "pretrained")
    assert bundle_main([str(tmp_path / "run"), "--name", "mine", "--root", str(tmp_path / "pretrained"),
                        "--note", "a debug run"]) == 0  # fmt: skip
    out = tmp_path / "pretrained" / "mine"
    assert sorted(p.name for p in out.iterdir()) == ["config.yaml", "latest.json", "policy.pt", "run_info.json"]
    info = json.loads((out / "run_info.json").read_text())
    assert info["note"] == "a debug run" and info["motions"] == ["walk"]
    assert info["source"]["iteration"] == load_run(tmp_path / "run").iteration > 0
    # The policy file holds the policy and nothing else of the learner (no buffers, optimisers or gym states).
    assert (out / "policy.pt").stat().st_size < 0.5 * min(p.stat().st_size for p in (tmp_path / "run" /
                                                                                      "checkpoints").glob("*.pt"))
    assert _judge("pretrained:mine") == _judge(tmp_path / "run")
    np.testing.assert_equal(load_run("pretrained:mine").path, out)


def test_bundling_refuses_a_samcon_run_an_existing_folder_and_a_tampered_file(tmp_path: Path) -> None:
    samcon = tmp_path / "samcon"
    samcon.mkdir()
    (samcon / "config.yaml").write_text("train: {}\n")
    (samcon / "run_info.json").write_text(json.dumps({"learner": "samcon", "policy_file": "samcon.h5"}))
    (samcon / "samcon.h5").write_bytes(b"")
    with pytest.raises(ReportError, match="holds no network policy"):
        bundle(samcon, tmp_path / "b")
    _ppo(tmp_path / "run")
    bundle(tmp_path / "run", tmp_path / "b")
    with pytest.raises(ReportError, match="already exists"):
        bundle(tmp_path / "run", tmp_path / "b")
    policy = tmp_path / "b" / "policy.pt"
    policy.write_bytes(policy.read_bytes()[:-1] + bytes([policy.read_bytes()[-1] ^ 1]))  # one bit flipped
    with pytest.raises((ReportError, ValueError), match="policy.pt"):
        _judge(tmp_path / "b")


def test_the_shipped_general_policy_loads_weights_only_and_tracks_walk_it_never_trained_on() -> None:
    """pretrained/general: SuperTrack trained on the generalisation split's training clips (walk held out)."""
    run = load_run("pretrained")
    assert run.path == bundled.PRETRAINED_ROOT / "general" and run.learner == "supertrack"
    assert "walk" not in run.motions and (run.path / "policy.pt").stat().st_size < 5e6
    humanoid = Humanoid(run.physics())
    library = load_motions(["walk"], humanoid)
    # load_eval_policy reads the file with torch.load(weights_only=True) and checks its recorded SHA-256.
    policy = export_module(run.learner).load_eval_policy(run.path, run.checkpoint, humanoid, library)
    result = evaluate(policy, library, humanoid, EvalConfig(starts_per_clip=2, max_frames=300, threads=1))
    assert result.overall["survival"] == 1.0 and result.overall["mpjpe_l"] < 60.0
