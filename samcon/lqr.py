"""Time-varying LQR around SAMCON's paths: linear feedback from the full state, from the dynamics themselves.

The regressed feedback of :mod:`samcon.feedback` learns corrections from the spread of one search's samples, which
start from a few dozen nearby states; on walk it never held more than 1 of 16 evaluator starts (sessions 12-17).
Here the corrections come from the simulator's own derivatives instead, as trajectory stabilisation does in
robotics (time-varying LQR; Tedrake's LQR-trees, 2010) and as Muico et al. (2009) track motion capture with a
linearised character:

1. **Linearise** the chosen open-loop path: at every physics step of every control step, MuJoCo's
   ``mjd_transitionFD`` (centred finite differences, step ``eps``) gives the one-step Jacobians ``A_i`` of the
   state (in the tangent space: ``2 nv`` coordinates, the root's rotation as an angular vector) and ``B_i`` of the
   position actuators' targets, which a control step holds for its ``substeps`` physics steps; so per control step
   ``A = A_S ... A_1`` and ``B = sum_i A_S ... A_{i+1} B_i``.
2. **Riccati** backwards along the path with a diagonal state cost Q (per coordinate group: root position, root
   rotation, hinge angles, and their velocities) and ``R = control * I``: ``K_t = -(R + B^T P B)^-1 B^T P A``,
   ``P_t = Q + A^T P (A + B K_t)``, from ``P_T`` (Q at the clip's end; a recovery path ends on the main path's
   ``P`` there, so that cost-to-go values of different paths compare).
3. **The policy**: ``u_t = u*_t + clip(K_t dx, -limit, limit)`` every control step, ``dx`` the character's
   deviation from the path's state at that frame (``mj_differentiatePos`` for positions). With several paths
   (``lqr.visit_rounds``), the one of least cost-to-go ``dx^T P_t dx`` among those covering the frame (LQR-trees'
   choice of funnel). Loop clips past the path's end go back whole cycles; the character is then moved by the rigid
   transform (yaw and horizontal shift) that takes the reference at its frame to the reference at the frame used.

Recovery paths (``lqr.visit_rounds``): the policy plays episodes from random frames of the clip's first cycle (not
the evaluator's starts), and from each episode that falls SAMCON searches ``visit_segments`` segments from the
character's own state ``visit_lead`` frames or more before the fall; each such path gets its own LQR and joins the
set (LQR-trees' growth; Liu et al. 2016's guided learning aggregates searched states the same way).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Container, Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import EvalConfig, Policy
from common.maths.rotations import quat_from_yaw, quat_mul, quat_rotate, quat_yaw
from common.motion.library import MotionLibrary
from common.sim.gym import GymConfig, StepResult, TrackingGym
from samcon.config import LqrConfig
from samcon.feedback import ClipPlan, FeedbackPolicy
from samcon.search import ExternalForce, Trajectory, replay

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS


def nominal_states(humanoid: Humanoid, start_state: np.ndarray, targets: np.ndarray,
                   force: ExternalForce | None = None, first: int = 0) -> np.ndarray:  # fmt: skip
    """The full states a path passes through, ``start_state`` first, replayed as the gym steps
    (:func:`samcon.search.replay`), so that they are bit-exactly those of an evaluator episode that plays ``targets``
    from ``start_state`` (with ``force``, the external force it gives at every step too, the path's first state at
    clip frame ``first``). Shape: (F + 1, nstate)."""
    return np.concatenate([np.asarray(start_state, dtype=np.float64)[None],
                           replay(humanoid, start_state, targets, force=force, first=first)])  # fmt: skip


def linearise(humanoid: Humanoid, states: np.ndarray, targets: np.ndarray, eps: float,
              force: ExternalForce | None = None, first: int = 0) -> tuple[np.ndarray, ...]:  # fmt: skip
    """Per control step f, the Jacobians of the next state's tangent coordinates with respect to those of the state
    at f and to the targets held over the step (see the module docstring).

    Args:
        states: Full MuJoCo states at every frame (:func:`nominal_states`). Shape: (F + 1, nstate).
        targets: PD targets of every frame. Shape: (F, nu).
        eps: Finite-difference step.
        force: An external generalised force from the state at every step (None: none), the path's first state at
            clip frame ``first``. Its dependence on the state joins A: ``A += dx'/dF dF/dx``, dx'/dF by central
            differences (:func:`force_response`) at the dofs the force depends on.

    Returns:
        A: Shape: (F, 2 nv, 2 nv). B: Shape: (F, 2 nv, nu).
    """
    m = humanoid.model
    d = mujoco.MjData(m)
    n, nu, frames = 2 * m.nv, m.nu, len(targets)
    a_out, b_out = np.zeros((frames, n, n)), np.zeros((frames, n, nu))
    a, b = np.zeros((n, n)), np.zeros((n, nu))
    scratch = None if force is None else mujoco.MjData(m)  # for the force's central differences
    for f in range(frames):
        mujoco.mj_setState(m, d, states[f], _FULL)
        d.ctrl[:] = targets[f]
        held = jac = None
        if force is not None:
            qpos, qvel = states[f : f + 1, 1 : 1 + m.nq], states[f : f + 1, 1 + m.nq : 1 + m.nq + m.nv]
            held, jac = force(first + f, qpos, qvel)[0], force.jacobian(first + f, qpos, qvel)[0]
            d.qfrc_applied[:] = held
        a_f, b_f = np.eye(n), np.zeros((n, nu))
        for _ in range(humanoid.physics.substeps):
            mujoco.mjd_transitionFD(m, d, eps, True, a, b, None, None)
            a_f, b_f = a @ a_f, a @ b_f + b
            mujoco.mj_step(m, d)
        if jac is not None:
            for dof in np.flatnonzero(np.abs(jac).max(axis=1) > 0):
                a_f += np.outer(force_response(humanoid, scratch, states[f], targets[f], held, int(dof)), jac[dof])
        a_out[f], b_out[f] = a_f, b_f
    return a_out, b_out


FORCE_STEP = 0.01  # N: the central-difference step of a generalised force in force_response


def force_response(humanoid: Humanoid, d: mujoco.MjData, state: np.ndarray, target: np.ndarray, force: np.ndarray,
                   dof: int) -> np.ndarray:  # fmt: skip
    """d(next state's tangent coordinates) / d(generalised force at ``dof``) over one control step from full state
    ``state`` (nstate,) with PD targets ``target`` (nu,) and external force ``force`` (nv,) held, central
    differences, on the scratch data ``d``. Shape: (2 nv,). The solver's warm start is not part of ``state``
    (``mjSTATE_FULLPHYSICS`` leaves it out): it is zeroed, as in a fresh ``MjData``, so that the result does not
    depend on what ``d`` did before (reused as it was, it moved the differences by up to 3e-12, which the polish's
    iterations amplified)."""
    m = humanoid.model
    ends = []
    for sign in (1.0, -1.0):
        mujoco.mj_setState(m, d, state, _FULL)
        d.qacc_warmstart[:] = 0.0
        d.ctrl[:], d.qfrc_applied[:] = target, force
        d.qfrc_applied[dof] += sign * FORCE_STEP
        for _ in range(humanoid.physics.substeps):
            mujoco.mj_step(m, d)
        ends.append((d.qpos.copy(), d.qvel.copy()))
    dq = np.zeros(m.nv)
    mujoco.mj_differentiatePos(m, dq, 1.0, ends[1][0], ends[0][0])
    return np.concatenate([dq, ends[0][1] - ends[1][1]]) / (2.0 * FORCE_STEP)


def riccati(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray,
            p_end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The finite-horizon discrete Riccati recursion for ``x' = A_t x + B_t u``, cost ``sum x^T Q x + u^T R u`` and
    ``x_T^T P_end x_T``.

    Returns:
        gain K_t (u = K_t x). Shape: (F, nu, n). cost_to_go P_t. Shape: (F, n, n).
    """
    frames, n, nu = b.shape
    gain, cost = np.zeros((frames, nu, n)), np.zeros((frames, n, n))
    p = p_end
    for f in range(frames - 1, -1, -1):
        bp = b[f].T @ p
        gain[f] = -np.linalg.solve(r + bp @ b[f], bp @ a[f])
        p = q + a[f].T @ p @ (a[f] + b[f] @ gain[f])
        p = 0.5 * (p + p.T)
        cost[f] = p
    return gain, cost


def state_weights(humanoid: Humanoid, cfg: LqrConfig) -> np.ndarray:
    """The diagonal of Q over the tangent coordinates: root position (x, y, z world), root rotation (root frame),
    hinge angles, then the same velocities. Shape: (2 nv,)."""
    hinges = humanoid.model.nv - 6
    return np.concatenate([[cfg.root_pos] * 2, [cfg.root_height], [cfg.root_rot] * 3, [cfg.hinge] * hinges,
                           [cfg.root_vel] * 3, [cfg.root_ang_vel] * 3, [cfg.hinge_vel] * hinges])  # fmt: skip


@dataclass
class LqrPath:
    """One path and its feedback. n frames from frame ``first``.

    Attributes:
        first: The clip frame of the path's first state.
        targets: PD targets. Shape: (n, nu).
        qpos: The path's coordinates at each of its frames. Shape: (n, nq).
        qvel: Its velocities. Shape: (n, nv).
        gain: K_t, stored as float32. Shape: (n, nu, 2 nv).
        cost_to_go: P_t, stored as float32. Shape: (n, 2 nv, 2 nv). None for a clip's only path (nothing to choose
            between; ``samcon.h5`` then leaves its 9.5 MB per 512 frames out).
    """

    first: int
    targets: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    gain: np.ndarray
    cost_to_go: np.ndarray | None

    @property
    def end(self) -> int:
        return self.first + len(self.targets)


def stabilise(humanoid: Humanoid, start_state: np.ndarray, targets: np.ndarray, first: int, cfg: LqrConfig,
              p_end: np.ndarray | None = None) -> LqrPath:  # fmt: skip
    """The LQR of the path that plays ``targets`` from ``start_state`` at clip frame ``first``; ``p_end`` the
    cost-to-go it ends on (None: Q)."""
    m = humanoid.model
    states = nominal_states(humanoid, start_state, targets)
    a, b = linearise(humanoid, states, targets, cfg.eps)
    q = np.diag(state_weights(humanoid, cfg))
    gain, cost = riccati(a, b, q, cfg.control * np.eye(m.nu), q if p_end is None else p_end)
    qpos, qvel = states[:-1, 1 : 1 + m.nq], states[:-1, 1 + m.nq : 1 + m.nq + m.nv]
    return LqrPath(first, np.asarray(targets, dtype=np.float64), qpos.copy(), qvel.copy(),
                   gain.astype(np.float32), cost.astype(np.float32))  # fmt: skip


class LqrPolicy:
    """The paths' LQR as an evaluator policy, from any start (see the module docstring); a clip without paths
    gets ``fallback``'s output.

    Args:
        paths: {clip name: [paths]}, the first of each being the path from the clip's start.
        limits: {clip name: the largest correction per actuator (rad)}.
        fallback: The policy of the other clips (e.g. :class:`samcon.feedback.FeedbackPolicy`).
    """

    def __init__(self, paths: dict[str, list[LqrPath]], limits: dict[str, float], library: MotionLibrary,
                 humanoid: Humanoid, fallback: Policy) -> None:  # fmt: skip
        self.paths, self.limits, self.library, self.humanoid = paths, limits, library, humanoid
        self.fallback = fallback
        self._dq = np.zeros(humanoid.model.nv)

    def frame_used(self, name: str, clip: int, frame: int) -> int:
        """The frame of the main path that clip frame ``frame`` maps to (loop clips go back whole cycles past its
        end; one-shot clips hold its last frame)."""
        span = self.paths[name][0].end
        if self.library.loop[clip] and frame >= span:
            cycle = int(round(self.library.duration[clip] / self.library.dt))
            frame -= int(np.ceil((frame - span + 1) / cycle)) * cycle
        return min(max(frame, 0), span - 1)

    def moved(self, clip: int, qpos: np.ndarray, qvel: np.ndarray, ref_qpos: np.ndarray,
              frame: int) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """A character's coordinates moved by the yaw and horizontal shift that take the reference root
        ``ref_qpos`` (its frame's) onto the reference root at ``frame``."""
        to = self.library.query(np.array([clip]), np.array([frame * self.library.dt])).qpos[0]
        turn = quat_from_yaw(np.array(float(quat_yaw(to[3:7]) - quat_yaw(ref_qpos[3:7]))))
        qpos, qvel = qpos.copy(), qvel.copy()
        offset = qpos[:3] - np.array([ref_qpos[0], ref_qpos[1], 0.0])
        qpos[:3] = quat_rotate(turn, offset) + np.array([to[0], to[1], 0.0])
        qpos[3:7] = quat_mul(turn, qpos[3:7])
        qvel[:3] = quat_rotate(turn, qvel[:3])  # MuJoCo's free joint: linear velocity world, angular root frame
        return qpos, qvel

    def control(self, name: str, frame: int, qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, int, float]:
        """The targets for coordinates at main-path frame ``frame``: from the covering path of least cost-to-go.
        Also that path's index and cost-to-go."""
        m = self.humanoid.model
        best: tuple[float, int, np.ndarray] | None = None
        for j, path in enumerate(self.paths[name]):
            if not path.first <= frame < path.end:
                continue
            k = frame - path.first
            mujoco.mj_differentiatePos(m, self._dq, 1.0, path.qpos[k], qpos)
            dx = np.concatenate([self._dq, qvel - path.qvel[k]])
            v = 0.0 if path.cost_to_go is None else float(dx @ path.cost_to_go[k].astype(np.float64) @ dx)
            if best is None or v < best[0]:
                best = (v, j, dx)
        v, j, dx = best
        path = self.paths[name][j]
        k = frame - path.first
        limit = self.limits[name]
        u = path.targets[k] + np.clip(path.gain[k].astype(np.float64) @ dx, -limit, limit)
        return u, j, v

    def __call__(self, result: StepResult) -> np.ndarray:
        out = np.asarray(self.fallback(result), dtype=np.float64).copy()
        frames = np.rint(result.time / self.library.dt).astype(np.int64)
        for i, (c, f) in enumerate(zip(result.clip, frames, strict=True)):
            name = self.library.names[c]
            if name not in self.paths:
                continue
            g = self.frame_used(name, int(c), int(f))
            qpos, qvel = result.sim.qpos[i], result.sim.qvel[i]
            if g != f:
                qpos, qvel = self.moved(int(c), qpos, qvel, result.ref.qpos[i], g)
            out[i] = self.control(name, g, qpos, qvel)[0]
        return out


def play_until_falls(policy: Policy, library: MotionLibrary, humanoid: Humanoid, clip: int, first: np.ndarray,
                     steps: int, end: int, keep: Container[int], ev: EvalConfig,
                     threads: int = 0) -> tuple[list[dict[int, np.ndarray]], np.ndarray]:  # fmt: skip
    """Episodes of ``policy`` on ``clip`` from the reference at frames ``first`` under the evaluator's failure rule,
    for at most ``steps`` steps and before frame ``end``.

    Returns:
        Per episode {frame: full MuJoCo state} at the frames in ``keep`` it reached standing (its first included),
        and the frame each one failed at (-1: never). Shapes: (N,) each.
    """
    n = len(first)
    gym = TrackingGym(GymConfig(num_envs=n, threads=threads, seed=ev.seed, physics=humanoid.physics,
                                termination=ev.termination, rsi_lift=ev.rsi_lift), library, humanoid)  # fmt: skip
    states: list[dict[int, np.ndarray]] = [{} for _ in range(n)]
    failed = np.full(n, -1)
    try:
        result = gym.reset(clips=np.full(n, clip), times=first * library.dt)
        for i in range(n):
            if int(first[i]) in keep:
                states[i][int(first[i])] = gym.sim.state[i].copy()
        alive = np.ones(n, dtype=bool)
        for step in range(1, steps + 1):
            result = gym.step(policy(result), autoreset=False)
            frame = first + step
            newly = alive & result.terminated
            failed[newly] = frame[newly]
            alive &= ~result.terminated & (frame < end)
            for i in np.flatnonzero(alive):
                if int(frame[i]) in keep:
                    states[i][int(frame[i])] = gym.sim.state[i].copy()
            if not alive.any():
                break
    finally:
        gym.close()
    return states, failed


def visit_falls(policy: LqrPolicy, name: str, library: MotionLibrary, humanoid: Humanoid, grid: np.ndarray,
                cfg: LqrConfig, ev: EvalConfig, rng: np.random.Generator,
                threads: int = 0) -> tuple[list[tuple[int, np.ndarray]], float]:  # fmt: skip
    """Where ``policy`` falls: ``cfg.visit_episodes`` episodes from the reference at random frames of the clip's
    first cycle (one-shot clips: of its tracked range), under the evaluator's failure rule; of each that fails at
    frame t, the simulated state at the last segment start of ``grid`` at or before ``t - visit_lead`` (on the main
    path's frames, before any wrap) from which ``visit_segments`` segments remain.

    Returns:
        [(frame, full MuJoCo state (nstate,))] and the share of the episodes that fell.
    """
    clip = library.clip_index(name)
    cycle = int(round(library.duration[clip] / library.dt)) if library.loop[clip] else int(grid[-1])
    n = cfg.visit_episodes
    first = rng.integers(0, max(1, min(cycle, int(grid[-1]) - 1)), n)
    starts = {int(f) for i, f in enumerate(grid[:-1]) if i + cfg.visit_segments <= len(grid) - 1}
    last = library.num_frames[clip] - 1 if not library.loop[clip] else np.iinfo(np.int64).max
    states, failed = play_until_falls(policy, library, humanoid, clip, first, cfg.visit_frames, last, starts, ev,
                                      threads)  # fmt: skip
    out = []
    for i in np.flatnonzero(failed >= 0):
        ok = [f for f in states[i] if f <= failed[i] - cfg.visit_lead]
        if ok:
            out.append((max(ok), states[i][max(ok)]))
    return out, float(np.mean(failed >= 0))


def grow_paths(traj: Trajectory, library: MotionLibrary, humanoid: Humanoid, cfg: LqrConfig, ev: EvalConfig,
               searcher: Callable[[int, int, np.ndarray], Trajectory], rng: np.random.Generator,
               log: Any = None, extra: Sequence[Trajectory] = ()) -> tuple[list[LqrPath], dict[str, Any]]:  # fmt: skip
    """The LQR of the path ``traj`` (from the clip's start), of the ``extra`` searches that started later on the
    reference (``feedback.starts``; those whose kept path fell are left out) and, with ``cfg.visit_rounds``, of
    recovery paths that ``searcher(first, end, state)`` searches from states where the policy falls (see the module
    docstring). A path that ends before the main one ends on the main path's cost-to-go there.

    Returns:
        The paths (the main one first) and a summary: seconds, per round the share of visit episodes that fell and
        the searches run (those whose kept path fell are dropped).
    """
    t0 = time.perf_counter()
    main = stabilise(humanoid, traj.start_state, traj.targets, int(traj.bounds[0]), cfg)
    paths = [main]

    def ending(end: int) -> np.ndarray | None:
        return main.cost_to_go[end - main.first].astype(np.float64) if end < main.end else None

    for path in extra:
        if path.segment_terms["fallen"].sum() == 0:
            first = int(path.bounds[0])
            paths.append(stabilise(humanoid, path.start_state, path.targets, first, cfg, ending(int(path.bounds[-1]))))
    rounds = []
    for r in range(cfg.visit_rounds):
        policy = LqrPolicy({traj.clip: paths}, {traj.clip: cfg.limit}, library, humanoid,
                           fallback=_reference_angles(humanoid))  # fmt: skip
        visits, share = visit_falls(policy, traj.clip, library, humanoid, traj.bounds, cfg, ev, rng)
        kept = 0
        for first, state in visits:
            end = int(traj.bounds[int(np.searchsorted(traj.bounds, first)) + cfg.visit_segments])
            path = searcher(first, end, state)
            if path.segment_terms["fallen"].sum() > 0:
                continue
            paths.append(stabilise(humanoid, state, path.targets, first, cfg, ending(end)))
            kept += 1
        rounds.append({"round": r + 1, "fell": share, "searches": len(visits), "kept": kept})
        if log is not None:
            print(f"{traj.clip}: LQR visit round {r + 1}/{cfg.visit_rounds}: {share:.0%} of {cfg.visit_episodes} "
                  f"episodes fell; {kept} of {len(visits)} recovery searches kept, {len(paths)} paths", file=log,
                  flush=True)  # fmt: skip
    return paths, {"seconds": time.perf_counter() - t0, "paths": len(paths), "visits": rounds}


def _reference_angles(humanoid: Humanoid) -> Policy:
    """The reference's next-frame hinge angles (the fallback of clips without paths)."""

    def policy(result: StepResult) -> np.ndarray:
        return result.ref_next.qpos[:, humanoid.hinge_qpos]

    return policy


def evaluation_policy(plans: dict[str, ClipPlan], library: MotionLibrary, humanoid: Humanoid) -> Policy:
    """A run's policy under the evaluator's protocol: the LQR paths of the clips that have them, the regressed
    feedback (:class:`samcon.feedback.FeedbackPolicy`) of the others."""
    feedback = FeedbackPolicy(plans, library, humanoid)
    paths = {k: p.lqr for k, p in plans.items() if p.lqr}
    if not paths:
        return feedback
    return LqrPolicy(paths, {k: plans[k].lqr_limit for k in paths}, library, humanoid, fallback=feedback)
