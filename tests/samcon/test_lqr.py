"""Time-varying LQR around SAMCON paths: the Riccati recursion, the linearisation against rollouts, the policy's
replay, path choice and loop transform, and the run directory."""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import EvalConfig, evaluate
from common.motion.dataset import load_motions
from common.sim.gym import GymConfig, TrackingGym
from common.sim.physics import BatchedSim
from samcon.config import LqrConfig
from samcon.lqr import LqrPath, LqrPolicy, linearise, nominal_states, riccati, stabilise

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def walk() -> tuple[Humanoid, object]:
    humanoid = Humanoid()
    return humanoid, load_motions(["walk"], humanoid)


def _start_and_reference_targets(humanoid: Humanoid, library, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """The gym's start state at t = 0 (as the evaluator resets) and the reference's next-frame angles."""
    gym = TrackingGym(GymConfig(num_envs=1, threads=1, physics=humanoid.physics), library, humanoid)
    try:
        gym.reset(clips=np.array([0]), times=np.array([0.0]))
        start = gym.sim.state[0].copy()
    finally:
        gym.close()
    times = (np.arange(frames) + 1) * library.dt
    targets = library.query(np.zeros(frames, dtype=np.int64), times).qpos[:, humanoid.hinge_qpos]
    return start, targets


def test_riccati_reaches_the_scalar_algebraic_solution() -> None:
    """x' = x + u, cost x^2 + u^2: the stationary P solves P = 1 + P - P^2 / (1 + P), i.e. P^2 = P + 1, the golden
    ratio, and K = -P / (1 + P) = -1 / phi (worked out by hand)."""
    frames = 60
    a, b = np.ones((frames, 1, 1)), np.ones((frames, 1, 1))
    gain, cost = riccati(a, b, np.eye(1), np.eye(1), np.eye(1))
    phi = (1 + 5**0.5) / 2
    assert cost[0, 0, 0] == pytest.approx(phi, rel=1e-12)
    assert gain[0, 0, 0] == pytest.approx(-1 / phi, rel=1e-12)
    # The last step from P_end = 1: K = -1 / 2, P = 1 + 1 - 1 / 2.
    assert gain[-1, 0, 0] == pytest.approx(-0.5) and cost[-1, 0, 0] == pytest.approx(1.5)


def test_linearisation_predicts_a_rollout_of_a_control_step(walk) -> None:
    """Off the floor (no contact changes), A dx + B du is the tangent deviation a control step of the gym's own
    rollout produces from a perturbed state and target (an independent computation: BatchedSim, not mjd_*)."""
    humanoid, library = walk
    m = humanoid.model
    start, targets = _start_and_reference_targets(humanoid, library, 1)
    start = start.copy()
    start[1 + 2] += 1.0  # the root 1 m up: in the air for the step
    states = nominal_states(humanoid, start, targets)
    a, b = linearise(humanoid, states, targets, 1e-6)
    rng = np.random.default_rng(0)
    dx = rng.normal(size=2 * m.nv) * 1e-5
    du = rng.normal(size=m.nu) * 1e-5
    sim = BatchedSim(humanoid, 1, threads=0)
    try:
        sim.state[0] = start
        qpos = sim.state[0, 1 : 1 + m.nq].copy()
        mujoco.mj_integratePos(m, qpos, dx[: m.nv], 1.0)
        sim.state[0, 1 : 1 + m.nq] = qpos
        sim.state[0, 1 + m.nq : 1 + m.nq + m.nv] += dx[m.nv :]
        sim.step(targets + du)
        out = sim.state[0]
    finally:
        sim.close()
    dq = np.zeros(m.nv)
    mujoco.mj_differentiatePos(m, dq, 1.0, states[1, 1 : 1 + m.nq], out[1 : 1 + m.nq])
    measured = np.concatenate([dq, out[1 + m.nq : 1 + m.nq + m.nv] - states[1, 1 + m.nq : 1 + m.nq + m.nv]])
    predicted = a[0] @ dx + b[0] @ du
    assert np.linalg.norm(predicted) > 1e-6  # a real response, not zero against zero
    np.testing.assert_allclose(predicted, measured, atol=1e-4 * np.abs(measured).max())


def test_a_force_response_does_not_depend_on_what_its_scratch_data_did_before() -> None:
    """The root force's central differences reuse one MjData; the solver's warm start is not part of the saved state,
    so the scratch data's history used to reach the result (roll, lying on the floor, 300 N up at the root: by 5e-14
    of 5.5e-4, which the polish's iterations amplified). Now a used MjData gives the fresh one's result bit for bit."""
    from samcon.lqr import force_response
    from samcon.search import reference_frames, start_state

    humanoid = Humanoid()
    library = load_motions(["roll"], humanoid)
    m = humanoid.model
    targets = reference_frames(library, 0, 6).qpos[1:, humanoid.hinge_qpos]
    states = nominal_states(humanoid, start_state(library, humanoid, 0), targets)
    force = np.zeros(m.nv)
    force[2] = 300.0
    fresh = force_response(humanoid, mujoco.MjData(m), states[3], targets[3], force, 2)
    used = mujoco.MjData(m)
    force_response(humanoid, used, states[1], targets[1], force, 0)  # leaves its warm start behind
    np.testing.assert_array_equal(force_response(humanoid, used, states[3], targets[3], force, 2), fresh)
    assert np.abs(fresh).max() > 1e-4


def test_policy_replays_its_path_bit_exactly_from_the_clip_start(walk) -> None:
    """On the path's own states the deviation is exactly zero, so the LQR policy plays the path's targets: the
    evaluator's episode from t = 0 scores exactly as the open-loop targets do."""
    humanoid, library = walk
    start, targets = _start_and_reference_targets(humanoid, library, 12)
    path = stabilise(humanoid, start, targets, 0, LqrConfig())
    assert np.abs(path.gain).max() > 0  # real feedback that stays silent on the path

    def open_loop(result):
        return targets[np.rint(result.time / library.dt).astype(int)]

    ev = EvalConfig(starts_per_clip=1, max_frames=12, threads=1)
    lqr = evaluate(LqrPolicy({"walk": [path]}, {"walk": 0.5}, library, humanoid, open_loop), library, humanoid, ev)
    plain = evaluate(open_loop, library, humanoid, ev)
    for key in ("mpjpe_g", "mpjpe_l", "joint_vel_err"):
        assert lqr.overall[key] == plain.overall[key], key


def test_the_policy_follows_the_path_of_least_cost_to_go(walk) -> None:
    """Two paths over the same frames: a character on the second one's state is steered by the second (zero
    deviation, zero cost-to-go), whatever the first's gains would do."""
    humanoid, library = walk
    m = humanoid.model
    n = 2 * m.nv
    qpos = np.tile(library.query(np.array([0]), np.array([0.0])).qpos, (3, 1))
    other = qpos.copy()
    other[:, 7:] += 0.1

    def path(q: np.ndarray, target: float) -> LqrPath:
        return LqrPath(0, np.full((3, m.nu), target), q, np.zeros((3, m.nv)), np.ones((3, m.nu, n), np.float32),
                       np.tile(np.eye(n, dtype=np.float32), (3, 1, 1)))  # fmt: skip

    policy = LqrPolicy({"walk": [path(qpos, 1.0), path(other, 2.0)]}, {"walk": 0.5}, library, humanoid, None)
    u, j, v = policy.control("walk", 1, other[1], np.zeros(m.nv))
    assert j == 1 and v == 0.0 and np.array_equal(u, np.full(m.nu, 2.0))
    u, j, v = policy.control("walk", 1, qpos[1], np.zeros(m.nv))
    assert j == 0 and np.array_equal(u, np.full(m.nu, 1.0))
    # Halfway (a tie: the first), K dx = 28 hinges x 0.05 rad = 1.4 is clipped to the limit 0.5.
    u, j, _ = policy.control("walk", 1, 0.5 * (qpos[1] + other[1]), np.zeros(m.nv))
    assert j == 0 and np.allclose(u, 1.5)


def test_a_later_cycle_maps_onto_the_path_by_the_reference_cycle_transform(walk) -> None:
    """Past the path's end, a loop clip's frame goes back whole cycles, and the reference state there, moved by the
    yaw and shift between the two reference roots, is the reference at the earlier frame (position, rotation and
    world-frame linear velocity; the root-frame angular velocity is unchanged)."""
    humanoid, library = walk
    cycle = int(round(library.duration[0] / library.dt))
    path = LqrPath(0, np.zeros((100, humanoid.nu)), np.zeros((100, humanoid.model.nq)),
                   np.zeros((100, humanoid.model.nv)), np.zeros((100, humanoid.nu, 2)),
                   np.zeros((100, 2, 2)))  # fmt: skip
    policy = LqrPolicy({"walk": [path]}, {"walk": 0.5}, library, humanoid, None)
    f = 100 + 2 * cycle + 5
    g = policy.frame_used("walk", 0, f)
    assert g == f - (int(np.ceil((f - 100 + 1) / cycle))) * cycle and 0 <= g < 100
    late, early = (library.query(np.array([0]), np.array([x * library.dt])) for x in (f, g))
    qpos, qvel = policy.moved(0, late.qpos[0], late.qvel[0], late.qpos[0], g)
    np.testing.assert_allclose(qpos[:3], early.qpos[0, :3], atol=1e-6)
    dot = abs(float(np.dot(qpos[3:7], early.qpos[0, 3:7])))
    assert dot == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_allclose(qpos[7:], early.qpos[0, 7:], atol=1e-6)
    np.testing.assert_allclose(qvel[:3], early.qvel[0, :3], atol=1e-4)
    np.testing.assert_allclose(qvel[3:], late.qvel[0, 3:])


def test_lqr_run_stores_its_paths_and_the_report_judges_them(tmp_path: Path) -> None:
    """``lqr.enabled`` on the debug config: samcon.h5 holds the main path's gains (as used), results.json the LQR's
    and the regressed policy's figures, and compare-trackers scores the LQR policy as the run did."""
    from report.compare import build_report
    from samcon import store
    from samcon.track import main

    out = tmp_path / "run"
    main(["--config", str(ROOT / "configs/samcon/debug.yaml"), "--out", str(out), "--set", "lqr.enabled=true",
          "--set", "lqr.visit_rounds=1", "--set", "lqr.visit_episodes=2", "--set", "lqr.visit_frames=6",
          "--set", "lqr.visit_segments=1", "--set", "lqr.visit_lead=0", "--set", "optimise.generations=0"])  # fmt: skip
    humanoid = Humanoid()
    plans, _ = store.load_plans(out / "samcon.h5", humanoid.physics.control_hz)
    plan = plans["walk"]
    assert plan.lqr_limit == 0.5 and plan.lqr[0].first == 0
    main_path = plan.lqr[0]
    assert np.array_equal(main_path.targets, plan.targets) and main_path.gain.dtype == np.float32
    assert main_path.gain.shape == (6, humanoid.nu, 2 * humanoid.model.nv)
    # The debug config's search from frame 3 (feedback.starts: 1) is the second path; in 6 frames nothing falls, so
    # no recovery path.
    assert len(plan.lqr) == 2 and plan.lqr[1].first == 3 and len(plan.lqr[1].targets) == 3
    assert plan.lqr[1].cost_to_go.shape == (3, 2 * humanoid.model.nv, 2 * humanoid.model.nv)
    results = json.loads((out / "results.json").read_text())
    row = results["clips"]["walk"]
    assert row["lqr"]["paths"] == len(plan.lqr) and len(row["lqr"]["visits"]) == 1
    assert {"feedback", "feedback_regressed"} <= set(row)
    report = build_report([out], tmp_path / "report", max_frames=6, do_render=False)
    # The report's judge replays the stored paths and gains: the numbers the run measured.
    assert report.results[0].per_clip["mpjpe_g"][0] == pytest.approx(row["feedback"]["mpjpe_g"], rel=1e-12)


def test_a_clips_only_path_is_stored_without_its_cost_to_go(tmp_path: Path) -> None:
    from samcon import store
    from samcon.track import main

    out = tmp_path / "run"
    main(["--config", str(ROOT / "configs/samcon/debug.yaml"), "--out", str(out), "--set", "feedback.starts=0",
          "--set", "optimise.generations=0", "--set", "feedback.visit_iterations=0"])  # fmt: skip
    plans, _ = store.load_plans(out / "samcon.h5", Humanoid().physics.control_hz)
    (path,) = plans["walk"].lqr
    assert path.cost_to_go is None and path.gain.shape[0] == 6
    results = json.loads((out / "results.json").read_text())["clips"]["walk"]
    again = evaluate(load_eval_policy_of(out), load_motions(["walk"], Humanoid()), Humanoid(),
                     EvalConfig(starts_per_clip=2, max_frames=6, threads=1))  # fmt: skip
    assert again.overall["mpjpe_g"] == pytest.approx(results["feedback"]["mpjpe_g"], rel=1e-12)


def load_eval_policy_of(run: Path):
    from samcon.export import load_eval_policy

    humanoid = Humanoid()
    return load_eval_policy(run, run / "samcon.h5", humanoid, load_motions(["walk"], humanoid))


def test_bad_lqr_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="weights"):
        LqrConfig(hinge=-1.0)
    with pytest.raises(ValueError, match="eps, control and limit"):
        LqrConfig(limit=0.0)
    with pytest.raises(ValueError, match="visit_lead"):
        LqrConfig(visit_lead=-1)


def test_lqr_walk_config_is_the_default_but_for_its_paths() -> None:
    from dataclasses import asdict

    from common.config import load_config
    from samcon.config import SamconConfig

    default = asdict(load_config(SamconConfig, str(ROOT / "configs/samcon/default.yaml"), []))
    walk = asdict(load_config(SamconConfig, str(ROOT / "configs/samcon/lqr-walk.yaml"), []))
    changed = {(sec, k) for sec in default for k in default[sec] if default[sec][k] != walk[sec][k]}
    assert changed == {("train", "eval"), ("search", "sigma_init"), ("feedback", "starts")}
    assert walk["lqr"]["enabled"] and walk["feedback"]["starts"] == 12 and walk["search"]["sigma_init"] == 0.1
