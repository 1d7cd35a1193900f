"""The iLQR polish of SAMCON paths: the backward pass against the quadratic programme it solves, the body cost's
derivatives against finite differences through MuJoCo's own kinematics, and a polish that replays."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from samcon.config import LqrConfig, PolishConfig
from samcon.lqr import linearise, nominal_states, riccati, state_weights
from samcon.polish import BodyCost, Follow, backward_pass, deviation, polish, window_rollout
from samcon.search import reference_frames, start_state


@pytest.fixture(scope="module")
def walk() -> tuple[Humanoid, object]:
    humanoid = Humanoid()
    return humanoid, load_motions(["walk"], humanoid)


class _Pushed:
    """An external force that changes over the path but not with the state: ``forces[f]`` at frame f (F, nv)."""

    def __init__(self, forces: np.ndarray) -> None:
        self.forces = forces

    def __call__(self, frame: int, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        return np.tile(self.forces[frame], (len(qpos), 1))

    def jacobian(self, frame: int, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        return np.zeros((len(qpos), self.forces.shape[1], 2 * self.forces.shape[1]))


def _qp_solution(a, b, lx, lxx, lu, luu, free):
    """The same problem written out as one quadratic programme in the free controls: dx = G du stacked from
    dx_0 = 0, cost sum lx.dx + dx^T lxx dx / 2 + lu.du + luu |du|^2 / 2, minimised by a linear solve."""
    frames, n, nu = b.shape
    g = np.zeros((frames, n, frames * nu))  # dx_{t+1} = g[t] @ du
    prev = np.zeros((n, frames * nu))
    for t in range(frames):
        cur = a[t] @ prev
        cur[:, t * nu : (t + 1) * nu] += b[t]
        g[t], prev = cur, cur
    cols = np.arange(free * nu)
    h = sum(g[t][:, cols].T @ lxx[t] @ g[t][:, cols] for t in range(frames)) + luu * np.eye(len(cols))
    grad = sum(g[t][:, cols].T @ lx[t] for t in range(frames)) + lu[:free].ravel()
    du = -np.linalg.solve(h, grad)
    return du.reshape(free, nu), float(grad @ du + 0.5 * du @ h @ du)


@pytest.mark.parametrize("free", [None, 3])
def test_backward_pass_solves_the_quadratic_programme(free) -> None:
    """On a linear system with a quadratic cost one step (alpha 1, mu 0: ``du_t = k_t + K_t dx_t`` rolled out from
    dx_0 = 0) is the programme's exact minimiser, and the predicted change d1 + d2 is its optimal value; with
    ``free`` the later controls stay put."""
    rng = np.random.default_rng(0)
    frames, n, nu = 6, 4, 2
    a = np.eye(n) + 0.3 * rng.standard_normal((frames, n, n))
    b = rng.standard_normal((frames, n, nu))
    lx = rng.standard_normal((frames, n))
    m = rng.standard_normal((frames, n, n))
    lxx = m @ m.transpose(0, 2, 1) + 0.1 * np.eye(n)
    lu = rng.standard_normal((frames, nu))
    k, gain, d1, d2 = backward_pass(a, b, lx, lxx, lu, 0.5, 0.0, free)
    used = frames if free is None else free
    du, value = _qp_solution(a, b, lx, lxx, lu, 0.5, used)
    dx, applied = np.zeros(n), np.zeros((frames, nu))
    for t in range(frames):
        applied[t] = k[t] + gain[t] @ dx
        dx = a[t] @ dx + b[t] @ applied[t]
    np.testing.assert_allclose(applied[:used], du, rtol=1e-9, atol=1e-10)
    assert np.allclose(k[0], du[0])
    assert d1 + d2 == pytest.approx(value, rel=1e-9)
    assert not k[used:].any() and not gain[used:].any()


def test_body_cost_derivatives_match_finite_differences(walk) -> None:
    """The gradient of the state cost in the tangent space (root rotation as an angular vector in the root frame,
    as mj_integratePos moves it) against centred differences of the cost computed by ForwardKinematics (the
    judge's body positions), at a state off the reference."""
    humanoid, library = walk
    m = humanoid.model
    cfg = PolishConfig(iterations=1, body=100.0, velocity=0.01, root_velocity=0.5)
    ref = reference_frames(library, 0, 4)
    cost = BodyCost(humanoid, cfg, ref, ref.qpos[1:, humanoid.hinge_qpos], 0.25)
    try:
        state = start_state(library, humanoid, 0)
        rng = np.random.default_rng(1)
        qpos = state[1 : 1 + m.nq].copy()
        mujoco.mj_integratePos(m, qpos, 0.1 * rng.standard_normal(m.nv), 1.0)
        state[1 : 1 + m.nq] = qpos
        state[1 + m.nq : 1 + m.nq + m.nv] += 0.3 * rng.standard_normal(m.nv)
        grad, hess = cost.state_derivatives(state, 2)

        def value(x: np.ndarray) -> float:
            # path_cost of a one-step path whose state after the step is x, at frame 2; control cost 0 by design
            states = np.stack([x, x])
            targets = ref.qpos[2:3, humanoid.hinge_qpos]
            return cost.path_cost(states, targets, 1).total

        h = 1e-6
        fd = np.zeros(2 * m.nv)
        for i in range(2 * m.nv):
            plus, minus = state.copy(), state.copy()
            if i < m.nv:
                for x, sign in ((plus, 1.0), (minus, -1.0)):
                    q = x[1 : 1 + m.nq].copy()
                    step = np.zeros(m.nv)
                    step[i] = sign * h
                    mujoco.mj_integratePos(m, q, step, 1.0)
                    x[1 : 1 + m.nq] = q
            else:
                plus[1 + m.nq + i - m.nv] += h
                minus[1 + m.nq + i - m.nv] -= h
            fd[i] = (value(plus) - value(minus)) / (2 * h)
        np.testing.assert_allclose(grad, fd, rtol=1e-4, atol=1e-6)
        assert np.all(np.linalg.eigvalsh(hess) >= -1e-9)  # Gauss-Newton: positive semidefinite
    finally:
        cost.close()


@pytest.mark.parametrize("pushed, follow", [(False, False), (True, False), (False, True), (True, True)])
def test_polish_lowers_the_cost_and_replays(walk, pushed: bool, follow: bool) -> None:
    """From the reference's own targets (open-loop playback) on walk's first 24 frames, two windows of iLQR and two
    iterations on the whole path lower the body error, and the targets returned replay to the cost the polish
    reports; with an external force on the root, replayed with the same force; with ``follow`` (look-aheads played by
    the path's LQR) too."""
    humanoid, library = walk
    frames = 24
    ref = reference_frames(library, 0, frames)
    ref_targets = ref.qpos[1:, humanoid.hinge_qpos]
    start = start_state(library, humanoid, 0)
    force = None
    if pushed:  # a root force changing over the path: 150 N up and a sideways swing of 80 N
        forces = np.zeros((frames, humanoid.nv))
        forces[:, 1], forces[:, 2] = 80.0 * np.sin(np.arange(frames) / 4.0), 150.0
        force = _Pushed(forces)
    cfg = PolishConfig(iterations=3, window=16, stride=8, lookahead=4, whole_iterations=2, follow=follow)
    targets, summary = polish(humanoid, start, ref_targets, ref, ref_targets, cfg, 0.25, force=force,
                              lqr=LqrConfig() if follow else None)  # fmt: skip
    assert summary["kept"] and summary["cost_after"] < summary["cost_before"]
    # the window pass, then the whole path from its result: never dearer than the pass it started from
    assert summary["passes"][-1]["whole_steps"] <= 2 and summary["cost_after"] <= summary["passes"][0]["cost"]
    assert [w["first"] for w in summary["windows"]] == [0, 8]
    assert not np.array_equal(targets, ref_targets)
    cost = BodyCost(humanoid, cfg, ref, ref_targets, 0.25)
    try:
        replayed = cost.path_cost(nominal_states(humanoid, start, targets, force), targets, 0)
        plain = cost.path_cost(nominal_states(humanoid, start, targets), targets, 0)
    finally:
        cost.close()
    assert replayed.total == summary["cost_after"]
    assert replayed.fell_at == -1
    assert (plain.total == replayed.total) == (not pushed)  # the forces were applied, not ignored


def test_a_pass_that_would_repeat_a_dropped_one_is_skipped(walk, monkeypatch) -> None:
    """Two more passes with the same settings after a dropped one would start from the same path and do the same:
    they are skipped, not run."""
    import samcon.polish as P

    humanoid, library = walk
    ref = reference_frames(library, 0, 8)
    ref_targets = ref.qpos[1:, humanoid.hinge_qpos]
    calls = []

    def worse(humanoid, cost, start, targets, *args, **kwargs):  # a pass that ends dearer than it started
        calls.append(1)
        return targets + 0.3, []

    monkeypatch.setattr(P, "_sweep", worse)
    targets, summary = polish(humanoid, start_state(library, humanoid, 0), ref_targets, ref, ref_targets,
                              PolishConfig(iterations=1, window=4, stride=2, passes=3), 0.25)  # fmt: skip
    assert len(calls) == 1 and targets is ref_targets and not summary["kept"]
    assert [p.get("repeat_skipped", False) for p in summary["passes"]] == [False, True, True]


def test_windows_ask_the_searcher_for_the_frames_after_the_last_look_ahead(walk) -> None:
    """With a searcher, each window's frames beyond what earlier windows played start from its answer, asked for
    from the state where the last look-ahead ended (its time field says which frame); None falls back."""
    humanoid, library = walk
    frames = 24
    ref = reference_frames(library, 0, frames)
    ref_targets = ref.qpos[1:, humanoid.hinge_qpos]
    start = start_state(library, humanoid, 0)
    calls = []

    def searcher(first: int, end: int, state: np.ndarray) -> np.ndarray | None:
        calls.append((first, end, round(state[0] / library.dt)))
        return None if first == 16 else ref_targets[first:end]

    cfg = PolishConfig(iterations=1, window=8, stride=4, lookahead=4)
    _, summary = polish(humanoid, start, ref_targets, ref, ref_targets, cfg, 0.25, searcher=searcher)
    assert calls == [(12, 16, 12), (16, 20, 16), (20, 24, 20)]
    assert [w["searched"] for w in summary["windows"]] == [False, True, False, True, False]


def test_a_path_without_a_usable_lqr_is_polished_from_its_targets(walk, monkeypatch) -> None:
    """A path through a blow-up has a singular or non-finite LQR (a continuation that took a root force away met
    one): the windows then start their new frames from the path's targets, and the polish still returns."""
    import samcon.polish as polish_module

    def singular(*args, **kwargs):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setattr(polish_module, "riccati", singular)
    humanoid, library = walk
    ref = reference_frames(library, 0, 24)
    ref_targets = ref.qpos[1:, humanoid.hinge_qpos]
    cfg = PolishConfig(iterations=2, window=16, stride=8, lookahead=4)
    targets, summary = polish(humanoid, start_state(library, humanoid, 0), ref_targets, ref, ref_targets, cfg, 0.25,
                              lqr=LqrConfig())  # fmt: skip
    assert summary["kept"] and summary["cost_after"] < summary["cost_before"] and targets.shape == ref_targets.shape


def test_follow_plays_the_look_ahead_by_the_lqr_and_linearises_its_closed_loop(walk) -> None:
    """``polish.follow``: after a window's changed targets, the look-ahead's targets are the searched path's LQR's
    (``u*_t + clip(K_t (x_t - x*_t))`` from the states reached), the path replays open loop bit for bit, and the
    closed loop ``A + B K`` that the window's iLQR uses predicts how a change of the window's first target carries
    through the look-ahead (centred differences of the rollout), where the open-loop ``A`` does not."""
    humanoid, library = walk
    m = humanoid.model
    frames, free = 12, 4
    ref = reference_frames(library, 0, frames)
    ref_targets = ref.qpos[1:, humanoid.hinge_qpos]
    start = start_state(library, humanoid, 0)
    searched = nominal_states(humanoid, start, ref_targets)
    lqr = LqrConfig()
    a, b = linearise(humanoid, searched, ref_targets, lqr.eps)
    q = np.diag(state_weights(humanoid, lqr))
    follow = Follow(searched, ref_targets, riccati(a, b, q, lqr.control * np.eye(m.nu), q)[0], lqr.limit)
    zeros_k, zeros_gain = np.zeros_like(ref_targets), np.zeros((frames, m.nu, 2 * m.nv))

    def play(first_change: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        base = ref_targets.copy()
        base[:free] += 0.05
        base[0] += first_change
        roll, applied, blown = window_rollout(humanoid, start, searched, base, zeros_k, zeros_gain, np.ones(1), 0, free,
                                     follow, None)  # fmt: skip
        assert not blown.any()
        return roll[0], applied[0]

    states, applied = play(np.zeros(m.nu))
    np.testing.assert_array_equal(applied[:free], ref_targets[:free] + 0.05)
    dq = np.zeros(m.nv)
    nq = m.nq
    for t in range(free, frames):
        mujoco.mj_differentiatePos(m, dq, 1.0, searched[t, 1 : 1 + nq], states[t, 1 : 1 + nq])
        dx = np.concatenate([dq, states[t, 1 + nq : 1 + nq + m.nv] - searched[t, 1 + nq : 1 + nq + m.nv]])
        np.testing.assert_array_equal(deviation(m, searched[t], states[t], np.zeros(m.nv)), dx)
        expected = ref_targets[t] + np.clip(follow.gain[t] @ dx, -lqr.limit, lqr.limit)
        np.testing.assert_allclose(applied[t], expected, rtol=0, atol=1e-12)
    assert not np.allclose(applied[free:], ref_targets[free:])  # the LQR corrected something
    np.testing.assert_array_equal(nominal_states(humanoid, start, applied), states)

    a, b = linearise(humanoid, states, applied, 1e-6)
    closed = a.copy()
    closed[free:] += b[free:] @ follow.effective_gain(humanoid, states[free:frames], free)
    rng = np.random.default_rng(2)
    du = 1e-5 * rng.standard_normal(m.nu)
    ends = []
    for sign in (1.0, -1.0):
        end = play(sign * du)[0][-1]
        mujoco.mj_differentiatePos(m, dq, 1.0, states[-1, 1 : 1 + nq], end[1 : 1 + nq])
        ends.append(np.concatenate([dq, end[1 + nq : 1 + nq + m.nv] - states[-1, 1 + nq : 1 + nq + m.nv]]))
    actual = 0.5 * (ends[0] - ends[1])

    def predicted(jac: np.ndarray) -> np.ndarray:
        dx = b[0] @ du
        for t in range(1, frames):
            dx = jac[t] @ dx
        return dx

    err_closed = np.linalg.norm(predicted(closed) - actual)
    err_open = np.linalg.norm(predicted(a) - actual)
    assert err_closed < 0.05 * np.linalg.norm(actual) < err_open


def test_follow_is_set_per_pass() -> None:
    """``polish.follow`` per pass: each pass's settings say whether it follows and use ``follow_lookahead`` then;
    one bool applies to every pass; a list of the wrong length is refused."""
    cfg = PolishConfig(iterations=1, window=8, stride=4, lookahead=2, passes=2, follow=(False, True),
                       follow_lookahead=6)  # fmt: skip
    first, second = cfg.for_pass(0), cfg.for_pass(1)
    assert (first.follow, first.lookahead) == (False, 2)
    assert (second.follow, second.lookahead) == (True, 6)
    assert [PolishConfig(passes=3, follow=True, lookahead=5).for_pass(p).lookahead for p in range(3)] == [5, 5, 5]
    with pytest.raises(ValueError, match="one value per pass"):
        PolishConfig(passes=2, follow=(True,))


@pytest.mark.parametrize(
    ("settings", "message"),
    [({"window": 8, "stride": 9}, "stride <= window"), ({"body": 0.0}, "body > 0"), ({"eps": 0.0}, "eps > 0"),
     ({"mu_min": 2.0}, "mu_min <= mu_init"), ({"control": -1.0}, "control >= 0")],
)  # fmt: skip
def test_bad_polish_settings_are_refused(settings: dict, message: str) -> None:
    """(These checks sat after a return until session 25 and never ran.)"""
    with pytest.raises(ValueError, match=message):
        PolishConfig(**settings)
