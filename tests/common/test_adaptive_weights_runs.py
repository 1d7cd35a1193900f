"""Both learners' debug runs on several clips with PARC's adaptive clip weights on: the failure rates move, the gym's
starts follow them, and a run stopped halfway and resumed ends bit for bit where the straight run does."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from common.run.directory import read_checkpoint
from ppo.train import main as ppo_main
from supertrack.train import run as supertrack_run
from tests.supertrack.test_train import _assert_same_tensors

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
# Episodes of 9 frames with the failure rules checked from the first: many episodes end (most truncated, some
# terminated) within a debug run, and a large EMA weight lets the rates move visibly in that time.
ADAPTIVE = ("--motions", "walk", "run", "jump", "--set", "motion_weights.enabled=true",
            "--set", "motion_weights.ema_weight=0.2", "--set", "gym.termination.max_episode_frames=9",
            "--set", "gym.termination.grace_frames=0")  # fmt: skip


def _supertrack(out: Path, *extra: str) -> None:
    supertrack_run(["--config", str(CONFIGS / "supertrack" / "debug.yaml"), "--out", str(out), *ADAPTIVE, *extra])


def _ppo(out: Path, *extra: str) -> None:
    assert ppo_main(["--config", str(CONFIGS / "ppo" / "debug.yaml"), "--out", str(out), *ADAPTIVE, *extra]) == 0


@pytest.mark.parametrize("train", [_supertrack, _ppo], ids=["supertrack", "ppo"])
def test_adaptive_weights_move_and_a_resumed_run_ends_where_the_straight_one_does(
        train: Callable[..., None], tmp_path: Path) -> None:  # fmt: skip
    train(tmp_path / "straight", "--max-iterations", "6")
    train(tmp_path / "resumed", "--max-iterations", "3")
    train(tmp_path / "resumed", "--resume", "--max-iterations", "6")
    straight, resumed = (read_checkpoint(tmp_path / k)[1] for k in ("straight", "resumed"))
    assert straight["iteration"] == resumed["iteration"] == 6
    _assert_same_tensors(straight["learner"], resumed["learner"])
    rates = straight["learner"]["motion_weights"]["failure_rate"]
    assert rates.shape == (3,) and rates.min() < 1.0  # episodes ended and moved the rates from the presumed 1.0
    gym = straight["learner"]["collector"]["sources"][0]["gym"]
    assert len(np.unique(gym["clip"])) >= 2  # the starts are spread over the clips
