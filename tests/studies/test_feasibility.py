"""Feasibility of a reference: the external force it implies, the torques it needs, the command's output."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import mujoco
import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from studies.samcon.feasibility import (
    CONTACT_TOLERANCE,
    FrameFeasibility,
    accel_step,
    angular_momentum,
    body_weight,
    clip_reference,
    com_and_clearance,
    contact_wrench_residual,
    hinge_ratios,
    main,
    measure,
    model_friction,
    nnls,
    pyramid,
    range_excess,
    residual_force,
    residual_vector,
    summarise,
    torque_limits,
    total_mass,
    triangle_rate,
)

STEP = 2


@pytest.fixture(scope="module")
def clips() -> tuple[Humanoid, object]:
    humanoid = Humanoid()
    return humanoid, load_motions(["walk", "dance_a", "spinkick"], humanoid)


def _still(pose: np.ndarray, frames: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """One pose repeated, at rest. Shapes: (frames, nq), (frames, nv)."""
    return np.repeat(pose[None], frames, axis=0), np.zeros((frames, nv))


def test_model_constants(clips) -> None:
    humanoid, _ = clips
    # Masses of the 15 bodies in humanoid3d.xml; floor and body geoms both have sliding friction 1.
    assert total_mass(humanoid) == pytest.approx(6 + 14 + 2 + 2 * (1.5 + 1 + 0.5) + 2 * (4.5 + 3 + 1))
    assert body_weight(humanoid) == pytest.approx(45.0 * 9.81)
    assert model_friction(humanoid) == 1.0
    lower, upper = torque_limits(humanoid)
    knee = mujoco.mj_name2id(humanoid.model, mujoco.mjtObj.mjOBJ_ACTUATOR, "right_knee")
    assert (lower[knee], upper[knee]) == (-150.0, 150.0)


def test_accel_step_covers_the_keyframe_spacing() -> None:
    dt = 1.0 / 60.0
    assert [accel_step(1.0 / hz, dt) for hz in (120.0, 60.0, 30.0, 24.0, 16.0)] == [2, 2, 2, 3, 4]
    assert accel_step(1.01 / 30.0, dt) == 2  # a wrap clip time-scaled by 1% onto whole frames


def test_com_is_mujocos_subtree_com(clips) -> None:
    humanoid, library = clips
    qpos = library.frames.qpos[[5, 40]]
    com, _ = com_and_clearance(humanoid, qpos)
    data = mujoco.MjData(humanoid.model)
    for q, c in zip(qpos, com, strict=True):
        data.qpos[:] = q
        mujoco.mj_forward(humanoid.model, data)
        np.testing.assert_allclose(c, data.subtree_com[0], atol=1e-12)


def test_residual_force_hand_computed() -> None:
    force = np.array([[3.0, 4.0, 10.0], [3.0, 4.0, 10.0], [3.0, 4.0, -1.0], [3.0, 4.0, 10.0]])
    contact = np.array([True, True, True, False])
    # |F_h| = 5: mu 0.2 holds 2 of it; mu 1 all of it; a pulling floor and flight leave |F|.
    np.testing.assert_allclose(residual_force(force[:1], contact[:1], 0.2), [3.0])
    np.testing.assert_allclose(residual_force(force, contact, 1.0), [0.0, 0.0, np.sqrt(26.0), np.sqrt(125.0)])


def test_residual_vector_is_the_force_outside_the_cone() -> None:
    force = np.array([[3.0, 4.0, 10.0], [3.0, 4.0, 10.0], [3.0, 4.0, -1.0], [3.0, 4.0, 10.0], [0.0, 0.0, 5.0]])
    contact = np.array([True, True, True, False, True])
    res = residual_vector(force, contact, 0.2)
    # mu F_z = 2 of |F_h| = 5 is the floor's, the other 3 along F_h = (3, 4)/5; a pulling floor and flight leave F.
    np.testing.assert_allclose(res, [[1.8, 2.4, 0.0], [1.8, 2.4, 0.0], [3.0, 4.0, -1.0], [3.0, 4.0, 10.0],
                                     [0.0, 0.0, 0.0]], atol=1e-12)  # fmt: skip
    # What is left for the floor is inside its cone (|F_h| <= mu F_z) where it touches and pushes.
    floor = (force - res)[[0, 1, 4]]
    assert np.all(np.linalg.norm(floor[:, :2], axis=-1) <= 0.2 * floor[:, 2] + 1e-12)
    np.testing.assert_allclose(np.linalg.norm(res, axis=-1), residual_force(force, contact, 0.2), atol=1e-12)


def test_standing_still_needs_body_weight_up_and_lifted_it_is_all_residual(clips) -> None:
    humanoid, library = clips
    pose = library.frames.qpos[0]
    _, clearance = com_and_clearance(humanoid, pose[None])
    assert clearance[0] <= CONTACT_TOLERANCE, "walk's first frame should have a foot on the floor"
    qpos, qvel = _still(pose, 2 * STEP + 3, humanoid.nv)
    on_floor = measure(humanoid, qpos, qvel, library.dt, STEP)
    weight = body_weight(humanoid)
    np.testing.assert_allclose(on_floor.force, np.tile([0.0, 0.0, weight], (3, 1)), atol=1e-9)
    assert on_floor.contact.all()
    np.testing.assert_allclose(on_floor.residual, 0.0, atol=1e-12)

    qpos[:, 2] += 1.0
    lifted = measure(humanoid, qpos, qvel, library.dt, STEP)
    assert not lifted.contact.any()
    np.testing.assert_allclose(lifted.residual, 1.0, atol=1e-12)
    # Nothing touches: the root must hold the whole weight, and switching contacts off changes nothing.
    np.testing.assert_allclose(lifted.root_residual, 1.0, atol=1e-9)
    np.testing.assert_allclose(lifted.hinge_ratio, lifted.hinge_ratio_unconstrained, atol=1e-12)


def test_ballistic_flight_has_no_residual_and_needs_no_torque(clips) -> None:
    humanoid, library = clips
    g = 9.81
    t = np.arange(9) * library.dt
    qpos, qvel = _still(library.frames.qpos[0], len(t), humanoid.nv)
    qpos[:, 0] += 1.5 * t
    qpos[:, 2] += 1.0 + 2.0 * t - 0.5 * g * t**2
    qvel[:, 0], qvel[:, 2] = 1.5, 2.0 - g * t
    frames = measure(humanoid, qpos, qvel, library.dt, STEP)
    assert not frames.contact.any()
    np.testing.assert_allclose(frames.residual, 0.0, atol=1e-9)
    # Free fall of a rigid pose: no generalised force anywhere.
    np.testing.assert_allclose(frames.root_residual, 0.0, atol=1e-9)
    np.testing.assert_allclose(frames.hinge_torque, 0.0, atol=1e-8)
    # A rigid pose moving without turning has no angular momentum, so it needs no moment either.
    np.testing.assert_allclose(frames.moment_rate, 0.0, atol=1e-9)
    np.testing.assert_allclose(frames.moment_residual, 0.0, atol=1e-12)


def _flight(humanoid: Humanoid, couple: np.ndarray, frames: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The character thrown with random joint velocities, nothing acting but gravity and ``couple`` (world, on the
    pelvis), sampled every dt: RK4 at dt / 10, no contacts, limits, actuators or armature (which MuJoCo's angular
    momentum does not count)."""
    m = copy.copy(humanoid.model)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    m.dof_armature[:] = 0.0
    m.opt.integrator, m.opt.timestep = mujoco.mjtIntegrator.mjINT_RK4, dt / 10.0
    data = mujoco.MjData(m)
    data.qpos[2], data.qpos[3] = 2.0, 1.0
    data.qvel[:] = np.random.default_rng(1).normal(0.0, 1.0, m.nv)
    data.xfrc_applied[1, 3:] = couple
    qpos, qvel = [], []
    for _ in range(frames):
        qpos.append(data.qpos.copy())
        qvel.append(data.qvel.copy())
        mujoco.mj_step(m, data, nstep=10)
    return np.array(qpos), np.array(qvel)


def test_angular_momentum_is_conserved_in_flight_and_a_couple_is_its_rate(clips) -> None:
    humanoid, library = clips
    dt = library.dt
    qpos, qvel = _flight(humanoid, np.zeros(3), 12, dt)
    moment = angular_momentum(humanoid, qpos, qvel)
    assert np.linalg.norm(moment[0]) > 1.0  # the limbs flail: the momentum is not trivially 0
    np.testing.assert_allclose(moment, np.tile(moment[0], (len(moment), 1)), atol=1e-7)
    # A constant couple on the pelvis (world frame) turns L at exactly that rate, whatever the limbs do.
    couple = np.array([3.0, -20.0, 12.0])
    qpos, qvel = _flight(humanoid, couple, 8, dt)
    rate = triangle_rate(angular_momentum(humanoid, qpos, qvel), dt, STEP)
    np.testing.assert_allclose(rate, np.tile(couple, (len(rate), 1)), atol=1e-3)  # RK4's error: ~5e-5 N m
    # In flight nothing can supply it: the residual is the couple, in body-weight metres.
    frames = measure(humanoid, qpos, qvel, dt, STEP)
    assert not frames.contact.any()
    np.testing.assert_allclose(frames.moment_residual, np.tile(couple, (len(rate), 1)) / body_weight(humanoid),
                               atol=1e-6)  # fmt: skip


def test_angular_momentum_by_finite_differences(clips) -> None:
    humanoid, library = clips
    m = humanoid.model
    qpos, qvel = library.frames.qpos[7].copy(), np.random.default_rng(0).normal(0.0, 1.0, m.nv)

    def inertial(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        data = mujoco.MjData(m)
        data.qpos[:] = q
        mujoco.mj_kinematics(m, data)
        return data.xipos.copy(), data.ximat.reshape(-1, 3, 3).copy()

    eps = 1e-7
    moved = qpos.copy()
    mujoco.mj_integratePos(m, moved, qvel, eps)
    (x0, r0), (x1, r1) = inertial(qpos), inertial(moved)
    mass = m.body_mass
    com, velocity = mass @ x0 / mass.sum(), (x1 - x0) / eps
    expected = np.zeros(3)
    for b in range(1, m.nbody):  # sum of m (x - c) x (v - v_c) + R I R^T w over the bodies
        spin = (r1[b] - r0[b]) @ r0[b].T / eps
        omega = np.array([spin[2, 1], spin[0, 2], spin[1, 0]])
        inertia = r0[b] @ np.diag(m.body_inertia[b]) @ r0[b].T
        expected += mass[b] * np.cross(x0[b] - com, velocity[b] - mass @ velocity / mass.sum()) + inertia @ omega
    np.testing.assert_allclose(angular_momentum(humanoid, qpos[None], qvel[None])[0], expected, rtol=1e-5, atol=1e-5)


def test_triangle_rate_is_exact_for_a_linear_quantity() -> None:
    t = np.arange(11) * 0.1
    values = np.stack([2.0 - 3.0 * t, 0.5 * t], axis=1)
    np.testing.assert_allclose(triangle_rate(values, 0.1, 3), np.tile([-3.0, 0.5], (5, 1)), atol=1e-12)
    # The slope steps from 0 to 1 at t = 0.5: the triangle centred there (frame 5, row 5 - h) weighs each side 1/2,
    # and 0.1 s on (row 4) 7/8 of it lies past the kink, where the rate is its mean 7/8.
    rate = triangle_rate(np.maximum(0.0, t - 0.5), 0.1, 2)
    assert rate[3] == pytest.approx(0.5) and rate[4] == pytest.approx(0.875)


def test_nnls_meets_its_optimality_conditions() -> None:
    np.testing.assert_allclose(nnls(np.eye(2), np.array([1.0, -2.0])), [1.0, 0.0])
    rng = np.random.default_rng(3)
    for _ in range(20):
        a, b = rng.normal(size=(6, 40)), rng.normal(size=6)
        x = nnls(a, b)
        gradient = a.T @ (b - a @ x)
        assert x.min() >= 0.0
        assert gradient.max() <= 1e-9  # no x_j may grow and lower the error ...
        np.testing.assert_allclose(gradient[x > 0.0], 0.0, atol=1e-9)  # ... nor move where it is free
    # Against a brute force over every support of a small problem.
    a, b = rng.normal(size=(3, 5)), rng.normal(size=3)
    best = min(
        (np.linalg.norm(a[:, s] @ np.linalg.lstsq(a[:, s], b, rcond=None)[0] - b)
         for k in range(1, 6) for s in map(list, __import__("itertools").combinations(range(5), k))
         if np.all(np.linalg.lstsq(a[:, s], b, rcond=None)[0] >= 0.0)),
        default=np.linalg.norm(b),
    )  # fmt: skip
    assert np.linalg.norm(a @ nnls(a, b) - b) == pytest.approx(min(best, np.linalg.norm(b)), abs=1e-10)


def test_pyramid_holds_the_friction_cone() -> None:
    edges = pyramid(0.8)
    np.testing.assert_allclose(edges[:, 2], 1.0)
    np.testing.assert_allclose(np.linalg.norm(edges[:, :2], axis=1), 0.8 / np.cos(np.pi / 8))
    # Each tangential direction reaches at least mu along it: the polygon's support function >= mu everywhere.
    for angle in np.linspace(0.0, 2.0 * np.pi, 73):
        direction = np.array([np.cos(angle), np.sin(angle)])
        assert (edges[:, :2] @ direction).max() >= 0.8 - 1e-12


def test_wrench_residual_hand_computed() -> None:
    weight, mu, half = 400.0, 0.5, 0.1
    up, com = np.array([0.0, 0.0, weight]), np.array([0.0, 0.0, 0.9])
    corners = np.array([[x, y, 0.0] for x in (-half, half) for y in (-half, half)])
    # A square foot under the CoM turns the body about the vertical through the lever of its four corners: at most
    # mu' W half sqrt 2 with the pyramid's mu' = mu / cos(pi / 8) (each corner's tangent is one of its edges).
    most = mu / np.cos(np.pi / 8) * weight * half * np.sqrt(2.0)
    for yaw, left in ((0.5 * most, 0.0), (most + 20.0, 20.0)):
        force_left, moment_left = contact_wrench_residual(up, np.array([0.0, 0.0, yaw]), com, corners, mu, weight)
        np.testing.assert_allclose(force_left, 0.0, atol=1e-7)
        np.testing.assert_allclose(moment_left, [0.0, 0.0, left / weight], atol=1e-6)
    # One point 0.2 m ahead of the CoM: holding the weight there tips the body forward (a moment -0.2 W about y),
    # which the reference, not turning, does not have: 0.2 body-weight metres about +y are left.
    # (The force rows' weight of 1000 lets the fit trade 2e-7 body weights of force for moment: the priority's slack.)
    force_left, moment_left = contact_wrench_residual(up, np.zeros(3), com, np.array([[0.2, 0.0, 0.0]]), mu, weight)
    np.testing.assert_allclose(force_left, 0.0, atol=1e-6)
    np.testing.assert_allclose(moment_left, [0.0, 0.2, 0.0], atol=1e-5)
    # No contact: all of both is left.
    force_left, moment_left = contact_wrench_residual(up, np.array([1.0, 2.0, 3.0]), com, np.zeros((0, 3)), mu, weight)
    np.testing.assert_allclose(force_left, [0.0, 0.0, 1.0])
    np.testing.assert_allclose(moment_left, np.array([1.0, 2.0, 3.0]) / weight)


def test_hinge_torques_are_qfrc_inverse_at_the_actuated_dofs(clips) -> None:
    humanoid, library = clips
    m = humanoid.model
    assert np.all(m.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT) and np.all(m.actuator_gear[:, 0] == 1.0)
    dofs = m.jnt_dofadr[m.actuator_trnid[:, 0]]
    qpos, qvel = library.frames.qpos[10:15], library.frames.qvel[10:15]
    frames = measure(humanoid, qpos, qvel, library.dt, STEP)
    # The middle frame by hand: qacc from the 2-step difference, then mj_inverse.
    qacc = np.zeros(m.nv)
    before, after = np.zeros(m.nv), np.zeros(m.nv)
    span = STEP * library.dt
    mujoco.mj_differentiatePos(m, before, span, qpos[0], qpos[2])
    mujoco.mj_differentiatePos(m, after, span, qpos[2], qpos[4])
    qacc[:] = (after - before) / span
    data = mujoco.MjData(m)
    data.qpos[:], data.qvel[:], data.qacc[:] = qpos[2], qvel[2], qacc
    mujoco.mj_inverse(m, data)
    np.testing.assert_allclose(frames.hinge_torque[0], data.qfrc_inverse[dofs], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(frames.root_residual[0], np.linalg.norm(data.qfrc_inverse[:3]) / body_weight(humanoid))


def test_a_hinge_over_its_limit_is_counted(clips) -> None:
    humanoid, _ = clips
    lower, upper = torque_limits(humanoid)
    knee = mujoco.mj_name2id(humanoid.model, mujoco.mjtObj.mjOBJ_ACTUATOR, "right_knee")
    elbow = mujoco.mj_name2id(humanoid.model, mujoco.mjtObj.mjOBJ_ACTUATOR, "left_elbow")
    torque = np.zeros((4, humanoid.nu))
    torque[0, knee] = 1.5 * upper[knee]  # 225 N m against 150
    torque[1, knee] = -1.2 * upper[knee]  # -180 N m against -150
    torque[2, elbow] = 0.9 * lower[elbow]  # within its limit
    ratio = hinge_ratios(humanoid, torque)
    assert ratio[0, knee] == pytest.approx(1.5) and ratio[1, knee] == pytest.approx(1.2)
    zeros = np.zeros(4)
    frames = FrameFeasibility(force=np.zeros((4, 3)), contact=np.ones(4, bool), clearance=zeros, residual=zeros,
                              hinge_torque=torque, hinge_ratio=ratio, root_residual=zeros,
                              hinge_ratio_unconstrained=0.0 * ratio, range_excess=0.0 * ratio,
                              moment_rate=np.zeros((4, 3)), moment_residual=np.zeros((4, 3)))  # fmt: skip
    row = summarise(humanoid, frames, first_frame=STEP)
    assert row["hinge_over_share"] == 0.5 and row["worst_joint"] == "right_knee"
    assert row["worst_joint_over_share"] == 0.5
    # 95th percentile of (0, 0, 1.2, 1.5) by linear interpolation: position 2.85 -> 1.2 + 0.85 * 0.3.
    assert row["worst_joint_p95_ratio"] == pytest.approx(1.455)
    assert row["unconstrained_hinge_over_share"] == 0.0 and row["out_of_range_joint"] is None


def test_hinges_past_their_joint_range_are_measured(clips) -> None:
    humanoid, library = clips
    m = humanoid.model
    qpos = library.frames.qpos[:2].copy()
    knee = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, "left_knee")
    elbow = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, "right_elbow")
    qpos[0, humanoid.hinge_qpos[knee]] = -0.1  # knee range [0, 3.14]: hyperextended by 0.1 rad
    qpos[1, humanoid.hinge_qpos[elbow]] = 0.25  # elbow range [-3.14, 0]
    qpos[1, humanoid.hinge_qpos[knee]] = 1.0
    expected = np.zeros((2, humanoid.nu))
    expected[0, knee], expected[1, elbow] = 0.1, 0.25
    np.testing.assert_allclose(range_excess(humanoid, qpos), expected, atol=1e-12)


def test_loop_seam_keeps_the_hinge_angles_continuous(clips) -> None:
    humanoid, library = clips
    c = library.clip_index("spinkick")
    n = library.num_frames[c] - 1
    # The library carries whole turns on (dance_a's shoulders), but spinkick's right hip ends its cycle on the other
    # Euler branch (x and z about pi away), which its continuation does not mend.
    seam = library.query(np.full(2, c), np.array([n - 1, n]) * library.dt)
    assert np.abs(np.diff(seam.qpos[:, humanoid.hinge_qpos], axis=0)).max() > 3.0
    qpos, _ = clip_reference(humanoid, library, c, STEP)
    assert len(qpos) == n + 2 * STEP
    # Across the seam (frames n - 1, n, n + 1) the re-chosen angles move as little as the library's do before it.
    across = np.abs(np.diff(qpos[n - 1 : n + 2, humanoid.hinge_qpos], axis=0)).max()
    before = np.abs(np.diff(qpos[n - 3 : n, humanoid.hinge_qpos], axis=0)).max()
    assert across < 2.0 * before + 0.05


def test_command_writes_the_table_numbers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "feasibility.json"
    main(["--motions", "walk", "--out", str(out), "--friction", "0.8"])
    result = json.loads(out.read_text())
    walk = result["clips"]["walk"]
    assert result["friction"] == 0.8 and result["friction_source"] == "--friction"
    assert walk["frames"] == 76 and walk["step"] == 2  # one 76-frame cycle of 30 Hz keyframes
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("walk "))
    assert f"{walk['residual_mean']:.3f}" in row and walk["worst_joint"] in row


@pytest.mark.parametrize(
    ("args", "message"),
    [(["--motions", "nosuchclip"], "nosuchclip: no such motion file"), (["--friction", "-1"], "--friction")],
)
def test_bad_input_is_refused_in_one_line(args: list[str], message: str, tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main([*args, "--out", str(tmp_path / "f.json")])
    text = str(exit_info.value.code)
    assert text.startswith("error: ") and message in text and "\n" not in text
    assert not (tmp_path / "f.json").exists()
