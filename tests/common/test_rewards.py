"""Reward terms against hand-computed errors away from sim = ref, their combination, presets and config checks."""

from __future__ import annotations

import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.character.state import CharacterState
from common.config import ConfigError, from_dict
from common.maths.rotations import quat_from_axis_angle, quat_mul
from common.motion.dataset import load_motions
from common.sim.rewards import DEFAULT_SCALES, RewardConfig, TrackingReward
from common.sim.tracking_rewards import REWARD_TERMS, TERM_FUNCTIONS, Derived, RewardModel, prepare, term_errors

# DeepMimic's joint weights of humanoid3d sum to 4.8 (pelvis 1, torso 0.5, head 0.3, thighs 0.5, shins 0.3,
# feet 0.2, upper arms 0.3, lower arms 0.2, hands 0).
WEIGHT_SUM = 4.8


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


@pytest.fixture(scope="module")
def ref(humanoid: Humanoid) -> CharacterState:
    return load_motions(["walk"], humanoid).query(np.array([0, 0]), np.array([0.3, 0.7]))


def _copy(s: CharacterState) -> CharacterState:
    return CharacterState(**{k: v.copy() for k, v in vars(s).items()})


def _turn(q: np.ndarray, axis: list[float], angle: float) -> np.ndarray:
    return quat_mul(quat_from_axis_angle(np.array(axis), np.array(angle)), q)


def _moved(humanoid: Humanoid, ref: CharacterState) -> CharacterState:
    """A simulated state off the reference in a way every term sees, with errors worked out by hand below."""
    sim = _copy(ref)
    b = humanoid.body_index
    sim.body_pos[:, 0] += [0.1, -0.2, 0.05]  # root: |dp|^2 = 0.01 + 0.04 + 0.0025 = 0.0525
    sim.body_rot[:, 0] = _turn(sim.body_rot[:, 0], [1.0, 0.0, 0.0], 0.4)  # root: 0.16 rad^2
    sim.body_pos[:, b("right_hand")] += [0.0, 0.0, 0.1]  # moves 0.1 m relative to the moved root as well
    sim.body_rot[:, b("right_thigh")] = _turn(sim.body_rot[:, b("right_thigh")], [0.0, 1.0, 0.0], 0.6)
    sim.body_linvel[:, 0] += [1.0, 0.0, 0.0]
    sim.qvel[:, humanoid.hinge_dof[[3, 10]]] += [2.0, -1.0]
    return sim


def test_every_term_by_hand(humanoid: Humanoid, ref: CharacterState) -> None:
    sim, model = _moved(humanoid, ref), RewardModel.from_humanoid(humanoid)
    err = {k: f(sim, ref, model) for k, f in TERM_FUNCTIONS.items()}
    expected = {
        "root_pos": 0.0525,
        "root_rot": 0.16,
        "body_pos": (0.0525 + 0.01) / 15,  # root and right hand moved, out of 15 bodies
        "body_rot": (0.16 + 0.36) / 15,  # root 0.4 rad, right thigh 0.6 rad
        "dof_vel": 2.0**2 + 1.0**2,
        # |dp|^2 + 0.1 angle^2 + 0.01 |dv|^2 + 0.001 |dw|^2 (the root's angular velocity is untouched)
        "root": 0.0525 + 0.1 * 0.16 + 0.01 * 1.0,
    }
    for k, v in expected.items():
        np.testing.assert_allclose(err[k], v, rtol=1e-9, atol=1e-12, err_msg=k)


def test_end_effector_by_hand(humanoid: Humanoid, ref: CharacterState) -> None:
    """Root moved by dp, right hand by (0, 0, 0.1), no rotation: the heading frame is the reference's, so the
    root-relative error has the same length in both: |(0, 0, 0.1) - dp|^2 for the hand, |dp|^2 for the other three."""
    sim = _copy(ref)
    dp = np.array([0.1, -0.2, 0.05])
    sim.body_pos[:, 0] += dp
    sim.body_pos[:, humanoid.body_index("right_hand")] += [0.0, 0.0, 0.1]
    expected = (np.sum((np.array([0.0, 0.0, 0.1]) - dp) ** 2) + 3 * np.sum(dp**2)) / 4
    np.testing.assert_allclose(TERM_FUNCTIONS["end_effector"](sim, ref, RewardModel.from_humanoid(humanoid)),
                               expected, rtol=1e-9)  # fmt: skip


def test_pose_velocity_com_by_hand(humanoid: Humanoid, ref: CharacterState) -> None:
    """A 0.5 rad turn of the torso changes the local rotation of the torso, head and both upper arms by 0.5 rad;
    2 rad/s more on the left foot (weight 0.2, no children) changes only its joint velocity; a common velocity
    added to every body moves the centre of mass by that velocity."""
    model = RewardModel.from_humanoid(humanoid)
    sim = _copy(ref)
    t = humanoid.body_index("torso")
    sim.body_rot[:, t] = quat_mul(sim.body_rot[:, t], quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), np.array(0.5)))
    np.testing.assert_allclose(TERM_FUNCTIONS["pose"](sim, ref, model), (0.5 + 0.3 + 0.3 + 0.3) * 0.25 / WEIGHT_SUM)
    sim = _copy(ref)
    sim.body_angvel[:, humanoid.body_index("left_foot")] += [0.0, 0.0, 2.0]
    np.testing.assert_allclose(TERM_FUNCTIONS["velocity"](sim, ref, model), 0.2 * 2.0**2 / WEIGHT_SUM)
    sim = _copy(ref)
    sim.body_linvel += [0.5, 0.0, -0.3]
    np.testing.assert_allclose(TERM_FUNCTIONS["com"](sim, ref, model), 0.25 + 0.09)


@pytest.mark.parametrize("preset", ["deepmimic", "parc"])
def test_reward_combines_terms_by_hand(humanoid: Humanoid, ref: CharacterState, preset: str) -> None:
    sim, model = _moved(humanoid, ref), RewardModel.from_humanoid(humanoid)
    for form in ("sum", "product"):
        cfg = RewardConfig(preset=preset, form=form)
        reward, terms = TrackingReward(humanoid, cfg)(sim, ref)
        assert set(terms) == set(cfg.weights)
        err = {k: TERM_FUNCTIONS[k](sim, ref, model) for k in cfg.weights}
        for k in cfg.weights:
            np.testing.assert_allclose(terms[k], np.exp(-DEFAULT_SCALES[k] * err[k]))
        if form == "sum":
            expected = sum(w * terms[k] for k, w in cfg.weights.items())
        else:
            expected = np.prod([terms[k] ** w for k, w in cfg.weights.items()], axis=0)
        np.testing.assert_allclose(reward, expected)
        assert np.all(reward < 1.0)
        # at sim = ref every term and the reward are 1
        perfect, perfect_terms = TrackingReward(humanoid, cfg)(ref, ref)
        np.testing.assert_allclose(perfect, 1.0)
        for v in perfect_terms.values():
            np.testing.assert_allclose(v, 1.0)


def test_shared_derivations_give_the_terms_to_the_bit(humanoid: Humanoid) -> None:
    """The reward derives each state's joint-local rotations, centre-of-mass velocity and effectors once and shares
    them between terms, the reference's ahead of the physics (prepare): the same numbers as each term on its own."""
    lib = load_motions(["walk", "run"], humanoid)
    rng = np.random.default_rng(0)
    ref = lib.query(rng.integers(0, 2, 40), rng.uniform(0.0, 3.0, 40))
    sim = lib.query(rng.integers(0, 2, 40), rng.uniform(0.0, 3.0, 40))
    model = RewardModel.from_humanoid(humanoid)
    alone = {k: f(sim, ref, model) for k, f in TERM_FUNCTIONS.items()}
    for prepared in (Derived(ref, model), prepare(REWARD_TERMS, ref, model)):
        shared = term_errors(REWARD_TERMS, Derived(sim, model), prepared)
        for k in REWARD_TERMS:
            np.testing.assert_array_equal(shared[k], alone[k], err_msg=k)
    for preset in ("deepmimic", "parc"):
        fn = TrackingReward(humanoid, RewardConfig(preset=preset))
        reward, terms = fn(sim, ref)
        reward_prepared, terms_prepared = fn(sim, fn.prepare(ref))
        np.testing.assert_array_equal(reward_prepared, reward)
        for k in terms:
            np.testing.assert_array_equal(terms_prepared[k], terms[k])


def test_presets_and_overrides() -> None:
    parc = RewardConfig(preset="parc")
    assert parc.form == "product"
    assert parc.weights == {"root_pos": 0.3, "root_rot": 0.2, "body_pos": 0.3, "body_rot": 0.1, "dof_vel": 0.05,
                            "end_effector": 0.05}  # fmt: skip
    assert parc.scales == {"root_pos": 10.0, "root_rot": 5.0, "body_pos": 20.0, "body_rot": 2.0, "dof_vel": 0.1,
                           "end_effector": 40.0}  # fmt: skip
    dm = RewardConfig()
    assert dm.form == "sum" and dm.weights == {"pose": 0.5, "velocity": 0.05, "end_effector": 0.15, "root": 0.2,
                                               "com": 0.1}  # fmt: skip
    mixed = RewardConfig(preset="parc", form="sum", weights={"root_pos": 0.5, "pose": 0.5}, scales={"pose": 3.0})
    assert mixed.scales == {"root_pos": 10.0, "pose": 3.0}
    assert RewardConfig(**{"preset": mixed.preset, "form": mixed.form, "weights": mixed.weights,
                           "scales": mixed.scales}) == mixed  # fmt: skip
    assert set(REWARD_TERMS) == set(DEFAULT_SCALES)


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"weights": {"root_poss": 1.0}}, "weights: unknown reward terms \\['root_poss'\\]"),
        ({"scales": {"body_pos": 2.0}}, "scales: terms \\['body_pos'\\] have no weight"),
        ({"weights": {"pose": -1.0}}, "weights must be non-negative"),
        ({"preset": "phc"}, "key 'preset' expects"),
    ],
)
def test_bad_reward_config_fails_clearly(data: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        from_dict(RewardConfig, data, source="cfg.yaml")
