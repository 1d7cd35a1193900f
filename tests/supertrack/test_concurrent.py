"""``policy.concurrent``: the policy step in a second thread beside W's steps, through W as the update found it.

One torch thread (the autouse fixture of conftest.py, as the Trainer sets train.torch_threads): a reduction split over
a varying number of threads would change bits."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from common.character.humanoid import Humanoid
from common.config import load_config
from common.motion.dataset import load_motions
from supertrack.config import SuperTrackConfig
from supertrack.learner import SuperTrackLearner

DEBUG = str(Path(__file__).resolve().parents[2] / "configs" / "supertrack" / "debug.yaml")


def _learner(*overrides: str) -> SuperTrackLearner:
    cfg = load_config(SuperTrackConfig, DEBUG, list(overrides))
    humanoid = Humanoid(cfg.gym.physics)
    torch.manual_seed(0)  # the networks' initialisation, then the policy's noise: build and train one at a time
    return SuperTrackLearner(cfg, humanoid, load_motions(["walk"], humanoid), np.random.default_rng(0))


def _trained(iterations: int, *overrides: str) -> tuple[SuperTrackLearner, list[dict[str, float]]]:
    learner = _learner(*overrides)
    return learner, _train(learner, iterations)


def _train(learner: SuperTrackLearner, iterations: int) -> list[dict[str, float]]:
    logs = []
    try:
        for _ in range(iterations):
            learner.collect()
            logs.append(learner.update())
    finally:
        learner.close()
    return logs


def _weights(learner: SuperTrackLearner) -> dict[str, torch.Tensor]:
    return {**{f"w.{k}": v for k, v in learner.world_model.state_dict().items()},
            **{f"p.{k}": v for k, v in learner.policy_net.state_dict().items()}}  # fmt: skip


def test_with_a_still_world_model_the_concurrent_update_is_the_serial_one() -> None:
    # With W's learning rate 0 the W steps leave W as it was, so "W before this update's W steps" (concurrent) and
    # "W after them" (serial) are one network: the same windows, noise and order must give the same bits.
    serial, logs_s = _trained(4, "world_model.lr=0.0")
    concurrent, logs_c = _trained(4, "world_model.lr=0.0", "policy.concurrent=true")
    assert [x.get("losses/policy") for x in logs_s] == [x.get("losses/policy") for x in logs_c]
    assert logs_s[-1]["losses/policy"] > 0
    ws, wc = _weights(serial), _weights(concurrent)
    for name in ws:
        torch.testing.assert_close(ws[name], wc[name], rtol=0, atol=0, msg=name)


def test_the_policy_learns_through_w_as_the_update_found_it() -> None:
    learner = _learner("policy.concurrent=true")
    learner.collect()
    learner.update()  # W only (start_iteration 1)
    learner.collect()
    before = {k: v.clone() for k, v in learner.world_model.state_dict().items()}
    learner.update()
    after = learner.world_model.state_dict()
    copy = learner.policy_world.state_dict()
    learner.close()
    assert learner.policy_world is not learner.world_model
    assert learner.policy_world.local_norm is learner.policy_net.local_norm
    assert any(not torch.equal(before[k], after[k]) for k in before), "W's steps changed W"
    for k in before:
        torch.testing.assert_close(copy[k], before[k], rtol=0, atol=0, msg=k)
    assert not any(p.requires_grad for p in learner.policy_world.parameters())
    assert all(p.requires_grad for p in learner.world_model.parameters())


def test_concurrent_runs_of_one_seed_are_identical_and_differ_from_serial() -> None:
    a, logs_a = _trained(5, "policy.concurrent=true")
    b, logs_b = _trained(5, "policy.concurrent=true")
    s, logs_s = _trained(5)
    assert [x["losses/world_model"] for x in logs_a] == [x["losses/world_model"] for x in logs_b]
    wa, wb, ws = _weights(a), _weights(b), _weights(s)
    for name in wa:
        torch.testing.assert_close(wa[name], wb[name], rtol=0, atol=0, msg=name)
    # W sees the same windows in both modes, so its losses agree until the policy's data differs; the policies
    # themselves learn through different W's from the second policy step on.
    assert logs_a[1]["losses/world_model"] == logs_s[1]["losses/world_model"]
    assert any(not torch.equal(wa[k], ws[k]) for k in wa if k.startswith("p."))
