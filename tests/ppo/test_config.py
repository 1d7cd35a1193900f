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
    term = cfg.gym.termination
    assert term.grace_frames == 0 and term.fall_contact == "deepmimic"
    # PARC's reward and observation; rules measured against the reference (no absolute root height)
    assert cfg.gym.reward.preset == "parc" and cfg.gym.reward.form == "product" and cfg.observation.kind == "parc"
    assert term.min_root_height is None and term.root_height_error == 0.3 and term.contact_clearance == 0.1
    # the YAML spells out what the preset would give
    assert cfg.gym.reward == type(cfg.gym.reward)(preset="parc")
    # a config without a gym section gets the same PPO defaults as default.yaml
    if name == "default":
        assert PPOTrackerConfig().gym.termination == term and PPOTrackerConfig().gym.reward == cfg.gym.reward
        assert PPOTrackerConfig().observation == cfg.observation


def test_paper_config_is_parc_scale() -> None:
    cfg = load_config(PPOTrackerConfig, CONFIGS / "paper.yaml")
    assert (cfg.gym.num_envs, cfg.ppo.rollout_length, cfg.ppo.epochs, cfg.ppo.minibatch_size) == (4096, 8, 5, 4096)
    assert cfg.ppo.actor_lr == 1e-4 and cfg.network.actor_hidden == (1024, 512, 512)
    assert cfg.ppo.advantage_clip == 5.0 and cfg.network.learn_std
    assert cfg.observation.future_frames == (2, 4, 6, 20, 40, 60)  # PARC's 1, 2, 3, 10, 20, 30 at 30 Hz


def test_unknown_key_is_rejected_with_its_path() -> None:
    with pytest.raises(ConfigError, match="unknown key 'ppo.lr' \\(allowed: .*actor_lr"):
        load_config(PPOTrackerConfig, CONFIGS / "debug.yaml", ["ppo.lr=1e-3"])


def test_minibatch_must_divide_the_rollout(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="minibatch_size \\(48\\) must divide the rollout of .* = 64 samples"):
        load_config(PPOTrackerConfig, CONFIGS / "debug.yaml", ["ppo.minibatch_size=48"])
