"""The ``parc`` observation: invariant to a shift along the ground and a turn about the vertical, values by hand,
named layout, and the future frames the Observer queries."""

from __future__ import annotations

import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.character.state import CharacterState
from common.config import ConfigError, from_dict
from common.maths.rotations import quat_from_yaw, quat_mul, quat_rotate, quat_yaw
from common.motion.dataset import load_motions
from common.motion.library import MotionLibrary
from common.sim.gym import GymConfig, TrackingGym
from common.sim.observation import ObservationConfig, Observer, parc_features

OFFSETS = (1, 2, 4, 8, 16)


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


@pytest.fixture(scope="module")
def library(humanoid: Humanoid) -> MotionLibrary:
    return load_motions(["walk", "backflip"], humanoid)


def _states(library: MotionLibrary, times: list[float]) -> CharacterState:
    return library.query(np.array([0, 1, 1]), np.array(times))


def _turned(s: CharacterState, yaw: float | np.ndarray, shift: np.ndarray) -> CharacterState:
    """The same characters turned by ``yaw`` (one or one per character) about +Z through the origin, then shifted."""
    q = quat_from_yaw(np.broadcast_to(yaw, s.body_pos.shape[:1]))[:, None]
    out = CharacterState(**{k: v.copy() for k, v in vars(s).items()})
    out.body_pos = quat_rotate(q, s.body_pos) + shift
    out.body_rot = quat_mul(q, s.body_rot)
    out.body_linvel, out.body_angvel = quat_rotate(q, s.body_linvel), quat_rotate(q, s.body_angvel)
    out.qpos[:, :3], out.qpos[:, 3:7] = out.body_pos[:, 0], out.body_rot[:, 0]
    out.qvel[:, :3] = out.body_linvel[:, 0]  # the root's angular velocity in qvel is in its own frame: unchanged
    return out


def test_features_unchanged_by_ground_shift_and_turn(humanoid: Humanoid, library: MotionLibrary) -> None:
    # The simulated characters are other frames than their references, so every difference is far from zero.
    sim = _states(library, [0.2, 0.4, 0.9])
    refs = {k: _states(library, [0.25 + 0.02 * k, 0.45 + 0.01 * k, 0.7 + 0.03 * k]) for k in OFFSETS}
    base = parc_features(sim, refs, humanoid.hinge_qpos, humanoid.hinge_dof)
    shift = np.array([4.0, -2.0, 0.0])
    for yaw in (1.3, -2.9):
        moved = parc_features(_turned(sim, yaw, shift), {k: _turned(r, yaw, shift) for k, r in refs.items()},
                              humanoid.hinge_qpos, humanoid.hinge_dof)  # fmt: skip
        assert list(moved) == list(base)
        for key in base:
            np.testing.assert_allclose(moved[key], base[key], atol=1e-10, err_msg=key)
    assert np.abs(base["ref1_pos"]).max() > 0.1 and np.abs(base["ref16_rot"] - [1, 0, 0, 0, 1, 0] * 15).max() > 0.1
    # Turning only the simulated characters changes their relation to the reference.
    alone = parc_features(_turned(sim, 1.3, shift), refs, humanoid.hinge_qpos, humanoid.hinge_dof)
    assert np.abs(alone["ref1_pos"] - base["ref1_pos"]).max() > 1.0


def test_features_by_hand(humanoid: Humanoid, library: MotionLibrary) -> None:
    """Root heading 90 deg (+x of the root along world +y): a simulated character 0.1 m further along world +x
    than its reference is 0.1 m along the heading frame's -y; the same pose gives identity rotations."""
    ref = _states(library, [0.2, 0.4, 0.9])
    ref = _turned(ref, np.pi / 2 - quat_yaw(ref.body_rot[:, 0]), np.zeros(3))
    sim = _turned(ref, 0.0, np.array([0.1, 0.0, 0.0]))
    f = parc_features(sim, {1: ref, 3: ref}, humanoid.hinge_qpos, humanoid.hinge_dof)
    np.testing.assert_allclose(f["ref1_pos"].reshape(3, 15, 3), np.tile([0.0, -0.1, 0.0], (3, 15, 1)), atol=1e-12)
    np.testing.assert_allclose(f["ref3_rot"], np.tile([1.0, 0, 0, 0, 1, 0], (3, 15)), atol=1e-12)
    np.testing.assert_allclose(f["ref1_vel"], 0.0, atol=1e-12)
    np.testing.assert_allclose(f["ref3_dof_pos"], 0.0, atol=1e-12)
    # The root sits above the heading frame's origin and looks along its +x.
    np.testing.assert_allclose(f["sim_pos"][:, :2], 0.0, atol=1e-12)
    np.testing.assert_allclose(f["sim_pos"][:, 2], sim.body_pos[:, 0, 2])
    assert "ref3_vel" not in f  # velocity errors only for the first offset


def test_observer_layout_and_future_frames(humanoid: Humanoid, library: MotionLibrary) -> None:
    gym = TrackingGym(GymConfig(num_envs=3, threads=1), library, humanoid)
    res = gym.reset(clips=np.array([0, 1, 1]), times=np.array([0.1, 0.2, 0.3]))
    observe = Observer(ObservationConfig(future_frames=(1, 4)), humanoid, library)
    layout = observe.layout(res)
    widths = {k: s.stop - s.start for k, s in layout.items()}
    assert widths == {"sim_pos": 45, "sim_rot": 90, "sim_vel": 45, "sim_angvel": 45, "dof_pos": 28, "dof_vel": 28,
                      "ref1_pos": 45, "ref1_rot": 90, "ref1_dof_pos": 28, "ref1_vel": 45, "ref1_angvel": 45,
                      "ref1_dof_vel": 28, "ref4_pos": 45, "ref4_rot": 90, "ref4_dof_pos": 28}  # fmt: skip
    obs = observe(res)
    assert obs.shape == (3, sum(widths.values()))
    # Right after RSI the simulated character is its reference at t, so ref4_pos is x(t) - x_ref(t + 4 dt).
    ahead = library.query(res.clip, res.time + 4 * gym.dt)
    np.testing.assert_allclose(
        np.linalg.norm(obs[:, layout["ref4_pos"]].reshape(3, 15, 3), axis=-1),
        np.linalg.norm(res.sim.body_pos - ahead.body_pos, axis=-1), atol=1e-9,
    )  # fmt: skip
    np.testing.assert_array_equal(observe.final(res, np.array([2])), obs[2:])  # no step yet: final = current
    local = Observer(ObservationConfig(kind="local"), humanoid, library)
    assert list(local.layout(res)) == ["sim_local", "ref_local", "ref_root_pos", "ref_root_rot", "phase"]
    gym.close()


def test_bad_offsets_fail_clearly() -> None:
    with pytest.raises(ConfigError, match="future_frames must be distinct positive offsets"):
        from_dict(ObservationConfig, {"future_frames": [1, 4, 2]}, source="x.yaml")
