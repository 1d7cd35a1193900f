"""AMP for PPO: the discriminator's losses, gradient penalty and reward by hand, the features (one layout for the
policy's and the expert's transitions), the replay buffer's turnover, the config's checks, and the learner with AMP
off (nothing built, the task reward) and on (the mixed reward)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from common.character.humanoid import Humanoid
from common.character.state import CharacterState
from common.config import ConfigError, load_config
from common.maths.rotations import quat_from_yaw, quat_mul, quat_rotate
from common.motion.dataset import load_motions
from common.motion.library import MotionLibrary
from common.sim.collect import LocalCollector
from common.sim.gym import GymConfig, TrackingGym
from common.sim.observation import ObservationConfig, Observer
from ppo.actor import GymActor, observation_layout
from ppo.amp import accuracy, amp_reward, classification_loss, discriminator_loss, gradient_penalty
from ppo.amp_data import AMPFeatures, ExpertSampler, TransitionReplay
from ppo.config import AMPConfig, NetworkConfig, PPOTrackerConfig
from ppo.learner import PPOLearner
from ppo.networks import ActorCritic
from ppo.normalizer import RunningNormalizer

DEBUG = Path(__file__).resolve().parents[2] / "configs" / "ppo" / "debug.yaml"


def _t(*values: float) -> torch.Tensor:
    return torch.tensor(values, dtype=torch.float32)


def _raw_of_tanh(*scores: float) -> torch.Tensor:
    return torch.atanh(torch.tensor(scores, dtype=torch.float64)).float()


# ----------------------------------------------------------------------------------------------- losses by hand
def test_hinge_losses_by_hand() -> None:
    raw = _raw_of_tanh(0.5, -0.8)
    # expert label 1: max(0, 1 - 0.5) = 0.5, max(0, 1 + 0.8) = 1.8; policy label -1: 1.5, 0.2
    assert classification_loss(raw, True, "tanh", 0.0).item() == pytest.approx(1.15, abs=1e-6)
    assert classification_loss(raw, False, "tanh", 0.0).item() == pytest.approx(0.85, abs=1e-6)
    # label smoothing 0.1: labels 0.9 and -0.9: 1 - 0.45 = 0.55, 1 + 0.72 = 1.72; 1.45, 0.28
    assert classification_loss(raw, True, "tanh", 0.1).item() == pytest.approx(1.135, abs=1e-6)
    assert classification_loss(raw, False, "tanh", 0.1).item() == pytest.approx(0.865, abs=1e-6)
    assert classification_loss(_t(20.0), True, "tanh", 0.0).item() == 0.0  # tanh(20) = 1 in float32: no loss


def test_bce_losses_by_hand() -> None:
    raw = _t(0.0, math.log(3.0))  # sigmoid 0.5 and 0.75
    assert classification_loss(raw, True, "sigmoid", 0.0).item() == pytest.approx(
        (math.log(2) + math.log(4 / 3)) / 2, abs=1e-6
    )  # -ln 0.5, -ln 0.75
    assert classification_loss(raw, False, "sigmoid", 0.0).item() == pytest.approx(
        (math.log(2) + math.log(4)) / 2, abs=1e-6
    )  # -ln 0.5, -ln 0.25
    # expert target 0.9: -(0.9 ln p + 0.1 ln(1 - p)): 0.693147 at p = 0.5, 0.258914 + 0.138629 at p = 0.75
    assert classification_loss(raw, True, "sigmoid", 0.1).item() == pytest.approx(0.545345, abs=1e-6)


def test_gradient_penalty_by_hand() -> None:
    x = torch.tensor([[1.0, 2.0], [0.0, 1.0]], requires_grad=True)
    # score = x1^2 + x2^2: gradients (2, 4) and (0, 2), squared norms 20 and 4
    assert gradient_penalty(x.pow(2).sum(-1), x).item() == pytest.approx(12.0)
    # A linear score w . x has the penalty ||w||^2 = 25, and it is differentiable in w: d/dw = 2 w.
    w = torch.tensor([3.0, 4.0], requires_grad=True)
    penalty = gradient_penalty(x @ w, x)
    assert penalty.item() == pytest.approx(25.0)
    penalty.backward()
    torch.testing.assert_close(w.grad, torch.tensor([6.0, 8.0]))


def test_accuracy_counts_each_side_of_zero() -> None:
    raw = _t(0.3, -0.2, 1.5, -4.0)
    assert accuracy(raw, True).item() == 0.5 and accuracy(raw, False).item() == 0.5
    assert accuracy(_t(2.0, 1.0, -1.0), True).item() == pytest.approx(2 / 3)


def test_rsl_rl_reward_by_hand_with_the_clamp_and_the_epsilon() -> None:
    c = AMPConfig(weight=1.0)
    r = amp_reward(_raw_of_tanh(0.5, 0.9, 0.0, -0.9), c)
    # -ln(1 - 0.5) - 0.45, -ln(0.1) - 0.45; -ln(1) - 0.45 = -0.45 and -ln(1.9) - 0.45 = -1.09 clamped to -0.1
    torch.testing.assert_close(r, _t(0.693147 - 0.45, 2.302585 - 0.45, -0.1, -0.1), atol=2e-6, rtol=0)
    # tanh(20) = 1: 1 - 1 = 0 floored at epsilon 1e-4: -ln(1e-4) - 0.45 = 8.760340
    assert amp_reward(_t(20.0), c).item() == pytest.approx(9.210340 - 0.45, abs=1e-5)
    # label smoothing 0.1: -ln(1 - 0.5 - 0.1) - 0.45; 1 - 0.95 - 0.1 < 0 floored at epsilon
    smooth = amp_reward(_raw_of_tanh(0.5, 0.95), replace(c, label_smoothing=0.1))
    torch.testing.assert_close(smooth, _t(0.916291 - 0.45, 9.210340 - 0.45), atol=2e-5, rtol=0)
    # with a sigmoid output the score is sigmoid(x): sigmoid(0) = 0.5
    assert amp_reward(_t(0.0), replace(c, output="sigmoid")).item() == pytest.approx(0.693147 - 0.45, abs=1e-6)


def test_mimickit_reward_by_hand_with_the_epsilon() -> None:
    c = AMPConfig(weight=1.0, output="sigmoid", reward="mimickit")
    r = amp_reward(_t(0.0, math.log(3.0), -math.log(3.0), 20.0), c)
    # -ln(1 - p) * 2 at p = 0.5, 0.75, 0.25; at x = 20, 1 - p = 0 in float32, floored at 1e-4: 2 * 9.210340
    torch.testing.assert_close(r, _t(2 * 0.693147, 2 * 1.386294, 2 * 0.287682, 2 * 9.210340), atol=3e-5, rtol=0)


def test_discriminator_loss_sums_its_terms_by_hand() -> None:
    c = AMPConfig(weight=1.0, lambda_gp=0.5, logit_reg=0.01, weight_decay=1e-3)
    expert_raw, policy_raw = _raw_of_tanh(0.5, -0.8), _raw_of_tanh(-0.5, -0.8, 0.3)
    weights = [torch.tensor([[1.0, 2.0], [3.0, 0.0]]), torch.tensor([[2.0, -1.0]])]  # squared sums 14 and 5
    loss, m = discriminator_loss(expert_raw, policy_raw, torch.tensor(12.0), weights, c)
    # expert 1.15; policy (0.5 + 0.2 + 1.3) / 3; 0.5 (1.15 + 2/3) + 0.5 * 12 + 0.01 * 5 + 1e-3 * (14 + 5)
    assert m["policy_loss"].item() == pytest.approx(2 / 3, abs=1e-6)
    assert loss.item() == pytest.approx(0.5 * (1.15 + 2 / 3) + 6.0 + 0.05 + 0.019, abs=1e-5)
    assert m["expert_accuracy"].item() == 0.5 and m["policy_accuracy"].item() == pytest.approx(2 / 3)
    assert m["logit_reg"].item() == 5.0 and m["weight_decay"].item() == 19.0 and m["grad_penalty"].item() == 12.0


# ----------------------------------------------------------------------------------------------- features
@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


@pytest.fixture(scope="module")
def library(humanoid: Humanoid) -> MotionLibrary:
    return load_motions(["walk"], humanoid)


def test_feature_layout(humanoid: Humanoid) -> None:
    features = AMPFeatures(humanoid)
    widths = {k: s.stop - s.start for k, s in features.layout.items()}
    assert widths == {"root_height": 1, "root_rot": 6, "root_vel": 3, "root_angvel": 3, "joint_rot": 72,
                      "joint_vel": 28, "end_effectors": 12}  # fmt: skip
    assert features.size == 125 and AMPFeatures(humanoid, end_effectors=False).size == 113


def test_features_by_hand_and_under_a_turn_and_a_shift(humanoid: Humanoid, library: MotionLibrary) -> None:
    features = AMPFeatures(humanoid)
    state = library.query(np.array([0]), np.array([0.5]))
    root, effector = humanoid.root_index, humanoid.end_effector_indices[0]
    state.body_rot[0, root] = quat_from_yaw(np.array(np.pi / 2))  # upright, facing +Y
    state.body_pos[0, root] = (3.0, 4.0, 0.9)
    state.body_linvel[0, root] = (1.0, 0.0, 0.0)
    state.body_angvel[0, root] = (0.0, 0.0, 2.0)
    state.body_pos[0, effector] = (3.0, 5.0, 0.9)  # 1 m along the world's +Y: the root's +X
    f = features.named(state)
    np.testing.assert_allclose(f["root_height"], [[0.9]])
    np.testing.assert_allclose(f["root_rot"], [[1, 0, 0, 0, 1, 0]], atol=1e-12)  # no tilt
    np.testing.assert_allclose(f["root_vel"], [[0.0, -1.0, 0.0]], atol=1e-12)  # +X is the heading frame's -Y
    np.testing.assert_allclose(f["root_angvel"], [[0.0, 0.0, 2.0]], atol=1e-12)
    np.testing.assert_allclose(f["end_effectors"][:, :3], [[1.0, 0.0, 0.0]], atol=1e-12)
    np.testing.assert_array_equal(f["joint_vel"], state.qvel[:, humanoid.hinge_dof])
    # The whole character turned by 0.7 rad about +Z and moved along the ground: the same features.
    q, shift = quat_from_yaw(np.array(0.7)), np.array([2.0, -1.0, 0.0])
    moved = CharacterState(qpos=state.qpos, qvel=state.qvel, body_pos=quat_rotate(q, state.body_pos) + shift,
                           body_rot=quat_mul(q, state.body_rot), body_linvel=quat_rotate(q, state.body_linvel),
                           body_angvel=quat_rotate(q, state.body_angvel))  # fmt: skip
    np.testing.assert_allclose(features(moved), features(state), atol=1e-6)


def test_the_policy_and_the_expert_paths_give_one_state_the_same_features(
    humanoid: Humanoid, library: MotionLibrary
) -> None:
    """The gym's reset puts each character on the reference at (clip, time): the actor's frame field of that state
    and the expert sampler's transition at (clip, time) hold the same features; the frame's next state is the one
    the step reached."""
    gym = TrackingGym(GymConfig(num_envs=3, threads=1, seed=5), library, humanoid)
    observe = Observer(ObservationConfig(), humanoid, library)
    obs_size = max(s.stop for s in observation_layout(observe, library).values())
    actor = GymActor(humanoid, ActorCritic(obs_size, humanoid.nu, NetworkConfig()),
                     RunningNormalizer(np.ones(obs_size, dtype=bool)), ObservationConfig(), library, NetworkConfig(),
                     amp=AMPConfig(weight=1.0))  # fmt: skip
    try:
        res = gym.reset()
        targets, fields = actor(res, np.random.default_rng(0), noise=np.zeros((3, humanoid.nu)))
        expert, _ = ExpertSampler(library, AMPFeatures(humanoid)).at(res.clip, res.time)
        assert fields["amp_obs"].shape == (3, 125) and fields["amp_obs"].dtype == np.float32
        np.testing.assert_allclose(fields["amp_obs"], expert, atol=1e-5)
        after = gym.step(targets)
        np.testing.assert_array_equal(actor.after_step(after, last=False)["amp_next"],
                                      AMPFeatures(humanoid)(after.final_sim))  # fmt: skip
    finally:
        gym.close()


def test_expert_transitions_are_one_step_apart(library: MotionLibrary, humanoid: Humanoid) -> None:
    features = AMPFeatures(humanoid)
    s, s_next = ExpertSampler(library, features).sample(5, np.random.default_rng(1))
    clips, times = library.sample_starts(5, np.random.default_rng(1))
    np.testing.assert_array_equal(s, features(library.query(clips, times)))
    np.testing.assert_array_equal(s_next, features(library.query(clips, times + library.dt)))


# ----------------------------------------------------------------------------------------------- replay buffer
def test_replay_turnover() -> None:
    """Capacity 10, 3 samples per rollout once full, rollouts of 4 (rows hold their transition's number)."""
    replay, rng = TransitionReplay(10, 2), np.random.default_rng(0)

    def rollout(k: int) -> np.ndarray:
        return np.repeat(np.arange(4 * k, 4 * k + 4, dtype=np.float32)[:, None], 2, axis=1)

    replay.add(rollout(0), 3, rng)
    replay.add(rollout(1), 3, rng)
    assert replay.size == 8 and not replay.full  # until full every transition goes in
    replay.add(rollout(2), 3, rng)  # 8, 9 in rows 8, 9; 10, 11 overwrite 0, 1 in rows 0, 1
    assert replay.full and replay.head == 2
    np.testing.assert_array_equal(replay.data[:, 0], [10, 11, 2, 3, 4, 5, 6, 7, 8, 9])
    replay.add(rollout(3), 3, rng)  # full: 3 of 12..15 overwrite the oldest, rows 2..4
    new = replay.data[2:5, 0]
    assert replay.head == 5 and len(set(new)) == 3 and set(new) <= {12, 13, 14, 15} and list(new) == sorted(new)
    np.testing.assert_array_equal(np.delete(replay.data[:, 0], [2, 3, 4]), [10, 11, 5, 6, 7, 8, 9])
    # A restored buffer continues exactly.
    copy = TransitionReplay(10, 2)
    copy.load_state_dict(replay.state_dict())
    a, b = np.random.default_rng(3), np.random.default_rng(3)
    replay.add(rollout(4), 3, a)
    copy.add(rollout(4), 3, b)
    np.testing.assert_array_equal(copy.data, replay.data)
    np.testing.assert_array_equal(copy.sample(6, a), replay.sample(6, b))
    assert set(replay.sample(50, a)[:, 0]) <= set(replay.data[:, 0])


def test_a_partly_filled_replay_buffer_samples_only_what_it_holds() -> None:
    replay = TransitionReplay(10, 1)
    replay.add(np.array([[7.0], [8.0]], dtype=np.float32), 1, np.random.default_rng(0))
    assert set(replay.sample(40, np.random.default_rng(0))[:, 0]) == {7.0, 8.0}
    state = replay.state_dict()
    assert state["data"].shape == (2, 1)  # a checkpoint holds the filled rows only


# ----------------------------------------------------------------------------------------------- config
@pytest.mark.parametrize(("override", "message"), [
    ("amp.weight=-0.1", r"amp\.weight must be >= 0"),
    ("amp.reward=mimickit", r"mimickit reads the logit of a sigmoid output"),
    ("amp.label_smoothing=0.5", r"label_smoothing must lie in \[0, 0\.5\)"),
    ("amp.batch_size=1", r"amp\.batch_size must be >= 2"),
    ("amp.output=softmax", r"amp\.output"),
])  # fmt: skip
def test_bad_amp_configs_fail_with_their_names(override: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_config(PPOTrackerConfig, DEBUG, [override])


def test_amp_is_off_by_default() -> None:
    assert not PPOTrackerConfig().amp.enabled and PPOTrackerConfig().amp.weight == 0.0
    for name in ("default", "debug", "paper"):
        assert load_config(PPOTrackerConfig, DEBUG.parent / f"{name}.yaml").amp.weight == 0.0


# ----------------------------------------------------------------------------------------------- the learner
def _learner(*overrides: str) -> PPOLearner:
    cfg = load_config(PPOTrackerConfig, DEBUG, list(overrides))
    humanoid = Humanoid(cfg.gym.physics)
    return PPOLearner(cfg, load_motions(["walk"], humanoid), humanoid, np.random.default_rng(0))


@pytest.fixture(scope="module")
def amp_off() -> Iterator[PPOLearner]:
    out = _learner()
    yield out
    out.close()


@pytest.fixture(scope="module")
def amp_on() -> Iterator[PPOLearner]:
    out = _learner("amp.weight=0.5")
    yield out
    out.close()


def test_with_weight_0_nothing_of_amp_is_built_and_gae_reads_the_task_reward(amp_off: PPOLearner) -> None:
    assert amp_off.amp is None and amp_off.state_dict()["amp"] is None
    assert isinstance(amp_off.collector, LocalCollector) and amp_off.collector.source.actor.amp_features is None
    amp_off.collect()
    data = amp_off.buffer.latest(8)
    assert not {"amp_obs", "amp_next"} & set(data)
    np.testing.assert_array_equal(amp_off.rewards(data), data["reward"].astype(np.float64))
    assert not any(k.startswith("amp/") for k in amp_off.update())


def test_with_amp_on_gae_reads_the_task_reward_plus_weight_times_the_amp_reward(amp_on: PPOLearner) -> None:
    amp = amp_on.amp
    assert amp is not None
    amp_on.collect()
    data = amp_on.buffer.latest(8)
    assert data["amp_obs"].shape == data["amp_next"].shape == (8, 8, 125)
    # The normaliser took the rollout's 64 states and the iteration's 2 x 32 expert states; the replay all 64.
    assert amp.normalizer.count == 64 + 2 * 32 and amp.replay.size == 64
    s, s_next = data["amp_obs"].reshape(64, -1), data["amp_next"].reshape(64, -1)
    with torch.no_grad():
        # Normalised, the features the library holds still zeroed (amp.active), as float32 like the learner's.
        norm = [torch.as_tensor(amp.normalizer.normalize(x) * amp.active, dtype=torch.float32) for x in (s, s_next)]
        raw = amp.disc(*norm)
    expected = data["reward"].astype(np.float64) + 0.5 * amp_reward(raw, amp.config).double().numpy().reshape(8, 8)
    np.testing.assert_allclose(amp_on.rewards(data), expected, rtol=0, atol=1e-12)
    before = [p.detach().clone() for p in amp.disc.parameters()]
    metrics = amp_on.update()
    for key in ("amp/expert_loss", "amp/policy_loss", "amp/grad_penalty", "amp/expert_accuracy",
                "amp/policy_accuracy", "amp/reward_mean"):  # fmt: skip
        assert np.isfinite(metrics[key]), key
    assert metrics["amp/steps"] == 2 and metrics["amp/replay_size"] == 64
    assert any(not torch.equal(a, b) for a, b in zip(before, amp.disc.parameters(), strict=True))
    amp_on.collect()
    assert amp.replay.size == 100 and amp.replay.full  # 64 more, of which 28 overwrote the oldest


def test_a_checkpoint_of_another_amp_setting_is_refused(amp_off: PPOLearner, amp_on: PPOLearner) -> None:
    with pytest.raises(ValueError, match="checkpoint has AMP on, this config has it off"):
        amp_off.load_state_dict(amp_on.state_dict())


def test_features_the_library_holds_still_are_zeroed_for_the_discriminator(
        humanoid: Humanoid, library: MotionLibrary) -> None:  # fmt: skip
    """Walk's reference never moves the neck (benchmarks/amp_separability.py): its three hinge velocities are masked,
    the root height is not, and with still_std 0 nothing is."""
    from ppo.amp import AMP

    features = AMPFeatures(humanoid)
    names = list(features.named(library.query(np.array([0]), np.array([0.0]))).items())
    start = {}
    offset = 0
    for name, value in names:
        start[name] = offset
        offset += value.shape[-1]
    neck = [start["joint_vel"] + i for i in (3, 4, 5)]  # hinges 3-5: neck_x, neck_y, neck_z (actuator order)
    amp = AMP(AMPConfig(weight=0.3), features, library, 5.0, 1e-2, torch.device("cpu"), seed=0)
    assert amp.active[neck].tolist() == [0.0, 0.0, 0.0] and amp.active[start["root_height"]] == 1.0
    moving = np.full((4, features.size), 3.0)
    out = amp._normalized(moving).numpy()
    assert np.all(out[:, neck] == 0.0) and np.all(out[:, start["root_height"]] != 0.0)
    keep_all = AMP(AMPConfig(weight=0.3, still_std=0.0), features, library, 5.0, 1e-2, torch.device("cpu"), seed=0)
    assert keep_all.active.min() == 1.0


def test_the_separability_classifier_tells_apart_only_what_differs() -> None:
    """benchmarks/amp_separability.py's per-group discriminator: near 1 on a column that differs between the two
    sides, near 0.5 on columns drawn from one distribution, 0.5 with no column kept."""
    from tests.benchmark_module import benchmark_module

    bench = benchmark_module("amp_separability")
    rng = np.random.default_rng(0)
    policy, expert = rng.normal(size=(2, 800, 4)).astype(np.float32)
    expert[:, 0] += 4.0  # column 0 separates the sides; columns 1-3 are the same distribution
    assert bench._accuracy(policy, expert, np.array([True, False, False, False]), steps=200) > 0.95
    assert abs(bench._accuracy(policy, expert, np.array([False, True, True, True]), steps=200) - 0.5) < 0.1
    assert bench._accuracy(policy, expert, np.zeros(4, dtype=bool), steps=200) == 0.5
