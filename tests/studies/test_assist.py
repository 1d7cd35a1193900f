"""Root forces (studies.samcon.assist): the force's sign, units and place against physics, the law by hand, assisted
searches that replay bit-exactly, a judge that is the evaluator's, and the command."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import EvalConfig, evaluate
from common.maths.rotations import quat_from_axis_angle, quat_mul, quat_rotate, quat_rotate_inv
from common.motion.dataset import load_motions
from common.sim.physics import BatchedSim
from samcon.config import CostConfig, SearchConfig
from samcon.feedback import ClipPlan, open_loop_policy
from samcon.lqr import linearise, nominal_states
from samcon.search import reference_frames, replay, samcon, searched_frames, start_state
from studies.samcon.assist import AssistConfig, RootAssist, judge, main, residual_per_frame
from studies.samcon.couple import Couple
from studies.samcon.feasibility import body_weight, com_and_clearance, total_mass
from studies.samcon.forces import HeldForces, assisted_replay


@pytest.fixture(scope="module")
def walk() -> tuple[Humanoid, object]:
    humanoid = Humanoid()
    return humanoid, load_motions(["walk"], humanoid)


def test_the_residual_of_a_pose_held_in_the_air_holds_it_there(walk) -> None:
    """A still pose 1 m up needs m |g| upwards, all of it residual (nothing touches); applied at the root it keeps
    the centre of mass where it is, while without it the body falls g t^2 / 2."""
    humanoid, library = walk
    pose = library.frames.qpos[0].copy()
    pose[2] += 1.0
    qpos = np.repeat(pose[None], 9, axis=0)
    res = residual_per_frame(humanoid, qpos, library.dt, step=2)
    np.testing.assert_allclose(res, np.tile([0.0, 0.0, body_weight(humanoid)], (9, 1)), atol=1e-6)
    steps = 10
    sims = BatchedSim(humanoid, 2, threads=0, applied=True)
    sims.set_state(np.arange(2), np.repeat(pose[None], 2, axis=0), np.zeros((2, humanoid.nv)))
    force = np.zeros((2, humanoid.nv))
    force[0, 0:3] = res[0]  # the first character is held, the second is not
    com0 = com_and_clearance(humanoid, sims.qpos.copy())[0]
    for _ in range(steps):
        sims.step(np.repeat(pose[None, humanoid.hinge_qpos], 2, axis=0), force)
    drop = com0[:, 2] - com_and_clearance(humanoid, sims.qpos.copy())[0][:, 2]
    sims.close()
    free_fall = 0.5 * 9.81 * (steps * humanoid.physics.control_dt) ** 2  # 0.136 m
    assert abs(drop[0]) < 1e-3
    assert drop[1] == pytest.approx(free_fall, rel=0.02)


def test_the_law_by_hand(walk) -> None:
    humanoid, library = walk
    m, weight = total_mass(humanoid), body_weight(humanoid)
    ref = reference_frames(library, 0, 40)
    f = 20
    qpos, qvel = ref.qpos[[f, f, f]].copy(), ref.qvel[[f, f, f]].copy()
    qpos[1, 0] += 0.1  # 10 cm ahead: kp pulls back
    qvel[2, 1] -= 0.5  # 0.5 m/s too slow sideways: kd pushes
    pd = RootAssist(humanoid, library, 0, 30, AssistConfig(kp=100.0, kd=20.0, cap=2.0, step=2))(f, qpos, qvel)
    expected = np.zeros((3, humanoid.nv))
    expected[1, 0], expected[2, 1] = -m * 100.0 * 0.1, m * 20.0 * 0.5
    np.testing.assert_allclose(pd, expected, atol=1e-9)
    # Capped: a 2 m error asks for 200 m/s^2, the cap gives 0.5 body weights along the same direction.
    qpos[1, 0] = ref.qpos[f, 0] + 2.0
    capped = RootAssist(humanoid, library, 0, 30, AssistConfig(cap=0.5, step=2))(f, qpos[1:2], ref.qvel[f : f + 1])
    np.testing.assert_allclose(capped[0, 0:3], [-0.5 * weight, 0.0, 0.0], rtol=1e-12)
    # Feed-forward alone: the mean of the residual of frames f and f + 1.
    residual = residual_per_frame(humanoid, reference_frames(library, 0, 30).qpos, library.dt, 2)
    ff = RootAssist(humanoid, library, 0, 30, AssistConfig(scale=1.0, kp=0.0, kd=0.0, cap=10.0, step=2))
    np.testing.assert_allclose(ff(f, qpos[:1], qvel[:1])[0, 0:3], 0.5 * (residual[f] + residual[f + 1]), atol=1e-9)
    # A zero cap gives no force and no dependence on the state, also where the pull would be 0 (on the reference).
    none = RootAssist(humanoid, library, 0, 30, AssistConfig(cap=0.0, step=2))
    on_ref = ref.qpos[f : f + 1], ref.qvel[f : f + 1]
    assert not none(f, *on_ref).any() and not none.jacobian(f, *on_ref).any()


def test_an_assisted_search_replays_bit_exactly_and_a_zero_cap_is_the_plain_search(walk) -> None:
    humanoid, library = walk
    search = SearchConfig(segment_frames=4, samples=8, iterations=2, keep=3, elite=4, lookahead_frames=4)
    steps = searched_frames(library, 0, 12, search.lookahead_frames)  # the law covers the look-ahead too

    def run(cap: float | None):
        force = None if cap is None else RootAssist(humanoid, library, 0, steps, AssistConfig(cap=cap, step=2))
        return samcon(humanoid, library, 0, 12, search, CostConfig(), np.random.default_rng(5), force=force)

    plain, zero, pushed = run(None), run(0.0), run(0.5)
    np.testing.assert_array_equal(plain.targets, zero.targets)
    np.testing.assert_array_equal(plain.segment_cost, zero.segment_cost)
    law = RootAssist(humanoid, library, 0, 12, AssistConfig(cap=0.5, step=2))
    # Replayed with the law, the path passes through the searched end states; held, its forces do the same.
    states, forces = assisted_replay(humanoid, pushed.start_state, pushed.targets, law)
    np.testing.assert_array_equal(states[pushed.bounds[1:] - 1], pushed.end_states)
    np.testing.assert_array_equal(replay(humanoid, pushed.start_state, pushed.targets, force=law), states)
    np.testing.assert_array_equal(replay(humanoid, pushed.start_state, pushed.targets, force=HeldForces(forces)),
                                  states)  # fmt: skip
    none = RootAssist(humanoid, library, 0, 12, AssistConfig(cap=0.0, step=2))
    assert not assisted_replay(humanoid, zero.start_state, zero.targets, none)[1].any()
    assert np.abs(forces[:, 0:3]).max() > 1.0 and not forces[:, 3:].any()
    assert np.linalg.norm(forces[:, 0:3], axis=-1).max() <= 0.5 * body_weight(humanoid) * (1 + 1e-12)


def test_the_judge_is_the_evaluator(walk) -> None:
    """An open-loop path that falls (the reference's targets bent 0.6 rad): the judge's errors and its failure step
    are the shared evaluator's."""
    humanoid, library = walk
    frames = 120
    ref = reference_frames(library, 0, frames)
    targets = ref.qpos[1:, humanoid.hinge_qpos] + 0.6
    plan = ClipPlan(targets, np.array([0, frames]), np.zeros((1, humanoid.nu, 16)), np.zeros((1, humanoid.nu)))
    ev = EvalConfig(starts_per_clip=1, max_frames=frames, threads=1)
    result = evaluate(open_loop_policy({"walk": plan}, library, humanoid), library, humanoid, ev)
    got = judge(humanoid, replay(humanoid, start_state(library, humanoid, 0), targets), ref[1:], ev)
    assert result.per_clip["survival"][0] == 0.0 and got["fell_at"] == result.episode_length[0, 0]
    assert got["mpjpe_g"] == pytest.approx(result.per_clip["mpjpe_g"][0], rel=1e-9)
    assert got["mpjpe_l"] == pytest.approx(result.per_clip["mpjpe_l"][0], rel=1e-9)
    # Without the grace period the rule fires earlier or at the same step, never later.
    early = judge(humanoid, replay(humanoid, start_state(library, humanoid, 0), targets), ref[1:],
                  replace(ev, termination=replace(ev.termination, grace_frames=0)))  # fmt: skip
    assert early["fell_at"] <= got["fell_at"]


def test_command_writes_searched_and_polished_figures(tmp_path: Path) -> None:
    out = tmp_path / "assist.json"
    main(["--config", "configs/samcon/debug.yaml", "--motions", "walk", "--set", "polish.search=false",
          "--cap", "0.3", "--then-caps", "0", "--out", str(out)])  # fmt: skip
    row = json.loads(out.read_text())["clips"]["walk"]
    assert row["frames"] == 6 and row["step"] == 2
    assert set(row["searched"]) == {"mpjpe_g", "mpjpe_l", "fell_at"} and "kept" in row["polished"]
    assert 0.0 < row["force_body_weights"]["max"] <= 0.3 + 1e-9
    # Polished again without the force: an unassisted path, judged with no force.
    (last,) = row["then"]
    assert last["cap"] == 0.0 and last["force_body_weights"]["max"] == 0.0 and "kept" in last


def test_command_reports_the_root_torque(tmp_path: Path) -> None:
    out = tmp_path / "assist.json"
    main(["--config", "configs/samcon/debug.yaml", "--motions", "spin", "--set", "polish.search=false",
          "--cap", "0", "--torque-cap", "0.3", "--out", str(out)])  # fmt: skip
    data = json.loads(out.read_text())
    row = data["clips"]["spin"]
    assert data["assist"]["torque_cap"] == 0.3 and row["force_body_weights"]["max"] == 0.0
    torque = row["torque_body_weight_metres"]
    assert 0.0 < torque["vertical_mean"] <= torque["mean"] <= torque["max"] <= 0.3 + 1e-9


def test_command_searches_around_the_assisted_path_down_to_none(tmp_path: Path) -> None:
    """--then-search: a search around the torque-assisted path with a smaller torque, then with none; the last
    stage is an unassisted path that replays, without any force, to the figures reported; --paths holds it."""
    out, paths = tmp_path / "assist.json", tmp_path / "paths.npz"
    main(["--config", "configs/samcon/debug.yaml", "--motions", "walk", "--set", "polish.search=false",
          "--cap", "0", "--torque-cap", "0.2", "--then-search", "0:0.05", "0:0", "--then-sigma", "0.05",
          "--out", str(out), "--paths", str(paths)])  # fmt: skip
    data = json.loads(out.read_text())
    assert data["then_search"] == [[0.0, 0.05], [0.0, 0.0]] and data["then_sigma"] == 0.05
    first, last = data["clips"]["walk"]["then_search"]
    assert 0.0 < first["torque_body_weight_metres"]["max"] <= 0.05 + 1e-9
    assert last["force_cap"] == last["torque_cap"] == 0.0 and last["force_body_weights"]["max"] == 0.0
    assert "torque_body_weight_metres" not in last and "kept" in last["polished"]
    saved = np.load(paths)
    assert set(saved.files) == {f"walk/{k}" for k in ("start_state", "searched", "polished", "then_search_0",
                                                       "then_search_1")}  # fmt: skip
    humanoid = Humanoid()
    library = load_motions(["walk"], humanoid)
    ev = EvalConfig(starts_per_clip=1, max_frames=6, threads=1)
    states = replay(humanoid, saved["walk/start_state"], saved["walk/then_search_1"])
    got = judge(humanoid, states, reference_frames(library, 0, 6)[1:], ev)
    assert got["mpjpe_g"] == last["polished"]["mpjpe_g"] and got["fell_at"] == last["polished"]["fell_at"]
    # Started again from the first stage's saved path, judged with its own law, it is where that stage ended.
    again = tmp_path / "again.json"
    main(["--config", "configs/samcon/debug.yaml", "--motions", "walk", "--set", "polish.search=false",
          "--cap", "0", "--torque-cap", "0.05", "--start-path", f"{paths}:then_search_0", "--then-search", "0:0",
          "--out", str(again)])  # fmt: skip
    row = json.loads(again.read_text())["clips"]["walk"]
    assert row["given"] == {k: first["polished"][k] for k in ("mpjpe_g", "mpjpe_l", "fell_at")}
    assert "searched" not in row and len(row["then_search"]) == 1
    with pytest.raises(SystemExit, match="walk/nope"):
        main(["--config", "configs/samcon/debug.yaml", "--motions", "walk", "--set", "polish.search=false",
              "--start-path", f"{paths}:nope", "--then-search", "0:0"])  # fmt: skip


def test_command_takes_the_couple_away_inside_the_polish(tmp_path: Path) -> None:
    """--then-couple: the torque-assisted path's couple polished as a control at a cheap and then a dear weight, then
    the path without it. Each couple stage replays, its couple held, to the figures reported; the dear weight leaves
    almost no couple; the last path replays without any force to its figures."""
    out, paths = tmp_path / "assist.json", tmp_path / "paths.npz"
    main(["--config", "configs/samcon/debug.yaml", "--motions", "walk", "--set", "polish.search=false",
          "--cap", "0", "--torque-cap", "0.2", "--then-couple", "1e-4", "1", "--out", str(out),
          "--paths", str(paths)])  # fmt: skip
    data = json.loads(out.read_text())
    row = data["clips"]["walk"]
    assert data["then_couple"] == [1e-4, 1.0] and [t["weight"] for t in row["then_couple"]] == [1e-4, 1.0]
    cheap, dear = (t["torque_body_weight_metres"]["mean"] for t in row["then_couple"])
    assert dear < 1e-3 * cheap
    saved = np.load(paths)
    assert {"walk/then_couple_0", "walk/then_couple_1_couple", "walk/unassisted"} <= set(saved.files)
    humanoid = Humanoid()
    library = load_motions(["walk"], humanoid)
    ev = EvalConfig(starts_per_clip=1, max_frames=6, threads=1)
    ref = reference_frames(library, 0, 6)[1:]
    start = saved["walk/start_state"]
    for i, stage in enumerate(row["then_couple"]):
        law = Couple(saved[f"walk/then_couple_{i}_couple"], stage["weight"]).law(humanoid.nv)
        states, _ = assisted_replay(humanoid, start, saved[f"walk/then_couple_{i}"], law)
        assert judge(humanoid, states, ref, ev)["mpjpe_g"] == stage["mpjpe_g"]
    got = judge(humanoid, replay(humanoid, start, saved["walk/unassisted"]), ref, ev)
    assert got["mpjpe_g"] == row["unassisted"]["mpjpe_g"] and got["fell_at"] == row["unassisted"]["fell_at"]
    # --polish-again from that saved unassisted path: judged as it was, then polished once more without help.
    again, again_paths = tmp_path / "again.json", tmp_path / "again.npz"
    main(["--config", "configs/samcon/debug.yaml", "--motions", "walk", "--set", "polish.search=false", "--cap", "0",
          "--torque-cap", "0", "--start-path", f"{paths}:unassisted", "--polish-again", "1", "--out", str(again),
          "--paths", str(again_paths)])  # fmt: skip
    row2 = json.loads(again.read_text())["clips"]["walk"]
    assert row2["given"] == {k: row["unassisted"][k] for k in ("mpjpe_g", "mpjpe_l", "fell_at")}
    assert len(row2["unassisted_rounds"]) == 1 and "then_couple" not in row2
    got = judge(humanoid, replay(humanoid, start, np.load(again_paths)["walk/unassisted"]), ref, ev)
    assert got["mpjpe_g"] == row2["unassisted"]["mpjpe_g"]


def test_paths_are_written_after_every_stage(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A run stopped in its last stage (here the polish without the couple raises) keeps the stages before it in
    --paths: the searched, polished and couple stages."""
    import studies.samcon.assist as A

    def stop(*args, **kwargs):  # the module's own polish is the unassisted one (the couple's is polish_couple)
        raise RuntimeError("stopped")

    monkeypatch.setattr(A, "polish", stop)
    paths = tmp_path / "paths.npz"
    with pytest.raises(RuntimeError, match="stopped"):
        main(["--config", "configs/samcon/debug.yaml", "--motions", "walk", "--set", "polish.search=false",
              "--cap", "0", "--torque-cap", "0.2", "--then-couple", "1e-4", "--paths", str(paths)])  # fmt: skip
    assert set(np.load(paths).files) == {f"walk/{k}" for k in ("start_state", "searched", "polished", "then_couple_0",
                                                               "then_couple_0_couple")}  # fmt: skip


@pytest.mark.parametrize(
    ("args", "message"),
    [(["--motions", "nosuchclip"], "nosuchclip"), (["--cap", "-1"], "cap"), (["--set", "search.bogus=1"], "bogus"),
     (["--torque-cap", "-0.1"], "torque"), (["--set", "polish.search=true"], "polish.search"),
     (["--set", "polish.iterations=0", "--then-caps", "0"], "--then-caps"),
     (["--then-search", "0.1"], "FORCE_CAP:TORQUE_CAP"), (["--then-search", "0:-1"], ">= 0"),
     (["--then-search", "0:0", "--then-sigma", "0"], "--then-sigma"),
     (["--start-path", "a.npz:polished"], "--start-path needs --then-search"),
     (["--cap", "0", "--then-couple", "0"], "weights > 0"), (["--cap", "0.5", "--then-couple", "1e-3"], "force cap"),
     (["--cap", "0", "--then-search", "0.1:0", "--then-couple", "1e-3"], "force cap"),
     (["--cap", "0", "--torque-cap", "0.1", "--polish-again", "1"], "--polish-again polishes an unassisted path")],
)  # fmt: skip
def test_bad_input_is_refused_in_one_line(args: list[str], message: str, tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--config", "configs/samcon/debug.yaml", "--set", "polish.search=false", *args, "--out",
              str(tmp_path / "a.json")])  # fmt: skip
    text = str(exit_info.value.code)
    assert text.startswith("error: ") and message in text and "\n" not in text
    assert not (tmp_path / "a.json").exists()


def _prediction_errors(humanoid: Humanoid, law: RootAssist, start: np.ndarray, targets: np.ndarray, pos_dof: int,
                       vel_dof: int) -> tuple[float, float]:  # fmt: skip
    """One step from ``start`` moved 1e-3 along tangent coordinate ``pos_dof`` and 1e-2 along velocity ``vel_dof``,
    simulated with ``law``, against A dx from the linearisation with the law's Jacobian and with its forces held
    (no Jacobian): the two prediction errors relative to the simulated change."""
    m = humanoid.model
    nominal = nominal_states(humanoid, start, targets, law)
    dx = np.zeros(2 * m.nv)
    dx[pos_dof], dx[m.nv + vel_dof] = 1e-3, 1e-2
    moved = start.copy()
    qpos = moved[1 : 1 + m.nq]
    mujoco.mj_integratePos(m, qpos, dx[: m.nv], 1.0)
    moved[1 + m.nq : 1 + m.nq + m.nv] += dx[m.nv :]
    after = nominal_states(humanoid, moved, targets, law)[1]
    change = np.zeros(2 * m.nv)
    mujoco.mj_differentiatePos(m, change[: m.nv], 1.0, nominal[1, 1 : 1 + m.nq], after[1 : 1 + m.nq])
    change[m.nv :] = after[1 + m.nq :] - nominal[1, 1 + m.nq :]
    a, _ = linearise(humanoid, nominal, targets, 1e-6, law)
    a_held, _ = linearise(humanoid, nominal, targets, 1e-6, HeldForces(law(0, start[None, 1 : 1 + m.nq],
                                                                           start[None, 1 + m.nq :])))  # fmt: skip
    size = np.linalg.norm(change)
    return float(np.linalg.norm(a[0] @ dx - change) / size), float(np.linalg.norm(a_held[0] @ dx - change) / size)


@pytest.mark.parametrize("cap", [5.0, 0.05])
def test_the_linearisation_counts_the_laws_dependence_on_the_state(walk, cap: float) -> None:
    """A step from a state moved 1 mm ahead and 1 cm/s sideways, simulated with the law, against A dx: with the
    law's Jacobian (unclipped, and clipped at 0.05 body weights) the prediction holds; without it, it does not (by a
    factor 10^4 unclipped, 20 clipped, where only the sideways part of the pull changes)."""
    humanoid, library = walk
    m = humanoid.model
    law = RootAssist(humanoid, library, 0, 10, AssistConfig(kp=100.0, kd=20.0, cap=cap, step=2))
    ref = reference_frames(library, 0, 10)
    start = start_state(library, humanoid, 0)
    start[1] += 0.03  # 3 cm off the reference: the law pulls with 0.31 body weights, clipped at 0.05 or not at 5
    targets = ref.qpos[1:2, humanoid.hinge_qpos]
    assert (
        np.linalg.norm(law(0, start[None, 1 : 1 + m.nq], start[None, 1 + m.nq :])) < 0.3 * body_weight(humanoid)
    ) == (cap < 1.0)
    err, err_held = _prediction_errors(humanoid, law, start, targets, pos_dof=0, vel_dof=1)
    assert err < 0.05 and err_held > 4 * err


def test_the_root_torque_by_hand_and_in_its_frames(walk) -> None:
    """The torque's PD in the world frame, given in the root's frame: a root yawed 0.1 rad past the reference is
    turned back by kp 0.1 about world z; an angular velocity 0.5 rad/s too fast about the root's own z is braked by
    kd 0.5 about it; a large error is capped at torque_cap m |g| x 1 m; with no torque_cap nothing changes."""
    humanoid, library = walk
    weight = body_weight(humanoid)
    ref = reference_frames(library, 0, 40)
    f = 20
    law = RootAssist(humanoid, library, 0, 30, AssistConfig(cap=0.0, step=2, torque_cap=5.0, torque_kp=1000.0,
                                                             torque_kd=100.0))  # fmt: skip
    qpos, qvel = ref.qpos[[f, f]].copy(), ref.qvel[[f, f]].copy()
    qpos[0, 3:7] = quat_mul(quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), 0.1), qpos[0, 3:7])  # world yaw
    qvel[0, 3:6] = quat_rotate_inv(qpos[0, 3:7], quat_rotate(ref.qpos[f, 3:7], ref.qvel[f, 3:6]))  # same world w
    qvel[1, 5] += 0.5  # root frame
    out = law(f, qpos, qvel)
    assert not out[:, 0:3].any() and not out[:, 6:].any()
    np.testing.assert_allclose(quat_rotate(qpos[0, 3:7], out[0, 3:6]), [0.0, 0.0, -100.0], atol=1e-9)
    np.testing.assert_allclose(out[1, 3:6], [0.0, 0.0, -50.0], atol=1e-9)
    far = qpos[:1].copy()
    far[0, 3:7] = quat_mul(quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), 2.0), ref.qpos[f, 3:7])
    capped = RootAssist(humanoid, library, 0, 30, AssistConfig(cap=0.0, step=2, torque_cap=0.2))(f, far, qvel[:1])
    assert np.linalg.norm(capped[0, 3:6]) == pytest.approx(0.2 * weight, rel=1e-12)
    plain = RootAssist(humanoid, library, 0, 30, AssistConfig(cap=0.5, step=2))
    assert not plain(f, qpos, qvel)[:, 3:].any() and not plain.jacobian(f, qpos, qvel)[:, 3:].any()


def test_the_root_torque_turns_the_body_as_a_couple(walk) -> None:
    """In the air, tilted 90 degrees so that the root's frame is not the world's, the torque changes the whole body's
    angular momentum about its centre of mass (MuJoCo's subtree_angmom) by the world torque times the time, and its
    centre of mass's velocity not at all: a couple, in the frame MuJoCo's free joint takes it in."""
    humanoid, library = walk
    m = humanoid.model
    pose = library.frames.qpos[0].copy()
    pose[2] += 1.0
    pose[3:7] = quat_mul(quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), np.pi / 2), pose[3:7])
    tau_world = np.array([3.0, -2.0, 5.0])
    applied = np.zeros((1, humanoid.nv))
    applied[0, 3:6] = quat_rotate_inv(pose[3:7], tau_world)
    sim = BatchedSim(humanoid, 1, threads=0, applied=True)
    d = mujoco.MjData(m)

    def momentum(qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d.qpos[:], d.qvel[:] = qpos, qvel
        mujoco.mj_forward(m, d)
        mujoco.mj_subtreeVel(m, d)
        return d.subtree_angmom[1].copy(), d.subtree_linvel[1].copy()

    try:
        sim.set_state(np.arange(1), pose[None], np.zeros((1, humanoid.nv)))
        before = momentum(sim.qpos[0], sim.qvel[0])
        sim.step(pose[None, humanoid.hinge_qpos], applied)
        after = momentum(sim.qpos[0], sim.qvel[0])
    finally:
        sim.close()
    dt = humanoid.physics.control_dt
    # Held in the root's frame over the step, the couple turns with the body a little (<1e-3 rad): 1% tolerance.
    np.testing.assert_allclose(after[0] - before[0], tau_world * dt, rtol=0.01, atol=1e-4)
    np.testing.assert_allclose(after[1] - before[1], np.asarray(m.opt.gravity) * dt, atol=1e-5)  # a 5 N force: 2e-3


def test_the_linearisation_counts_the_torques_dependence_on_the_state(walk) -> None:
    """As for the force: a step from a state turned 1 mrad about the root's x and 1 cm/s faster about its z, simulated
    with the torque law, against A dx, with the law's (central-difference) Jacobian and without it."""
    humanoid, library = walk
    law = RootAssist(humanoid, library, 0, 10, AssistConfig(cap=0.0, step=2, torque_cap=5.0))
    ref = reference_frames(library, 0, 10)
    start = start_state(library, humanoid, 0)
    targets = ref.qpos[1:2, humanoid.hinge_qpos]
    err, err_held = _prediction_errors(humanoid, law, start, targets, pos_dof=3, vel_dof=5)
    assert err < 0.05 and err_held > 4 * err
