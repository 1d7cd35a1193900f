"""The closed-loop gain search: where its parameters go, what its rollouts score, how the plan applies the result."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import EvalConfig, episode_starts, evaluate
from common.motion.dataset import load_motions
from samcon.config import OptimiseConfig
from samcon.cost import FEATURE_NAMES
from samcon.feedback import ClipPlan, FeedbackPolicy
from samcon.optimise import GainLayout, optimise_gains, reduced_indices, rollout_cost

D = len(FEATURE_NAMES)


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


def _playback_plan(segments: int = 4, frames: int = 24, nu: int = 28) -> ClipPlan:
    """A plan that adds nothing: the policy plays the reference's angles (zero gains and offsets)."""
    bounds = np.linspace(0, frames, segments + 1).astype(np.int64)
    return ClipPlan(np.zeros((frames, nu)), bounds, np.zeros((segments, nu, D)), np.zeros((segments, nu)))


def test_layout_puts_each_parameter_at_its_actuator_and_scaled_feature() -> None:
    scale = np.arange(1.0, D + 1.0)
    layout = GainLayout(groups=2, nu=5, features=np.array([3, 1]), actuators=np.array([4, 0, 2]), scale=scale)
    assert layout.size == 2 * 3 * 2
    theta = np.arange(1.0, 13.0)
    g = layout.gains(theta)
    assert g.shape == (2, 5, D)
    # Group-major, then actuator-major: group 1, actuator 0 (the second listed), feature 1 (the second listed) is
    # parameter 6 + 2 + 1 = 9 (value 10), divided by feature 1's scale, 2.
    assert g[1, 0, 1] == 10.0 / 2.0
    assert g[0, 4, 3] == 1.0 / 4.0 and g[0, 4, 1] == 2.0 / 2.0 and g[0, 2, 1] == 6.0 / 2.0
    assert np.count_nonzero(g) == 12 and np.count_nonzero(g[:, [1, 3]]) == 0
    # Batched parameter vectors give batched gains.
    np.testing.assert_array_equal(layout.gains(np.stack([theta, 2 * theta]))[1], 2 * g)


def test_reduced_indices_name_the_key_and_the_unknown_name(humanoid: Humanoid) -> None:
    f, a, _ = reduced_indices(humanoid, OptimiseConfig(features=["root_tilt_y"], actuators=["left_knee", "chest_x"]))
    assert f.tolist() == [FEATURE_NAMES.index("root_tilt_y")] and a.tolist() == [24, 0]
    with pytest.raises(ValueError, match="optimise.features: no feature 'tilt'"):
        reduced_indices(humanoid, OptimiseConfig(features=["tilt"]))
    with pytest.raises(ValueError, match="optimise.actuators: no actuator 'knee'"):
        reduced_indices(humanoid, OptimiseConfig(actuators=["knee"]))
    with pytest.raises(ValueError, match="missing: left_foot_y, right_ankle_x"):
        reduced_indices(humanoid, OptimiseConfig(groups=2, mirror=True, features=["right_foot_y"],
                                                 actuators=["left_ankle_x"]))  # fmt: skip
    with pytest.raises(ValueError, match="must not repeat"):
        reduced_indices(humanoid, OptimiseConfig(actuators=["left_knee", "left_knee"]))


def test_plan_adds_the_reference_gain_of_the_segments_group() -> None:
    rng = np.random.default_rng(0)
    plan = _playback_plan(segments=6, nu=3)
    plan = replace(plan, gain=rng.normal(size=(6, 3, D)), bias=rng.normal(size=(6, 3)))
    ref_gain = rng.normal(size=(2, 3, D))
    s = rng.normal(size=D)
    with_ref = replace(plan, ref_gain=ref_gain)
    # Six segments in two groups: 0-2 take R_0, 3-5 take R_1.
    assert [with_ref.group(k, 2) for k in range(6)] == [0, 0, 0, 1, 1, 1]
    for k in range(6):
        expected = plan.gain[k] @ s + plan.bias[k] + ref_gain[k // 3] @ s
        np.testing.assert_allclose(with_ref.offset(k, s), expected, rtol=1e-12)
        np.testing.assert_allclose(plan.offset(k, s), plan.gain[k] @ s + plan.bias[k], rtol=1e-12)


def test_rollouts_fail_as_the_shared_evaluator_does(humanoid: Humanoid) -> None:
    """Zero gains from the evaluator's own starts play exactly the share of the horizon the evaluator measures for the
    same policy, and identical candidates in one batch score identically."""
    library = load_motions(["walk"], humanoid)
    ev = EvalConfig(starts_per_clip=3, max_frames=90, threads=1)
    plan = _playback_plan()
    result = evaluate(FeedbackPolicy({"walk": plan}, library, humanoid), library, humanoid, ev)
    _, times, _ = episode_starts(library, ev)
    gains = np.zeros((2, 1, humanoid.nu, D))
    cost, played = rollout_cost(plan, "walk", library, humanoid, gains, 0.5, times, 90, ev, error_scale=0.5)
    assert played[0] == pytest.approx(result.per_clip["episode_len_ratio"][0], abs=1e-12)
    assert played[0] < 1.0  # reference playback falls within 90 frames of walk: the rule was exercised
    assert cost[0] == cost[1] and played[0] == played[1] and 0.0 < cost[0] <= 1.0
    # A cost near 1 for the frames after a fall: at least the unplayed share.
    assert cost[0] >= 1.0 - played[0] - 1e-12


def test_optimise_gains_returns_the_search_mean_on_the_chosen_entries(humanoid: Humanoid) -> None:
    library = load_motions(["walk"], humanoid)
    cfg = OptimiseConfig(generations=2, population=3, starts=2, frames=6, groups=2, features=["root_vel_x"],
                         actuators=["right_hip_y", "left_hip_y"])  # fmt: skip
    plan = _playback_plan()
    new, history = optimise_gains(plan, "walk", library, humanoid, cfg, EvalConfig(threads=1),
                                  np.random.default_rng(0))  # fmt: skip
    assert new.ref_gain.shape == (2, humanoid.nu, D) and history["parameters"] == 4
    assert history["generation"] == [1, 2] and len(history["cost_at_mean"]) == 2
    nonzero = np.argwhere(new.ref_gain != 0)
    assert set(map(tuple, nonzero[:, 1:].tolist())) <= {(15, 4), (22, 4)} and len(nonzero) > 0
    np.testing.assert_array_equal(new.gain, plan.gain)


def _mirrored(humanoid: Humanoid, qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The character reflected through its x-z plane (y -> -y), built by hand: root position and linear velocity
    negate y; the root quaternion (w, x, y, z) becomes (w, -x, y, -z) and the (local) angular velocity (-wx, wy,
    -wz); every hinge takes its left-right partner's angle, negated for x and z axes (from the joint's name)."""
    q, v = qpos.copy(), qvel.copy()
    q[:, 1] *= -1.0
    q[:, 4] *= -1.0
    q[:, 6] *= -1.0
    v[:, 1] *= -1.0
    v[:, [3, 5]] *= -1.0
    names = [humanoid.model.actuator(a).name for a in range(humanoid.nu)]
    for a, name in enumerate(names):
        partner = name.replace("right_", "@").replace("left_", "right_").replace("@", "left_")
        p = names.index(partner)
        sign = -1.0 if name[-2:] in ("_x", "_z") else 1.0
        q[:, humanoid.hinge_qpos[a]] = sign * qpos[:, humanoid.hinge_qpos[p]]
        v[:, humanoid.hinge_dof[a]] = sign * qvel[:, humanoid.hinge_dof[p]]
    return q, v


def test_mirror_maps_match_a_reflected_character(humanoid: Humanoid) -> None:
    """Two walk frames (simulated and reference, a real deviation) and their hand-built reflections: MuJoCo's
    kinematics put every reflected body at the reflected position of its partner (so the hinge signs are right), and
    the features of the reflected pair are the mirror map of the original's."""
    from common.motion.library import body_states
    from samcon.cost import feedback_features
    from samcon.optimise import mirror_maps

    library = load_motions(["walk"], humanoid)
    state = library.query(np.zeros(2, dtype=np.int64), np.array([0.3, 0.55]))
    qpos, qvel = _mirrored(humanoid, state.qpos, state.qvel)
    reflected = body_states(humanoid, qpos, qvel)
    fpart, fsign, apart, asign = mirror_maps(humanoid)
    bodies = list(humanoid.body_names)
    partner = [bodies.index(b.replace("right_", "@").replace("left_", "right_").replace("@", "left_")) for b in bodies]
    np.testing.assert_allclose(reflected.body_pos, state.body_pos[:, partner] * [1.0, -1.0, 1.0], atol=1e-9)
    sim, ref = state[0:1], state[1:2]
    msim, mref = reflected[0:1], reflected[1:2]
    s, ms = feedback_features(humanoid, sim, ref)[0], feedback_features(humanoid, msim, mref)[0]
    assert np.abs(s).max() > 0.05  # the two frames differ: the check has something to compare
    np.testing.assert_allclose(ms, fsign * s[fpart], atol=1e-9)
    # The actuators' map is the hand-built one above.
    names = [humanoid.model.actuator(a).name for a in range(humanoid.nu)]
    assert names[apart[names.index("right_hip_x")]] == "left_hip_x" and asign[names.index("right_hip_x")] == -1.0
    assert asign[names.index("left_knee")] == 1.0 and asign[names.index("chest_z")] == -1.0


def test_mirrored_groups_are_the_mirror_image_of_the_free_ones(humanoid: Humanoid) -> None:
    from samcon.optimise import mirror_maps

    mirror = mirror_maps(humanoid)
    features, actuators, _ = reduced_indices(humanoid, OptimiseConfig(
        features=["root_tilt_x", "right_foot_y", "left_foot_y"], actuators=["right_hip_x", "left_hip_x"]))  # fmt: skip
    layout = GainLayout(2, humanoid.nu, features, actuators, np.ones(D), mirror)
    assert layout.size == 6
    g = layout.gains(np.arange(1.0, 7.0))
    rh, lh = actuators
    tilt, rfy, lfy = features
    # Free group 0: right_hip_x <- (tilt 1, rfy 2, lfy 3), left_hip_x <- (4, 5, 6). Group 1 mirrors it: left_hip_x
    # takes right_hip_x's row with both signs of x-rotations and y-offsets (-1 each), feet swapped.
    np.testing.assert_array_equal(g[0, rh, [tilt, rfy, lfy]], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(g[1, lh, [tilt, rfy, lfy]], [(-1) * (-1) * 1.0, (-1) * (-1) * 3.0, 2.0])
    np.testing.assert_array_equal(g[1, rh, [tilt, rfy, lfy]], [4.0, 6.0, 5.0])
    with pytest.raises(ValueError, match="partner"):
        GainLayout(2, humanoid.nu, features[:2], actuators, np.ones(D), mirror)
    with pytest.raises(ValueError, match="even number of groups"):
        GainLayout(3, humanoid.nu, features, actuators, np.ones(D), mirror)


def test_layout_puts_the_offsets_after_the_gains_segment_major() -> None:
    layout = GainLayout(groups=1, nu=5, features=np.array([2]), actuators=np.array([1]), scale=np.ones(D),
                        offset_actuators=np.array([4, 0]), segments=3)  # fmt: skip
    assert layout.gain_size == 1 and layout.size == 1 + 3 * 2
    theta = np.arange(1.0, 8.0)
    off = layout.offsets(theta)
    # Parameter 1 is the gain; then segment 0: actuator 4 <- 2, actuator 0 <- 3; segment 1: 4, 5; segment 2: 6, 7.
    np.testing.assert_array_equal(off, [[3, 0, 0, 0, 2], [5, 0, 0, 0, 4], [7, 0, 0, 0, 6]])
    assert layout.gains(theta)[0, 1, 2] == 1.0 and np.count_nonzero(layout.gains(theta)) == 1
    np.testing.assert_array_equal(layout.offsets(np.stack([theta, -theta]))[1], -off)
    # Without offset actuators there are none.
    assert GainLayout(1, 5, np.array([2]), np.array([1]), np.ones(D)).offsets(np.ones(1)).shape == (0, 5)


def test_plan_adds_its_optimised_offset_of_the_segment() -> None:
    rng = np.random.default_rng(1)
    plan = replace(_playback_plan(segments=3, nu=4), gain=rng.normal(size=(3, 4, D)), bias=rng.normal(size=(3, 4)))
    ref_offset = rng.normal(size=(3, 4))
    s = rng.normal(size=D)
    with_off = replace(plan, ref_offset=ref_offset)
    for k in range(3):
        np.testing.assert_allclose(with_off.offset(k, s), plan.offset(k, s) + ref_offset[k], rtol=1e-12)


def test_rollout_offsets_change_the_play_and_zero_offsets_do_not(humanoid: Humanoid) -> None:
    library = load_motions(["walk"], humanoid)
    plan = _playback_plan()
    gains = np.zeros((3, 1, humanoid.nu, D))
    offsets = np.zeros((3, 4, humanoid.nu))
    offsets[2, :, 17] = 0.6  # candidate 2 bends its right knee 0.6 rad further in every segment
    times = np.array([0.0, 0.2])
    ev = EvalConfig(threads=1)
    cost, played = rollout_cost(plan, "walk", library, humanoid, gains, 0.5, times, 24, ev, 0.5, offsets=offsets)
    plain, _ = rollout_cost(plan, "walk", library, humanoid, gains[:1], 0.5, times, 24, ev, 0.5)
    assert cost[0] == cost[1] == plain[0]
    assert cost[2] > cost[0] + 1e-3


def test_optimise_searches_the_offsets_of_the_listed_actuators(humanoid: Humanoid) -> None:
    library = load_motions(["walk"], humanoid)
    cfg = OptimiseConfig(generations=2, population=3, starts=2, frames=6, features=["root_vel_x"],
                         actuators=["right_hip_y"], offsets=["left_knee", "chest_x"])  # fmt: skip
    plan = _playback_plan()
    new, history = optimise_gains(plan, "walk", library, humanoid, cfg, EvalConfig(threads=1),
                                  np.random.default_rng(0))  # fmt: skip
    assert history["parameters"] == 1 + 4 * 2 and new.ref_offset.shape == (4, humanoid.nu)
    assert np.count_nonzero(new.ref_offset[:, [24, 0]]) == 8 and np.count_nonzero(new.ref_offset) == 8
    with pytest.raises(ValueError, match="optimise.offsets: no actuator 'knee'"):
        reduced_indices(humanoid, OptimiseConfig(offsets=["knee"]))
    with pytest.raises(ValueError, match="offset_sigma"):
        OptimiseConfig(offset_sigma=0.0)
