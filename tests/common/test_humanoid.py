"""The MJCF against DeepMimic's character/controller files and against IsaacGymEnvs' amp_humanoid.xml."""

from __future__ import annotations

import json
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest

from common.character.humanoid import DEEPMIMIC_JOINTS, Humanoid, PhysicsConfig, set_torsional_friction

DATA = Path(__file__).resolve().parents[2] / "common" / "motion" / "data" / "deepmimic"
AMP_XML = Path(__file__).resolve().parents[1] / "data" / "amp_humanoid.xml"

# DeepMimic joint name -> our body name (the joint's child body).
BODY_OF = {
    "root": "pelvis",
    **{j: b for j, b, _ in DEEPMIMIC_JOINTS},
    "right_wrist": "right_hand",
    "left_wrist": "left_hand",
}


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


@pytest.fixture(scope="module")
def character() -> dict:
    return json.loads((DATA / "humanoid3d.txt").read_text())


def _amp_model() -> mujoco.MjModel:
    # amp_humanoid.xml names a material it never defines; drop it so MuJoCo loads the file.
    xml = re.sub(r'\s*material="grid"', "", AMP_XML.read_text())
    return mujoco.MjModel.from_xml_string(xml)


def test_structure(humanoid: Humanoid) -> None:
    assert humanoid.num_bodies == 15
    assert humanoid.nq == 7 + 28 and humanoid.nv == 6 + 28 and humanoid.nu == 28
    assert humanoid.body_names[humanoid.root_index] == "pelvis"
    assert [humanoid.body_names[i] for i in humanoid.foot_indices] == ["right_foot", "left_foot"]
    # Actuators drive exactly the hinges, each once.
    assert sorted(humanoid.hinge_qpos.tolist()) == list(range(7, 35))
    np.testing.assert_array_equal(humanoid.model.actuator_trnid[:, 0], humanoid.model.dof_jntid[humanoid.hinge_dof])


def test_timestep_from_config() -> None:
    h = Humanoid(PhysicsConfig(control_hz=30.0, substeps=4))
    assert h.model.opt.timestep == pytest.approx(1.0 / 120.0)
    with pytest.raises(ValueError, match="substeps"):
        PhysicsConfig(substeps=0)


def test_armature_on_every_hinge_only() -> None:
    h = Humanoid()
    m = h.model
    np.testing.assert_array_equal(m.dof_armature[:6], 0.0)  # the free root joint has no rotor
    np.testing.assert_array_equal(m.dof_armature[h.hinge_dof], 0.01)  # the MJCF's value
    override = Humanoid(PhysicsConfig(armature=0.004)).model
    np.testing.assert_array_equal(override.dof_armature[h.hinge_dof], 0.004)
    np.testing.assert_array_equal(override.dof_armature[:6], 0.0)
    with pytest.raises(ValueError, match="armature"):
        PhysicsConfig(armature=-0.001)


def test_torque_scale_multiplies_every_servos_limit() -> None:
    """A servo asked for far more than its limit delivers its limit: 90 N m at the ankle as in DeepMimic, 180 with
    torque_scale 2 (MuJoCo's own clamp on the position actuator's force); the gains are unchanged."""
    delivered = []
    for scale in (1.0, 2.0):
        h = Humanoid(PhysicsConfig(torque_scale=scale))
        m, d = h.model, mujoco.MjData(h.model)
        d.qpos[2] = 1.0
        d.qpos[3] = 1.0
        a = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, "right_ankle_y")
        d.ctrl[a] = 1.0  # 1 rad from the pose: kp 1 rad far above the limit
        mujoco.mj_forward(m, d)
        delivered.append(float(d.actuator_force[a]))
        np.testing.assert_array_equal(m.actuator_gainprm, Humanoid().model.actuator_gainprm)
    assert delivered == [pytest.approx(90.0), pytest.approx(180.0)]
    with pytest.raises(ValueError, match="torque_scale"):
        PhysicsConfig(torque_scale=0.0)


def test_offsets_masses_and_gains_match_deepmimic(humanoid: Humanoid, character: dict) -> None:
    m = humanoid.model
    ctrl = {c["Name"]: c for c in json.loads((DATA / "humanoid3d_ctrl.txt").read_text())["PDControllers"]}
    joints = {j["Name"]: j for j in character["Skeleton"]["Joints"]}
    for body in character["BodyDefs"]:
        name = body["Name"]
        b = humanoid.body_index(BODY_OF[name]) + 1
        assert m.body_mass[b] == pytest.approx(body["Mass"])
        j = joints[name]
        if name != "root":
            # Y up (x, y, z) -> Z up (x, -z, y)
            np.testing.assert_allclose(m.body_pos[b], [j["AttachX"], -j["AttachZ"], j["AttachY"]], atol=1e-9)
    assert m.body_mass.sum() == pytest.approx(45.0)
    for name, _, kind in DEEPMIMIC_JOINTS:
        axes = ("_x", "_y", "_z") if kind == "spherical" else ("",)
        for axis in axes:
            a = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, name + axis)
            assert m.actuator_gainprm[a, 0] == ctrl[name]["Kp"]
            assert m.actuator_biasprm[a, 1:3].tolist() == [-ctrl[name]["Kp"], -ctrl[name]["Kd"]]
            assert m.actuator_forcerange[a].tolist() == [-joints[name]["TorqueLim"], joints[name]["TorqueLim"]]


def test_joint_limits_only_on_knees_and_elbows(humanoid: Humanoid) -> None:
    m = humanoid.model
    limited = {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in np.flatnonzero(m.jnt_limited)}
    assert limited == {"right_knee", "left_knee", "right_elbow", "left_elbow"}
    knee = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "right_knee")
    elbow = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "right_elbow")
    # DeepMimic's knee range [-3.14, 0] and elbow [0, 3.14] about +z (Y up) negate about +y.
    np.testing.assert_allclose(m.jnt_range[knee], [0.0, 3.14])
    np.testing.assert_allclose(m.jnt_range[elbow], [-3.14, 0.0])


def test_matches_amp_humanoid(humanoid: Humanoid) -> None:
    amp = _amp_model()
    ours = humanoid.model
    names = [mujoco.mj_id2name(amp, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(amp.nbody)]
    assert names[1:] == list(humanoid.body_names)
    # Same joint offsets, and in a zero pose the same world positions of every body.
    np.testing.assert_allclose(ours.body_pos[2:], amp.body_pos[2:], atol=1e-6)
    xpos = []
    for model in (ours, amp):
        d = mujoco.MjData(model)
        mujoco.mj_kinematics(model, d)
        xpos.append(d.xpos.copy())
    np.testing.assert_allclose(xpos[0], xpos[1], atol=1e-6)
    # Main collision shapes: same type and radius per body (amp adds a waist sphere and clavicles; its head
    # sphere is 0.095 m against DeepMimic's 0.1025 m).
    for body in humanoid.body_names:
        g_ours = humanoid.geom_of_body(body)
        g_amp = mujoco.mj_name2id(amp, mujoco.mjtObj.mjOBJ_GEOM, body)
        assert ours.geom_type[g_ours] == amp.geom_type[g_amp], body
        tol = 0.008 if body == "head" else 1e-6
        np.testing.assert_allclose(ours.geom_size[g_ours], amp.geom_size[g_amp], atol=tol, err_msg=body)
    # Totals differ only by amp's density-based masses: both near DeepMimic's 45 kg.
    assert abs(amp.body_mass.sum() - ours.body_mass.sum()) / ours.body_mass.sum() < 0.15


def test_hinges_compose_as_intrinsic_xyz(humanoid: Humanoid) -> None:
    """Three nested hinges x, y, z give the body rotation Rx(a) Ry(b) Rz(c) relative to the parent."""
    from common.maths.rotations import euler_xyz_to_quat, quat_conj, quat_mul

    m = humanoid.model
    d = mujoco.MjData(m)
    angles = np.array([0.3, -0.7, 1.1])
    d.qpos[3:7] = [1, 0, 0, 0]
    group = next(g for g in humanoid.joint_groups if g.name == "right_hip")
    d.qpos[list(group.qpos)] = angles
    mujoco.mj_kinematics(m, d)
    rel = quat_mul(quat_conj(d.xquat[1]), d.xquat[humanoid.body_index("right_thigh") + 1])
    expected = euler_xyz_to_quat(angles)
    assert abs(np.dot(rel, expected)) == pytest.approx(1.0, abs=1e-12)


_SPHERE_ON_FLOOR = """<mujoco><option timestep="0.002"/><worldbody>
<geom name="floor" type="plane" size="0 0 0.05" condim="3" friction="1 0.005 0.0001"/>
<body pos="0 0 0.1"><freejoint/><geom type="sphere" size="0.1" mass="1" condim="3" friction="1 0.005 0.0001"/></body>
</worldbody></mujoco>"""


@pytest.mark.parametrize("couple", [0.15, 0.6])
def test_torsional_friction_resists_a_spin_up_to_its_limit(couple: float) -> None:
    """A 1 kg ball of radius 0.1 m on the floor (I = 0.4 m r^2 = 0.004 kg m^2), a vertical couple held for 0.5 s.
    Without torsional friction its one contact point gives no moment: w = couple / I x 0.5 s. With a coefficient of
    0.03 m the floor resists up to 0.03 x 9.81 N = 0.294 N m: 0.15 N m barely turns it (MuJoCo's soft contact creeps),
    0.6 N m spins it at (0.6 - 0.294) / I x 0.5 s = 38.2 rad/s."""

    def spin(coefficient: float) -> float:
        m = mujoco.MjModel.from_xml_string(_SPHERE_ON_FLOOR)
        if coefficient:
            set_torsional_friction(m, coefficient)
        d = mujoco.MjData(m)
        for _ in range(250):
            d.qfrc_applied[5] = couple
            mujoco.mj_step(m, d)
        return float(d.qvel[5])

    assert spin(0.0) == pytest.approx(couple / 0.004 * 0.5, rel=1e-6)
    held = spin(0.03)
    if couple < 0.03 * 9.81:
        assert abs(held) < 0.05 * couple / 0.004 * 0.5  # under 5 % of the free spin
    else:
        assert held == pytest.approx((couple - 0.03 * 9.81) / 0.004 * 0.5, rel=0.05)


def test_torsional_friction_sets_the_floor_only() -> None:
    base, h = Humanoid().model, Humanoid(PhysicsConfig(torsional_friction=0.03)).model
    floor = mujoco.mj_name2id(h, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    assert h.geom_condim[floor] == 4 and h.geom_friction[floor, 1] == 0.03
    others = np.arange(h.ngeom) != floor
    np.testing.assert_array_equal(h.geom_condim[others], base.geom_condim[others])
    np.testing.assert_array_equal(h.geom_friction[others], base.geom_friction[others])
    assert base.geom_condim[floor] == 3  # the default character is unchanged
    with pytest.raises(ValueError, match="torsional_friction"):
        PhysicsConfig(torsional_friction=-0.01)
    with pytest.raises(ValueError, match="no floor"):
        set_torsional_friction(mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><freejoint/>"
                                                              "<geom size='0.1'/></body></worldbody></mujoco>"), 0.03)
