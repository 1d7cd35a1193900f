"""The three PPO configs load, and bad configs fail with clear messages."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.config import ConfigError, load_config
from ppo.config import PPOTrackerConfig

CONFIGS = Path(__file__).resolve().parents[2] / "configs" / "ppo"


@pytest.mark.parametrize("name", ["default", "paper", "debug"])
def test_configs_load(name: str) -> None:
    cfg = load_config(PPOTrackerConfig, CONFIGS / f"{name}.yaml")
    assert cfg.batch_size % cfg.ppo.minibatch_size == 0
    assert cfg.gym.termination.grace_frames == 0 and cfg.gym.termination.fall_contact == "deepmimic"


def test_paper_config_is_parc_scale() -> None:
    cfg = load_config(PPOTrackerConfig, CONFIGS / "paper.yaml")
    assert (cfg.gym.num_envs, cfg.ppo.rollout_length, cfg.ppo.epochs, cfg.ppo.minibatch_size) == (4096, 8, 5, 4096)
    assert cfg.ppo.actor_lr == 1e-4 and cfg.network.actor_hidden == (1024, 512, 512)


def test_unknown_key_is_rejected_with_its_path() -> None:
    with pytest.raises(ConfigError, match="unknown key 'ppo.lr' \\(allowed: .*actor_lr"):
        load_config(PPOTrackerConfig, CONFIGS / "debug.yaml", ["ppo.lr=1e-3"])


def test_minibatch_must_divide_the_rollout(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="minibatch_size \\(48\\) must divide the rollout of .* = 64 samples"):
        load_config(PPOTrackerConfig, CONFIGS / "debug.yaml", ["ppo.minibatch_size=48"])
