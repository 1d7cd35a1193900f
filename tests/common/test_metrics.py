"""Tests for common.evaluation.metrics against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.evaluation.metrics import (
    FOOT_CONTACT_HEIGHT_M,
    METRIC_NAMES,
    METRICS,
    acceleration_error_mm,
    best_index,
    body_rot_error_rad,
    contact_mean,
    episode_length_ratio,
    foot_slide_mm,
    joint_vel_error,
    mean_body_pos_error_m,
    mpjpe_global_mm,
    mpjpe_local_mm,
    root_ang_vel_error,
    root_lin_vel_error,
    root_pos_error_m,
    root_rot_error_rad,
    success,
    summarise,
    target_jitter,
    velocity_error_mm,
)

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
# 90 deg about z: (cos 45, 0, 0, sin 45).
ROT_Z90 = np.array([math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)])
# 180 deg about x: (cos 90, sin 90, 0, 0).
ROT_X180 = np.array([0.0, 1.0, 0.0, 0.0])


# ---------------------------------------------------------------- positions


def test_mpjpe_global_two_bodies() -> None:
    sim = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    ref = np.array([[0.0, 0.0, 0.1], [1.0, 0.0, 0.3]])
    # Distances 0.1 m and 0.3 m -> mean 0.2 m.
    assert mpjpe_global_mm(sim, ref) == pytest.approx(200.0)
    assert mean_body_pos_error_m(sim, ref) == pytest.approx(0.2)
    # Relative to body 0: sim (0,0,0),(1,0,0); ref (0,0,0),(1,0,0.2) -> mean 0.1 m.
    assert mpjpe_local_mm(sim, ref) == pytest.approx(100.0)


def test_constant_shift_is_global_error_only() -> None:
    sim = np.array([[0.0, 0.0, 1.0], [0.3, -0.2, 1.4], [-0.5, 0.1, 0.2]])
    ref = sim + np.array([1.0, 2.0, 2.0])
    # |(1, 2, 2)| = 3 m for every body.
    assert mpjpe_global_mm(sim, ref) == pytest.approx(3000.0)
    assert mean_body_pos_error_m(sim, ref) == pytest.approx(3.0)
    assert mpjpe_local_mm(sim, ref) == pytest.approx(0.0, abs=1e-9)


def test_mpjpe_local_root_index() -> None:
    sim = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    ref = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.3], [2.0, 0.0, 0.0]])
    # Root 0: errors 0, 0.3, 0 -> 0.1 m.
    assert mpjpe_local_mm(sim, ref, root_index=0) == pytest.approx(100.0)
    # Root 1: ref shifted by -0.3 z relative to sim at bodies 0 and 2 -> errors 0.3, 0, 0.3 -> 0.2 m.
    assert mpjpe_local_mm(sim, ref, root_index=1) == pytest.approx(200.0)
    # Negative index counts from the end like numpy: body 2 behaves as body 0 here.
    assert mpjpe_local_mm(sim, ref, root_index=-1) == pytest.approx(100.0)
    with pytest.raises(IndexError):
        mpjpe_local_mm(sim, ref, root_index=3)


def test_root_pos_error() -> None:
    assert root_pos_error_m([1.0, 1.0, 1.0], [1.0, 4.0, 5.0]) == pytest.approx(5.0)


def test_position_shape_checks() -> None:
    with pytest.raises(ValueError):
        mpjpe_global_mm(np.zeros((2, 4)), np.zeros((2, 4)))
    with pytest.raises(ValueError):
        mpjpe_global_mm(np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError):
        mpjpe_global_mm(np.zeros((5, 2, 3)), np.zeros((4, 2, 3)))


# ---------------------------------------------------------------- rotations


def test_root_rot_error_quarter_turn_and_sign() -> None:
    assert root_rot_error_rad(ROT_Z90, IDENTITY) == pytest.approx(math.pi / 2)
    assert root_rot_error_rad(ROT_X180, IDENTITY) == pytest.approx(math.pi)
    # q and -q are the same rotation.
    assert root_rot_error_rad(ROT_Z90, -ROT_Z90) == pytest.approx(0.0, abs=1e-6)


def test_body_rot_error_mean_over_bodies() -> None:
    sim = np.stack([ROT_Z90, IDENTITY, ROT_X180])
    ref = np.stack([IDENTITY, -IDENTITY, IDENTITY])
    # Angles pi/2, 0, pi -> mean pi/2.
    assert body_rot_error_rad(sim, ref) == pytest.approx(math.pi / 2)


# ---------------------------------------------------------------- velocities


def test_joint_vel_error() -> None:
    sim = np.array([1.0, -2.0, 3.0, 0.0])
    ref = np.array([0.0, 0.0, 0.0, 4.0])
    # (1 + 2 + 3 + 4) / 4.
    assert joint_vel_error(sim, ref) == pytest.approx(2.5)


def test_root_velocity_errors_345() -> None:
    assert root_lin_vel_error([3.0, 4.0, 0.0], [0.0, 0.0, 0.0]) == pytest.approx(5.0)
    assert root_lin_vel_error([1.0, 1.0, 1.0], [1.0, 4.0, 5.0]) == pytest.approx(5.0)
    assert root_ang_vel_error([0.0, 3.0, 0.0], [0.0, 0.0, -4.0]) == pytest.approx(5.0)


# ---------------------------------------------------------------- motion quality


def test_constant_acceleration_body_has_its_second_difference_as_error() -> None:
    t = np.arange(5.0)
    # Body 0 accelerates along x: p = 0.001 t^2 m, second difference 0.002 m = 2 mm/frame^2 every frame; body 1 is
    # still. The reference moves both bodies at a constant 1 cm/frame along y: no acceleration.
    sim = np.zeros((5, 2, 3))
    sim[:, 0, 0] = 0.001 * t**2
    ref = np.zeros((5, 2, 3))
    ref[:, :, 1] = 0.01 * t[:, None]
    # Mean over the two bodies: (2 + 0) / 2 = 1 mm/frame^2, at the three frame triples of five frames.
    np.testing.assert_allclose(acceleration_error_mm(sim, ref), [1.0, 1.0, 1.0])
    # Velocity: body 0 moves 1, 3, 5, 7 mm along x against 10 mm along y; body 1 is 10 mm off.
    # Body 0: sqrt(1 + 100), sqrt(9 + 100), ...; mean with body 1's 10.
    expected = [(math.sqrt(d**2 + 100.0) + 10.0) / 2 for d in (1.0, 3.0, 5.0, 7.0)]
    np.testing.assert_allclose(velocity_error_mm(sim, ref), expected)


def test_constant_velocity_body_against_a_still_reference() -> None:
    t = np.arange(4.0)
    # One body moving (3, 4, 0) cm per frame: 50 mm/frame off a still reference, no acceleration error.
    sim = np.zeros((4, 1, 3))
    sim[:, 0, 0], sim[:, 0, 1] = 0.03 * t, 0.04 * t
    np.testing.assert_allclose(velocity_error_mm(sim, np.zeros((4, 1, 3))), [50.0, 50.0, 50.0])
    np.testing.assert_allclose(acceleration_error_mm(sim, np.zeros((4, 1, 3))), [0.0, 0.0], atol=1e-9)
    # Leading dims are episodes: (N, T, B, 3) -> (N, T - 1).
    batch = np.stack([sim, np.zeros_like(sim)])
    np.testing.assert_allclose(velocity_error_mm(batch, np.zeros_like(batch)), [[50.0] * 3, [0.0] * 3])


def test_motion_quality_needs_enough_frames() -> None:
    with pytest.raises(ValueError):
        acceleration_error_mm(np.zeros((2, 3, 3)), np.zeros((2, 3, 3)))
    with pytest.raises(ValueError):
        velocity_error_mm(np.zeros((1, 3, 3)), np.zeros((1, 3, 3)))
    with pytest.raises(ValueError):
        target_jitter(np.zeros((2, 28)))
    with pytest.raises(ValueError):
        foot_slide_mm(np.zeros((4, 2, 3)), np.zeros((4, 3)))


def test_a_sliding_foot_counts_only_while_it_touches_the_floor() -> None:
    # One foot moving 3 mm/frame along x (and 4 mm/frame along y on one step, and up and down, which do not count):
    # on the floor for frames 0-2, lifted to 5 cm for frames 3-4, exactly at the threshold at frame 5 (not touching:
    # the rule is strictly below), back on the floor (1 cm, under 2) at frames 6-7.
    height = np.array([0.0, -0.01, 0.0, 0.05, 0.05, FOOT_CONTACT_HEIGHT_M, 0.01, 0.01])
    pos = np.zeros((8, 1, 3))
    pos[:, 0, 0] = 0.003 * np.arange(8)
    pos[7, 0, 1] = 0.004
    pos[:, 0, 2] = height + 0.05
    slide, contact = foot_slide_mm(pos, height[:, None])
    np.testing.assert_allclose(slide[:, 0], [3.0] * 6 + [5.0])  # the last step: |(3, 4)| = 5 mm
    np.testing.assert_array_equal(contact[:, 0], [True, True, False, False, False, False, True])
    # Mean over the steps in contact: (3 + 3 + 5) / 3 mm/frame.
    summed = np.where(contact, slide, 0.0).sum(axis=-1)
    assert contact_mean(summed, contact.sum(axis=-1), np.ones(7, dtype=bool)) == pytest.approx(11.0 / 3)
    # Leaving the last step out (e.g. past the episode's end): 3 mm/frame.
    valid = np.arange(7) < 6
    assert contact_mean(summed, contact.sum(axis=-1), valid) == pytest.approx(3.0)
    # A lower threshold keeps only frames 0-2 on the floor.
    _, low = foot_slide_mm(pos, height[:, None], threshold_m=0.005)
    np.testing.assert_array_equal(low[:, 0], [True, True, False, False, False, False, False])


def test_contact_mean_over_feet_and_without_contact() -> None:
    # Two steps: 2 feet in contact summing 10 mm, then 1 foot with 5 mm: 15 mm over 3 foot-steps.
    assert contact_mean([10.0, 5.0], [2, 1], [True, True]) == pytest.approx(5.0)
    assert math.isnan(contact_mean([0.0, 0.0], [0, 0], [True, True]))
    assert math.isnan(contact_mean([10.0], [2], [False]))
    with pytest.raises(ValueError):
        contact_mean([1.0, 2.0], [1, 1], [True])


def test_target_jitter_by_hand() -> None:
    # Actuator 0 alternates +-0.1 rad: second differences -0.4, +0.4, -0.4 -> |.| = 0.4; actuator 1 follows
    # 0.5 x 0.02 t^2 rad: second difference 0.02. Mean over the two actuators: 0.21 rad/frame^2.
    t = np.arange(5.0)
    targets = np.stack([0.1 * (-1.0) ** t, 0.01 * t**2], axis=-1)
    np.testing.assert_allclose(target_jitter(targets), [0.21, 0.21, 0.21])
    # A target moving at constant speed does not jitter.
    np.testing.assert_allclose(target_jitter(0.3 * t[:, None]), [0.0, 0.0, 0.0], atol=1e-12)


# ---------------------------------------------------------------- success and length


def test_success_one_frame_exceeds() -> None:
    assert not success(np.array([0.1, 0.6, 0.2]))


def test_success_equal_to_threshold_passes() -> None:
    assert success(np.array([0.5, 0.5, 0.0]))
    assert not success(np.array([0.3, 0.3]), threshold_m=0.2)


def test_success_ignores_invalid_frames() -> None:
    err = np.array([0.1, 0.2, 0.9])
    assert not success(err)
    assert success(err, valid=np.array([True, True, False]))


def test_success_nan_in_valid_frame_fails() -> None:
    err = np.array([0.1, np.nan])
    assert not success(err)
    assert success(err, valid=np.array([True, False]))


def test_success_terminated_forces_failure() -> None:
    err = np.array([[0.1, 0.1], [0.1, 0.1], [0.1, 0.7]])
    out = success(err, terminated=np.array([False, True, False]))
    assert out.dtype == np.bool_
    np.testing.assert_array_equal(out, [True, False, False])
    assert not success(np.array([0.0, 0.0]), terminated=True)


def test_success_batched_with_mask() -> None:
    err = np.array([[0.1, 0.6, 0.0], [0.1, 0.2, 0.6], [0.5, 0.4, 0.3]])
    valid = np.array([[True, True, True], [True, True, False], [True, True, True]])
    np.testing.assert_array_equal(success(err, valid), [False, True, True])
    with pytest.raises(ValueError):
        success(err, valid[:, :2])


def test_episode_length_ratio() -> None:
    out = episode_length_ratio(np.array([256, 512, 600, -1, 0]))
    np.testing.assert_allclose(out, [0.5, 1.0, 1.0, 0.0, 0.0])
    assert episode_length_ratio(50, max_frames=100) == pytest.approx(0.5)
    with pytest.raises(ValueError):
        episode_length_ratio(10, max_frames=0)


# ---------------------------------------------------------------- summarise


def test_summarise_ignores_invalid_frames() -> None:
    valid = np.array([[True, True, True], [True, False, False]])
    per_frame = {
        "mpjpe_g": np.array([[1.0, 2.0, 3.0], [4.0, 100.0, np.nan]]),
        "root_pos_err": np.array([[0.0, 0.0, 0.0], [0.8, np.inf, -5.0]]),
    }
    out = summarise(per_frame, valid)
    # (1 + 2 + 3 + 4) / 4 and (0 + 0 + 0 + 0.8) / 4.
    assert out == {"mpjpe_g": pytest.approx(2.5), "root_pos_err": pytest.approx(0.2)}
    assert all(type(v) is float for v in out.values())


def test_summarise_no_valid_frame_and_shape_mismatch() -> None:
    out = summarise({"mpjpe_l": np.ones(3)}, np.zeros(3, dtype=bool))
    assert math.isnan(out["mpjpe_l"])
    with pytest.raises(ValueError):
        summarise({"mpjpe_l": np.ones(4)}, np.ones(3, dtype=bool))


# ---------------------------------------------------------------- broadcasting


def _random_quats(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    q = rng.normal(size=(*shape, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def test_leading_dims_match_loop() -> None:
    rng = np.random.default_rng(0)
    n_t, n_n, n_b, n_d = 4, 3, 5, 7
    sim_pos = rng.normal(size=(n_t, n_n, n_b, 3))
    ref_pos = rng.normal(size=(n_t, n_n, n_b, 3))
    sim_rot = _random_quats(rng, (n_t, n_n, n_b))
    ref_rot = _random_quats(rng, (n_t, n_n, n_b))
    sim_dof = rng.normal(size=(n_t, n_n, n_d))
    ref_dof = rng.normal(size=(n_t, n_n, n_d))

    batched = {
        "g": mpjpe_global_mm(sim_pos, ref_pos),
        "l": mpjpe_local_mm(sim_pos, ref_pos, root_index=2),
        "m": mean_body_pos_error_m(sim_pos, ref_pos),
        "rp": root_pos_error_m(sim_pos[..., 0, :], ref_pos[..., 0, :]),
        "rr": root_rot_error_rad(sim_rot[..., 0, :], ref_rot[..., 0, :]),
        "br": body_rot_error_rad(sim_rot, ref_rot),
        "jv": joint_vel_error(sim_dof, ref_dof),
        "lv": root_lin_vel_error(sim_pos[..., 1, :], ref_pos[..., 1, :]),
        "av": root_ang_vel_error(sim_pos[..., 2, :], ref_pos[..., 2, :]),
    }
    for value in batched.values():
        assert value.shape == (n_t, n_n)
    for t in range(n_t):
        for n in range(n_n):
            sp, rp = sim_pos[t, n], ref_pos[t, n]
            sr, rr = sim_rot[t, n], ref_rot[t, n]
            looped = {
                "g": mpjpe_global_mm(sp, rp),
                "l": mpjpe_local_mm(sp, rp, root_index=2),
                "m": mean_body_pos_error_m(sp, rp),
                "rp": root_pos_error_m(sp[0], rp[0]),
                "rr": root_rot_error_rad(sr[0], rr[0]),
                "br": body_rot_error_rad(sr, rr),
                "jv": joint_vel_error(sim_dof[t, n], ref_dof[t, n]),
                "lv": root_lin_vel_error(sp[1], rp[1]),
                "av": root_ang_vel_error(sp[2], rp[2]),
            }
            for key, value in looped.items():
                assert batched[key][t, n] == pytest.approx(float(value), rel=1e-12, abs=1e-12), key

    # success reduces the trailing (T) dim only: (N, T) -> (N,).
    err_nt = np.moveaxis(batched["m"], 0, -1) / 4.0
    expected = [bool(np.all(err_nt[n] <= 0.5)) for n in range(n_n)]
    np.testing.assert_array_equal(success(err_nt), expected)


def test_reference_broadcasts_against_batch() -> None:
    sim = np.zeros((2, 2, 3))
    sim[1] += np.array([0.0, 3.0, 4.0])
    ref = np.zeros((2, 3))
    np.testing.assert_allclose(mpjpe_global_mm(sim, ref), [0.0, 5000.0])


# ---------------------------------------------------------------- registry


def test_metric_registry() -> None:
    assert METRIC_NAMES == (
        "mpjpe_g",
        "mpjpe_l",
        "root_pos_err",
        "root_rot_err",
        "body_rot_err",
        "joint_vel_err",
        "root_vel_err",
        "root_ang_vel_err",
        "accel_err",
        "vel_err",
        "foot_slide",
        "foot_slide_ref",
        "target_jitter",
        "mpjpe_g_succ",
        "mpjpe_l_succ",
        "success",
        "episode_len_ratio",
        "survival",
    )
    assert METRICS["mpjpe_g"].unit == "mm"
    assert METRICS["root_pos_err"].unit == "m"
    assert METRICS["joint_vel_err"].unit == "rad/s"
    assert (METRICS["accel_err"].unit, METRICS["vel_err"].unit) == ("mm/frame^2", "mm/frame")
    assert (METRICS["foot_slide"].unit, METRICS["target_jitter"].unit) == ("mm/frame", "rad/frame^2")
    assert METRICS["foot_slide_ref"].direction == "not ranked"
    assert [k for k, m in METRICS.items() if not m.ranked] == ["foot_slide_ref"]
    higher = {k for k, m in METRICS.items() if m.higher_is_better}
    assert higher == {"success", "episode_len_ratio", "survival"}
    assert METRICS["mpjpe_l"].direction == "lower is better"
    assert METRICS["success"].direction == "higher is better"


def test_best_index() -> None:
    assert best_index("mpjpe_g", [30.0, 12.0, 50.0]) == 1
    assert best_index("success", [0.7, 0.95, 0.9]) == 1
    assert best_index("mpjpe_g", [np.nan, 40.0, 20.0]) == 2
    with pytest.raises(ValueError):
        best_index("success", [np.nan])
    with pytest.raises(KeyError):
        best_index("not_a_metric", [1.0])
    # The reference's own sliding is the same for every tracker: it ranks none.
    with pytest.raises(ValueError):
        best_index("foot_slide_ref", [1.0, 2.0])
