"""Trajectory optimisation after the search: iterative LQR (iLQR) on SAMCON's open-loop path, scored by the judge's
own body-position error.

SAMCON is greedy in time: it keeps, segment by segment, the samples that track that segment (and a 0.2 s look-ahead)
best, so it cannot give up a little now to be much better a second later; where a clip's root swings out and back
(session 17: kick, punch, dance_a) the search follows the swing late and never wins the distance back. iLQR (Li &
Todorov 2004; with the regularisation and line search of Tassa, Erez & Todorov 2012, as MuJoCo MPC's iLQG uses it)
optimises the targets of every frame together from the simulator's own derivatives:

1. **Linearise** the path (:func:`samcon.lqr.linearise`: ``A_t``, ``B_t`` per control step from MuJoCo's
   ``mjd_transitionFD``).
2. **Cost** of the state after control step t: ``polish.body`` x the mean over the 15 bodies of the squared
   distance of the body frame origin from the reference's (the square of the judge's MPJPE-g per body),
   ``polish.velocity`` and ``polish.root_velocity`` x the squared hinge and root velocity errors, and
   ``polish.control`` x the squared offset of the targets from the reference's next-frame hinge angles. Its
   gradient and Gauss-Newton Hessian in the state's tangent space come from MuJoCo's body Jacobians
   (``mj_jacBody``).
3. **Backward pass**: the Riccati-like recursion of iLQR gives an open-loop change ``k_t`` and a feedback ``K_t`` per
   step (``Q_uu`` regularised by ``mu``, raised when it is not positive definite or a step fails).
4. **Forward pass**: ``u_t = u_t + alpha k_t + K_t (x_t' - x_t)`` rolled out in the gym's own physics
   (:class:`common.sim.physics.BatchedSim`, every step size ``alpha`` a character of one batch); the cheapest rollout
   that lowers the true cost and does not fall (the evaluator's head rule) is the new path. Its targets are the
   ones it applied, so the result is again an open-loop path that replays bit-exactly from the clip's start.
5. **Windows** (``polish.window``): over a whole 512-frame path at once the rollouts are too sensitive to the early
   frames' changes (crawl: 92 to 76 mm MPJPE-g, then no step size lowered the cost), so the path is polished in
   windows, each from the state the windows before left, its cost counting ``lookahead`` frames more. Frames no
   window has changed yet start from the searched path tracked by its time-varying LQR (:mod:`samcon.lqr`), or,
   with ``polish.search``, from a SAMCON search from where the last look-ahead left the character: the searched
   path's own open-loop targets, played from a state off it, fall within a second. With ``polish.follow`` a
   window's look-ahead frames are played by that LQR too, in every rollout, and the window's iLQR sees their closed
   loop ``A + B K``: a window is then judged by how the LQR carries on from where it leaves the character, which is
   how the next window's new frames start (:class:`Follow`).

A clip whose reference needs force no contact can give keeps an error there whatever the targets; iLQR spends it
where it costs least over the window instead of where the greedy search left it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, TextIO

import mujoco
import numpy as np

from common.character.humanoid import Humanoid
from common.character.kinematics import ForwardKinematics
from common.character.state import CharacterState
from common.sim.physics import BatchedSim
from samcon.config import CostConfig, LqrConfig, PolishConfig
from samcon.cost import tracking_cost
from samcon.lqr import linearise, nominal_states, riccati, state_weights
from samcon.search import ExternalForce

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
Step = tuple[np.ndarray, np.ndarray, float, float]
"""k (F, nu), K (F, nu, n), and the expected change's linear and quadratic coefficients."""
Searcher = Callable[[int, int, np.ndarray], "np.ndarray | None"]
"""(first frame, end frame, full state at the first) -> targets of frames first..end-1, or None."""


@dataclass
class PathCost:
    """The iLQR cost of a path: total, per-frame parts, and whether it fell."""

    total: float
    body: np.ndarray  # (F,) mean squared body position error (m^2) after each step
    fell_at: int  # first frame (1-based step count) the head rule fired, -1: never


class BodyCost:
    """The cost of step t's resulting state and its derivatives (see the module docstring).

    Args:
        ref: The reference at frames 0..F (:func:`samcon.search.reference_frames`).
        ref_targets: The reference's next-frame hinge angles of every step. Shape: (F, nu).
    """

    def __init__(self, humanoid: Humanoid, cfg: PolishConfig, ref: CharacterState, ref_targets: np.ndarray,
                 fall_head_error: float) -> None:  # fmt: skip
        self.humanoid, self.cfg, self.ref, self.ref_targets = humanoid, cfg, ref, ref_targets
        self._judge = CostConfig(fall_head_error=fall_head_error)  # the search's terms and its head rule
        m = humanoid.model
        self._ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in humanoid.body_names]
        self._hinge_dof = humanoid.hinge_dof
        self._data = mujoco.MjData(m)
        self._fk = ForwardKinematics(humanoid, threads=0)

    def close(self) -> None:
        self._fk.close()

    def path_cost(self, states: np.ndarray, targets: np.ndarray, first: int) -> PathCost:
        """The cost of the path through ``states`` (F + 1, nstate) under ``targets`` (F, nu), ``states[0]`` at
        clip frame ``first``."""
        h = self.humanoid
        nq, nv = h.nq, h.nv
        sim = self._fk(states[1:, 1 : 1 + nq], states[1:, 1 + nq : 1 + nq + nv])
        ref = self.ref[first + 1 : first + len(states)]
        _, terms = tracking_cost(h, self._judge, sim, ref)
        body, fallen = terms["body_pos"], terms["fallen"]
        vel = np.sum((sim.qvel[:, self._hinge_dof] - ref.qvel[:, self._hinge_dof]) ** 2, axis=-1)
        root_vel = np.sum((sim.qvel[:, :6] - ref.qvel[:, :6]) ** 2, axis=-1)
        ctrl = np.sum((targets - self.ref_targets[first : first + len(targets)]) ** 2, axis=-1)
        total = float(np.sum(self.cfg.body * body + self.cfg.velocity * vel + self.cfg.root_velocity * root_vel
                             + self.cfg.control * ctrl))  # fmt: skip
        return PathCost(total, body, int(np.argmax(fallen)) + 1 if fallen.any() else -1)

    def state_derivatives(self, state: np.ndarray, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """Gradient and Gauss-Newton Hessian of the state cost at reference frame ``frame`` in the tangent space
        (2 nv). Shapes: (2 nv,), (2 nv, 2 nv)."""
        m, d = self.humanoid.model, self._data
        nv = m.nv
        mujoco.mj_setState(m, d, state, _FULL)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        grad, hess = np.zeros(2 * nv), np.zeros((2 * nv, 2 * nv))
        jac = np.zeros((3, nv))
        w = 2.0 * self.cfg.body / len(self._ids)
        for b, body_id in enumerate(self._ids):
            mujoco.mj_jacBody(m, d, jac, None, body_id)
            err = d.xpos[body_id] - self.ref.body_pos[frame, b]
            grad[:nv] += w * jac.T @ err
            hess[:nv, :nv] += w * jac.T @ jac
        dof = nv + self._hinge_dof
        grad[dof] += 2.0 * self.cfg.velocity * (d.qvel[self._hinge_dof] - self.ref.qvel[frame, self._hinge_dof])
        hess[dof, dof] += 2.0 * self.cfg.velocity
        grad[nv : nv + 6] += 2.0 * self.cfg.root_velocity * (d.qvel[:6] - self.ref.qvel[frame, :6])
        hess[nv : nv + 6, nv : nv + 6] += 2.0 * self.cfg.root_velocity * np.eye(6)
        return grad, hess


def backward_pass(a: np.ndarray, b: np.ndarray, lx: np.ndarray, lxx: np.ndarray, lu: np.ndarray, luu: float,
                  mu: float, free: int | None = None) -> Step | None:  # fmt: skip
    """iLQR's backward pass for ``x_{t+1} = A_t x_t + B_t u_t``, cost ``sum_t l_u(u_t) + l_x(x_{t+1})``.

    Args:
        a, b: Shapes: (F, n, n), (F, n, nu).
        lx, lxx: Gradient and Hessian of the state cost of x_1..x_F. Shapes: (F, n), (F, n, n).
        lu: Gradient of the control cost of u_0..u_{F-1}. Shape: (F, nu). luu: its Hessian, diagonal: one weight
            for every control or one per control (nu,).
        mu: Regularisation added to Q_uu.
        free: Only the controls of steps before this one change (None: all); the later steps' cost still shapes
            the change through the value function.

    Returns:
        k (F, nu), K (F, nu, n), and the expected change's linear and quadratic coefficients (the change for step
        size alpha is ``alpha d1 + alpha^2 d2``); None if some Q_uu is not positive definite.
    """
    frames, n, nu = b.shape
    k, gain = np.zeros((frames, nu)), np.zeros((frames, nu, n))
    vx, vxx = lx[-1].copy(), lxx[-1].copy()
    d1 = d2 = 0.0
    eye = np.eye(nu)
    free = frames if free is None else free
    for t in range(frames - 1, -1, -1):
        if t >= free:
            vx, vxx = a[t].T @ vx, a[t].T @ vxx @ a[t]
            if t > 0:
                vx, vxx = vx + lx[t - 1], vxx + lxx[t - 1]
            continue
        qx = a[t].T @ vx
        qu = lu[t] + b[t].T @ vx
        vb = vxx @ b[t]
        quu = b[t].T @ vb + (luu + mu) * eye
        qux = vb.T @ a[t]
        qxx = a[t].T @ vxx @ a[t]
        try:
            chol = np.linalg.cholesky(0.5 * (quu + quu.T))
        except np.linalg.LinAlgError:
            return None
        rhs = np.column_stack([qu, qux])
        sol = np.linalg.solve(chol.T, np.linalg.solve(chol, rhs))
        k[t], gain[t] = -sol[:, 0], -sol[:, 1:]
        d1 += float(k[t] @ qu)
        d2 += 0.5 * float(k[t] @ quu @ k[t])
        vx = qx + gain[t].T @ quu @ k[t] + gain[t].T @ qu + qux.T @ k[t]
        vxx = qxx + gain[t].T @ quu @ gain[t] + gain[t].T @ qux + qux.T @ gain[t]
        vxx = 0.5 * (vxx + vxx.T)
        if t > 0:
            vx, vxx = vx + lx[t - 1], vxx + lxx[t - 1]
    return k, gain, d1, d2


def deviation(m: mujoco.MjModel, ref: np.ndarray, state: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """The tangent-space deviation (2 nv,) of full state ``state`` from ``ref`` (``mj_differentiatePos`` for the
    positions, into the scratch ``dq``)."""
    nq, nv = m.nq, m.nv
    mujoco.mj_differentiatePos(m, dq, 1.0, ref[1 : 1 + nq], state[1 : 1 + nq])
    return np.concatenate([dq, state[1 + nq : 1 + nq + nv] - ref[1 + nq : 1 + nq + nv]])


def forward_pass(humanoid: Humanoid, start: np.ndarray, states: np.ndarray, targets: np.ndarray, k: np.ndarray,
                 gain: np.ndarray, alphas: np.ndarray, limit: float | np.ndarray = np.inf,
                 force: ExternalForce | None = None,
                 first: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Rolls out ``u_t + alpha k_t + clip(K_t dx_t, +-limit)`` for every alpha in one batch from ``start``, dx the
    deviation from ``states`` (with ``force``, the external force it gives every rollout at every step too,
    ``start`` at clip frame ``first``). ``limit``: one for all steps or one per step (F,).

    Returns:
        states (A, F + 1, nstate), the targets applied (A, F, nu) and which rollouts blew up (A,).
    """
    m = humanoid.model
    n, frames = len(alphas), len(targets)
    sim = BatchedSim(humanoid, n, threads=0, applied=force is not None)
    out = np.zeros((n, frames + 1, len(start)))
    applied = np.zeros((n, frames, targets.shape[1]))
    dq = np.zeros(m.nv)
    blown = np.zeros(n, dtype=bool)
    limit = np.broadcast_to(np.asarray(limit, dtype=np.float64), (frames,))
    try:
        sim.state[:] = start
        out[:, 0] = start
        for t in range(frames):
            for i in range(n):
                dx = deviation(m, states[t], sim.state[i], dq)
                applied[i, t] = targets[t] + alphas[i] * k[t] + np.clip(gain[t] @ dx, -limit[t], limit[t])
            blown |= sim.step(applied[:, t], None if force is None else force(first + t, sim.qpos, sim.qvel))
            sim.state[blown] = start  # a blown-up rollout is dropped; its state only has to stay finite
            out[:, t + 1] = sim.state
    finally:
        sim.close()
    return out, applied, blown


@dataclass
class Follow:
    """A path tracked by its time-varying LQR (:mod:`samcon.lqr`; in a pass of the polish, the path the pass starts
    from): at clip frame t the targets ``targets[t] + clip(gain[t] (x_t - states[t]), +-limit)``, x_t the character's
    state."""

    states: np.ndarray  # (F + 1, nstate): the path's states
    targets: np.ndarray  # (F, nu): its targets
    gain: np.ndarray  # (F, nu, 2 nv): its LQR gains
    limit: float

    def effective_gain(self, humanoid: Humanoid, states: np.ndarray, first: int) -> np.ndarray:
        """d(targets)/d(state) of the tracking at ``states`` (T, nstate) from clip frame ``first``: the gain with
        the rows of clipped corrections zeroed. Shape: (T, nu, 2 nv)."""
        out = self.gain[first : first + len(states)].copy()
        dq = np.zeros(humanoid.nv)
        for i, s in enumerate(states):
            out[i][np.abs(out[i] @ deviation(humanoid.model, self.states[first + i], s, dq)) >= self.limit] = 0.0
        return out


def window_rollout(humanoid: Humanoid, start: np.ndarray, states: np.ndarray, targets: np.ndarray, k: np.ndarray,
                   gain: np.ndarray, alphas: np.ndarray, first: int, free: int, follow: Follow | None,
                   force: ExternalForce | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """:func:`forward_pass` of a window whose first ``free`` steps take ``targets + alpha k + K dx`` and whose
    later ones (its look-ahead) hold ``targets`` (``follow`` None) or are played by ``follow``."""
    if follow is None or free >= len(targets):
        return forward_pass(humanoid, start, states, targets, k, gain, alphas, force=force, first=first)
    frames = len(targets)
    later = slice(first + free, first + frames)
    states, targets, k, gain = states.copy(), targets.copy(), k.copy(), gain.copy()
    states[free:frames] = follow.states[later]
    targets[free:] = follow.targets[later]
    k[free:] = 0.0
    gain[free:] = follow.gain[later]
    limit = np.full(frames, np.inf)
    limit[free:] = follow.limit
    return forward_pass(humanoid, start, states, targets, k, gain, alphas, limit, force, first)


def _ilqr(humanoid: Humanoid, cost: BodyCost, start: np.ndarray, targets: np.ndarray, first: int,
          cfg: PolishConfig, label: str, log: TextIO | None, free: int | None = None,
          force: ExternalForce | None = None,
          follow: Follow | None = None) -> tuple[np.ndarray, np.ndarray, list[dict[str, Any]]]:  # fmt: skip
    """iLQR on the path that plays ``targets`` (F, nu) from ``start`` at clip frame ``first``, changing the
    targets of its first ``free`` steps only (None: all); with ``force``, the external force it gives at every step
    too (in the linearisation and every rollout). With ``follow``, the steps from ``free`` on are played by it (their
    targets depend on the state; the linearisation's closed loop ``A + B K`` carries the window's changes through
    them), so that a window is judged by how that path's LQR carries on from where it leaves the character.

    Returns:
        Its targets (those applied, (F, nu)) and states (F + 1, nstate) at the end, and per accepted iteration the
        cost and step.
    """
    t0 = time.perf_counter()
    frames = len(targets)
    free = frames if free is None else free
    follow = follow if free < frames else None
    if follow is None:
        states = nominal_states(humanoid, start, targets, force, first)
    else:
        zero, anywhere = np.zeros((frames, humanoid.model.nu, 2 * humanoid.nv)), np.repeat(start[None], frames + 1, 0)
        roll, applied, _ = window_rollout(humanoid, start, anywhere, targets, np.zeros_like(targets), zero,
                                          np.ones(1), first, free, follow, force)  # fmt: skip
        states, targets = roll[0], applied[0]
    current = cost.path_cost(states, targets, first)
    history: list[dict[str, Any]] = [{"iteration": 0, "cost": current.total}]
    mu = cfg.mu_init
    alphas = np.asarray(cfg.alphas, dtype=np.float64)
    ref_targets = cost.ref_targets[first : first + frames]
    for it in range(1, cfg.iterations + 1):
        a, b = linearise(humanoid, states, targets, cfg.eps, force, first)
        derivs = [cost.state_derivatives(states[t + 1], first + t + 1) for t in range(frames)]
        lx, lxx = np.stack([g for g, _ in derivs]), np.stack([h for _, h in derivs])
        lu = 2.0 * cfg.control * (targets - ref_targets)
        if follow is not None:  # the look-ahead's targets follow the state: closed-loop dynamics and control cost
            kf = follow.effective_gain(humanoid, states[free:frames], first + free)
            a[free:] += b[free:] @ kf
            lx[free - 1 : frames - 1] += np.einsum("tun,tu->tn", kf, lu[free:])
            lxx[free - 1 : frames - 1] += 2.0 * cfg.control * np.einsum("tun,tum->tnm", kf, kf)
        accepted = False
        while not accepted and mu <= cfg.mu_max:
            bp = backward_pass(a, b, lx, lxx, lu, 2.0 * cfg.control, mu, free)
            if bp is None:
                mu *= cfg.mu_factor
                continue
            k, gain, d1, d2 = bp
            roll, applied, blown = window_rollout(humanoid, start, states, targets, k, gain, alphas, first, free,
                                                  follow, force)  # fmt: skip
            trials = [cost.path_cost(roll[i], applied[i], first) for i in range(len(alphas))]
            if cfg.verbose and log is not None:
                print(f"  mu {mu:.3g} expected {d1 + d2:.4g} trials " + " ".join(
                    f"{c.total:.4g}{'b' if blown[i] else ''}{'f' if c.fell_at >= 0 else ''}"
                    for i, c in enumerate(trials)), file=log, flush=True)  # fmt: skip
            best = cheaper(trials, blown, current)
            if best is not None:
                states, targets, current = roll[best], applied[best], trials[best]
                accepted, mu = True, accept_step(cfg, history, it, current, float(alphas[best]), d1, d2, mu)
            else:
                mu *= cfg.mu_factor
        if stops(cfg, history, current, accepted, label, it, t0, log):
            break
    return targets, states, history


def cheaper(trials: list[PathCost], blown: np.ndarray, current: PathCost) -> int | None:
    """The cheapest rollout that did not blow up, is finite, does not fall where ``current`` did not, and is cheaper
    than ``current``; None if there is none."""
    ok = [i for i, c in enumerate(trials)
          if not blown[i] and np.isfinite(c.total) and (c.fell_at < 0 or current.fell_at >= 0)]  # fmt: skip
    best = min(ok, key=lambda i: trials[i].total) if ok else None
    return best if best is not None and trials[best].total < current.total else None


def accept_step(cfg: PolishConfig, history: list[dict[str, Any]], it: int, current: PathCost, alpha: float,
                d1: float, d2: float, mu: float) -> float:  # fmt: skip
    """Records an accepted step in ``history``; returns the lowered regularisation."""
    mu = max(cfg.mu_min, mu / cfg.mu_factor)
    history.append({"iteration": it, "cost": current.total, "alpha": alpha, "expected": alpha * d1 + alpha**2 * d2,
                    "mu": mu})  # fmt: skip
    return mu


def stops(cfg: PolishConfig, history: list[dict[str, Any]], current: PathCost, accepted: bool, label: str, it: int,
          t0: float, log: TextIO | None) -> bool:  # fmt: skip
    """After an iteration: logs it (verbose) and says whether the iLQR stops (no step, or too small a gain)."""
    if cfg.verbose and log is not None:
        print(f"{label} iteration {it}: cost {current.total:.4g}{'' if accepted else ' (no step improved)'} "
              f"{time.perf_counter() - t0:.0f} s", file=log, flush=True)  # fmt: skip
    if not accepted:
        return True
    return len(history) > 2 and history[-2]["cost"] - current.total < cfg.tolerance * history[-2]["cost"]


def polish(humanoid: Humanoid, start: np.ndarray, targets: np.ndarray, ref: CharacterState,
           ref_targets: np.ndarray, cfg: PolishConfig, fall_head_error: float, name: str = "",
           log: TextIO | None = None, lqr: LqrConfig | None = None, searcher: Searcher | None = None,
           force: ExternalForce | None = None) -> tuple[np.ndarray, dict[str, Any]]:  # fmt: skip
    """iLQR from the open-loop path ``targets`` (F, nu) played from ``start`` at the clip's frame 0 (see the
    module docstring): over the whole path at once (``cfg.window`` 0), or window by window, each ``cfg.window``
    frames from the path's current state at its first frame, the next ``cfg.stride`` frames later; each window's
    cost also counts the ``cfg.lookahead`` frames after it.

    A window starts where the windows before left the character, off the searched path, whose open-loop targets
    from there soon fall (jog: every window's starting cost rose tenfold). So with ``lqr`` the frames no window has
    changed yet start from the searched path tracked by its time-varying LQR (:mod:`samcon.lqr`, these weights):
    ``u*_t + clip(K_t (x_t - x*_t))``; with ``cfg.follow`` each window's look-ahead is played by it as well. With
    ``searcher`` (which searches a stretch of frames from a state, as
    SAMCON does, and returns its targets, or None if it fell) the frames after the previous window's look-ahead are
    searched anew from where that look-ahead left the character (the LQR start where it fell). With ``force`` (an
    external force, :class:`samcon.search.ExternalForce`) every step of every rollout also gets the generalised force
    it gives, and the linearisation counts its dependence on the state.

    Returns:
        The polished targets (F, nu) (``targets`` itself if the polished path costs more or falls where it did
        not) and a summary: the cost and body error before and after, per window its iterations, seconds.
    """
    t0 = time.perf_counter()
    cost = BodyCost(humanoid, cfg, ref, ref_targets, fall_head_error)

    def replayed(path: np.ndarray) -> PathCost:  # replayed from the clip's start, judged
        return cost.path_cost(nominal_states(humanoid, start, path, force), path, 0)

    try:
        before = replayed(targets)
        best, after, windows, passes = targets, before, [], []
        for p in range(cfg.passes):
            if p and not passes[-1]["kept"] and searcher is None and cfg.for_pass(p) == cfg.for_pass(p - 1):
                # From the same path with the same settings the pass would do what the dropped one did, bit for bit.
                passes.append({"cost": passes[-1]["cost"], "fell_at": passes[-1]["fell_at"], "kept": False,
                               "repeat_skipped": True})  # fmt: skip
                continue
            new, pass_windows = _sweep(humanoid, cost, start, best, cfg.for_pass(p), lqr, searcher,
                                       f"{name} pass {p + 1}", log, t0, force)  # fmt: skip
            windows += pass_windows
            result = replayed(new)
            better = result.total < after.total and (result.fell_at < 0 or after.fell_at >= 0)
            passes.append({"cost": result.total, "fell_at": result.fell_at, "kept": better})
            if better:
                best, after = new, result
            if log is not None:
                print(f"{name}: polish pass {p + 1}/{cfg.passes}: cost {result.total:.4g}"
                      f"{'' if better else ' (dearer or fell: dropped)'}", file=log, flush=True)  # fmt: skip
        if cfg.whole_iterations:
            # Then the whole path at once from the best so far: every step lowers its cost (none falls where it did
            # not), so this never undoes the windows' gain.
            whole, _, hist = _ilqr(humanoid, cost, start, best, 0, replace(cfg, iterations=cfg.whole_iterations),
                                   f"{name} whole path", log, force=force)  # fmt: skip
            passes.append({"whole_steps": len(hist) - 1, "cost": hist[-1]["cost"], "kept": len(hist) > 1})
            if len(hist) > 1:
                best, after = whole, replayed(whole)
            if log is not None:
                print(f"{name}: whole path, {len(hist) - 1} steps: cost {after.total:.4g}", file=log, flush=True)
        worse = best is targets
    finally:
        cost.close()
    summary = {
        "cost_before": before.total, "cost_after": after.total, "kept": not worse,
        "body_rms_mm_before": 1000 * float(np.sqrt(before.body.mean())),
        "body_rms_mm_after": 1000 * float(np.sqrt(after.body.mean())),
        "passes": passes, "windows": windows, "seconds": time.perf_counter() - t0,
    }  # fmt: skip
    if log is not None:
        print(f"{name}: polished, cost {before.total:.4g} -> {after.total:.4g}, body rms "
              f"{summary['body_rms_mm_before']:.1f} -> {summary['body_rms_mm_after']:.1f} mm"
              f"{' (worse: the searched path is kept)' if worse else ''}, {summary['seconds']:.0f} s", file=log,
              flush=True)  # fmt: skip
    return best, summary


def tracking_gain(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray, name: str,
                  log: TextIO | None) -> np.ndarray | None:  # fmt: skip
    """The time-varying LQR gains (F, nu, n) that track a path from its linearisation ``a`` (F, n, n), ``b``
    (F, n, nu) with state cost ``q`` (n, n) (at the end too) and control cost ``r`` (nu, nu); None, logged, where the
    Riccati recursion is singular or not finite (a path that went through a blow-up has no usable LQR)."""
    try:
        gain = riccati(a, b, q, r, q)[0]
    except np.linalg.LinAlgError:
        gain = None
    if gain is not None and not np.isfinite(gain).all():
        gain = None
    if gain is None and log is not None:
        print(f"{name}: the path's LQR is singular or not finite; new frames start from its targets alone", file=log,
              flush=True)  # fmt: skip
    return gain


def _sweep(humanoid: Humanoid, cost: BodyCost, start: np.ndarray, targets: np.ndarray, cfg: PolishConfig,
           lqr: LqrConfig | None, searcher: Searcher | None, name: str, log: TextIO | None, t0: float,
           force: ExternalForce | None = None) -> tuple[np.ndarray, list]:  # fmt: skip
    """One pass of windows over the path (see :func:`polish`): its new targets and per window its iterations."""
    frames = len(targets)
    states = nominal_states(humanoid, start, targets, force)
    new = targets.copy()
    window = cfg.window or frames
    stride = cfg.stride or window
    firsts = list(range(0, max(1, frames - window + stride), stride))
    windows = []
    searched, track = states.copy(), None
    if lqr is not None and cfg.window:
        a, b = linearise(humanoid, searched, targets, lqr.eps, force)
        track = tracking_gain(a, b, np.diag(state_weights(humanoid, lqr)), lqr.control * np.eye(humanoid.model.nu),
                              name, log)  # fmt: skip
    follow = None if track is None else Follow(searched, targets, track, lqr.limit)
    changed = 0  # frames before this one have been a window's to change
    played = 0  # frames before this one have been played in a window's cost
    for j, s in enumerate(firsts):
        e = min(frames, s + window)
        tail = min(frames, e + cfg.lookahead) if cfg.window else e
        init = new[s:tail]
        found = searcher(played, tail, states[played]) if searcher is not None and 0 < played < tail else None
        if found is not None:
            init = np.concatenate([new[s:played], found])
        elif track is not None and tail > changed:
            gain = np.zeros((tail - s, *track.shape[1:]))
            gain[max(0, changed - s) :] = track[max(s, changed) : tail]
            unchanged = (np.arange(s, tail) >= changed)[:, None]
            base = np.where(unchanged, targets[s:tail], new[s:tail])
            _, applied, blown = forward_pass(humanoid, states[s], searched[s : tail + 1], base,
                                             np.zeros(gain.shape[:2]), gain, np.zeros(1), lqr.limit, force,
                                             s)  # fmt: skip
            if not blown[0]:
                init = applied[0]
        label = f"{name} frames {s}-{e}"
        got, got_states, hist = _ilqr(humanoid, cost, states[s], init, s, cfg, label, log, free=e - s, force=force,
                                      follow=follow if cfg.follow else None)  # fmt: skip
        new[s:tail], states[s : tail + 1] = got, got_states
        changed = max(changed, e)
        played = max(played, tail)
        windows.append({"first": s, "end": e, "iterations": hist, "searched": found is not None})
        if log is not None:
            print(f"{label} ({j + 1}/{len(firsts)}): cost {hist[0]['cost']:.4g} -> {hist[-1]['cost']:.4g} in "
                  f"{len(hist) - 1} steps, {time.perf_counter() - t0:.0f} s", file=log, flush=True)  # fmt: skip
    return new, windows
