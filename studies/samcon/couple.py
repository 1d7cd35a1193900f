"""A couple on the root as a control of the iLQR polish (session 25): taking root help away inside the optimiser.

The product's polish (:func:`samcon.polish.polish`) optimises a path's PD targets. Here a couple on the root (the free
joint's rotational dofs, root frame, N m, held over each step as :mod:`studies.samcon.assist`'s law applies its own)
joins the targets as three more controls (:class:`Couple`), optimised with them at the price ``weight`` x its
squared norm per frame. ``python -m studies.samcon.assist --then-couple`` polishes with a rising weight and then
without the couple, so that the help a path was found with is taken away by the optimiser, path kept, rather than by
a new search. The passes, windows and whole-path iterations are the polish's; the look-ahead is never played by the
LQR (``polish.follow``) and no frames are searched anew (``polish.search``): both would need the couple too.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any, TextIO

import mujoco
import numpy as np

from common.character.humanoid import Humanoid
from common.character.state import CharacterState
from common.sim.physics import BatchedSim
from samcon.config import LqrConfig, PolishConfig
from samcon.lqr import force_response, linearise, nominal_states, state_weights
from samcon.polish import (
    BodyCost,
    PathCost,
    accept_step,
    backward_pass,
    cheaper,
    deviation,
    stops,
    tracking_gain,
)
from studies.samcon.forces import HeldForces

ROOT_TURN = slice(3, 6)  # the free joint's rotational dofs: a couple on the root, in the root's frame
COUPLE_UNIT = 100.0  # N m: the iLQR's unit of a couple control, near what a radian of a PD target gives (session 25)


@dataclass
class Couple:
    """A couple on the root as three more controls of the polish: per clip frame a torque on the free joint's
    rotational dofs (root frame, N m, held over the step), optimised with the targets, each frame's costing
    ``weight`` x its squared norm. Raising the weight from one polish to the next takes the help away inside the
    optimiser, which keeps the path while it moves the work to the targets (session 25).

    Attributes:
        values: Shape: (F, 3) for the clip's frames 0..F-1.
        weight: Per (N m)^2 per frame, in the units of the polish's cost (``polish.body`` x m^2).
    """

    values: np.ndarray
    weight: float

    def law(self, nv: int) -> HeldForces:
        """The couple as a held generalised force (F, nv), 0 but at the root's rotational dofs."""
        forces = np.zeros((len(self.values), nv))
        forces[:, ROOT_TURN] = self.values
        return HeldForces(forces)

    def cost(self, values: np.ndarray) -> float:
        return float(self.weight * np.sum(values**2))


def couple_columns(humanoid: Humanoid, states: np.ndarray, targets: np.ndarray, forces: np.ndarray,
                   steps: int | None = None) -> np.ndarray:  # fmt: skip
    """d(next state's tangent coordinates) / d(couple) of each step, one column per rotational dof of the root: the
    columns a :class:`Couple` adds to B (central differences of the step, :func:`samcon.lqr.force_response`).

    Args:
        states: Full states of the path. Shape: (F + 1, nstate).
        targets: Its targets. Shape: (F, nu).
        forces: The generalised force held over each step (the couple's). Shape: (F, nv).
        steps: Only the first ``steps`` steps (the rest stay 0; None: all).

    Returns:
        Shape: (F, 2 nv, 3), per N m.
    """
    m = humanoid.model
    scratch = mujoco.MjData(m)
    out = np.zeros((len(targets), 2 * m.nv, 3))
    for t in range(len(targets) if steps is None else min(steps, len(targets))):
        for j, dof in enumerate(range(m.nv)[ROOT_TURN]):
            out[t, :, j] = force_response(humanoid, scratch, states[t], targets[t], forces[t], dof)
    return out


def couple_rollout(humanoid: Humanoid, start: np.ndarray, states: np.ndarray, targets: np.ndarray,
                   couple: np.ndarray, k: np.ndarray, gain: np.ndarray, alphas: np.ndarray,
                   limit: float | np.ndarray = np.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """:func:`samcon.polish.forward_pass` with the couple (F, 3) as three more controls: u_t is ``targets[t]`` and
    ``couple[t]`` (k and K have nu + 3 rows; ``limit`` clips the targets' feedback only).

    Returns:
        states (A, F + 1, nstate), the controls applied (A, F, nu + 3) and which rollouts blew up (A,).
    """
    m = humanoid.model
    nv, nu = m.nv, m.nu
    n, frames = len(alphas), len(targets)
    sim = BatchedSim(humanoid, n, threads=0, applied=True)
    out = np.zeros((n, frames + 1, len(start)))
    nominal = np.concatenate([targets, couple], axis=1)
    applied = np.zeros((n, frames, nominal.shape[1]))
    dq = np.zeros(nv)
    blown = np.zeros(n, dtype=bool)
    limit = np.broadcast_to(np.asarray(limit, dtype=np.float64), (frames,))
    try:
        sim.state[:] = start
        out[:, 0] = start
        for t in range(frames):
            for i in range(n):
                dx = deviation(m, states[t], sim.state[i], dq)
                feedback = gain[t] @ dx
                feedback[:nu] = np.clip(feedback[:nu], -limit[t], limit[t])
                applied[i, t] = nominal[t] + alphas[i] * k[t] + feedback
            force = np.zeros((n, nv))
            force[:, ROOT_TURN] += applied[:, t, nu:]
            blown |= sim.step(applied[:, t, :nu], force)
            sim.state[blown] = start  # a blown-up rollout is dropped; its state only has to stay finite
            out[:, t + 1] = sim.state
    finally:
        sim.close()
    return out, applied, blown


def ilqr_couple(humanoid: Humanoid, cost: BodyCost, start: np.ndarray, targets: np.ndarray, first: int,
                cfg: PolishConfig, label: str, log: TextIO | None, free: int | None,
                couple: Couple) -> tuple[np.ndarray, np.ndarray, list[dict[str, Any]]]:  # fmt: skip
    """The polish's iLQR on the path that plays ``targets`` (F, nu) from ``start`` at clip frame ``first``, the root
    couple three more controls: B gains the next state's response to the couple (central differences), the control
    cost its weight; only the controls of the first ``free`` steps change (None: all). Returns the controls
    (F, nu + 3), the states (F + 1, nstate) and per accepted iteration the cost and step.

    The backward pass sees the couple in units of :data:`COUPLE_UNIT`: its regularisation ``mu`` is added to every
    control alike, and in N m (a 1 N m couple moves the character a thousandth of what a radian of a target does) it
    froze the couple (measured on the test's push: 20 N m left at 19.7)."""
    t0 = time.perf_counter()
    m = humanoid.model
    nu, nv, frames = m.nu, m.nv, len(targets)
    free = frames if free is None else free
    values = couple.values.copy()  # every clip frame's couple; this window's are changed in place
    window = slice(first, first + frames)

    def total(states: np.ndarray, controls: np.ndarray) -> PathCost:
        got = cost.path_cost(states, controls[:, :nu], first)
        return replace(got, total=got.total + couple.cost(controls[:, nu:]))

    controls = np.concatenate([targets, values[window]], axis=1)
    states = nominal_states(humanoid, start, targets, replace(couple, values=values).law(nv), first)
    current = total(states, controls)
    history: list[dict[str, Any]] = [{"iteration": 0, "cost": current.total}]
    mu = cfg.mu_init
    alphas = np.asarray(cfg.alphas, dtype=np.float64)
    weights = np.concatenate([np.full(nu, cfg.control), np.full(3, couple.weight)])
    unit = np.concatenate([np.ones(nu), np.full(3, COUPLE_UNIT)])  # controls in the backward pass's units: u / unit
    reference = np.concatenate([cost.ref_targets[window], np.zeros((frames, 3))], axis=1)
    for it in range(1, cfg.iterations + 1):
        values[window] = controls[:, nu:]
        held = replace(couple, values=values).law(nv)
        a, b = linearise(humanoid, states, controls[:, :nu], cfg.eps, held, first)
        # the later steps' controls do not change: their columns are not used
        turn = couple_columns(humanoid, states, controls[:, :nu], held.forces[window], free)
        b = np.concatenate([b, turn], axis=2) * unit
        derivs = [cost.state_derivatives(states[t + 1], first + t + 1) for t in range(frames)]
        lx, lxx = np.stack([g for g, _ in derivs]), np.stack([h for _, h in derivs])
        lu = 2.0 * weights * (controls - reference) * unit
        accepted = False
        while not accepted and mu <= cfg.mu_max:
            bp = backward_pass(a, b, lx, lxx, lu, 2.0 * weights * unit**2, mu, free)
            if bp is None:
                mu *= cfg.mu_factor
                continue
            k, gain, d1, d2 = bp
            k, gain = k * unit, gain * unit[:, None]
            roll, applied, blown = couple_rollout(humanoid, start, states, controls[:, :nu], controls[:, nu:], k,
                                                  gain, alphas)  # fmt: skip
            trials = [total(roll[i], applied[i]) for i in range(len(alphas))]
            best = cheaper(trials, blown, current)
            if best is not None:
                states, controls, current = roll[best], applied[best], trials[best]
                accepted, mu = True, accept_step(cfg, history, it, current, float(alphas[best]), d1, d2, mu)
            else:
                mu *= cfg.mu_factor
        if stops(cfg, history, current, accepted, label, it, t0, log):
            break
    return controls, states, history


def polish_couple(humanoid: Humanoid, start: np.ndarray, targets: np.ndarray, ref: CharacterState,
                  ref_targets: np.ndarray, cfg: PolishConfig, fall_head_error: float, couple: Couple, name: str = "",
                  log: TextIO | None = None,
                  lqr: LqrConfig | None = None) -> tuple[np.ndarray, dict[str, Any]]:  # fmt: skip
    """:func:`samcon.polish.polish` (passes of windows, then the whole path) with ``couple``'s values three more
    controls, optimised with the targets at the price of its weight; with ``lqr`` the frames no window has changed
    yet start from the path's LQR, the couple one of its controls.

    Returns:
        The polished targets (F, nu) (``targets`` itself if no pass lowered the cost) and the polish's summary, with
        ``couple`` the polished path's couple (F, 3).
    """
    if any(map(cfg.follows, range(cfg.passes))):
        raise ValueError("a root couple as a control takes no polish.follow")
    t0 = time.perf_counter()
    cost = BodyCost(humanoid, cfg, ref, ref_targets, fall_head_error)

    def replayed(path: np.ndarray, values: np.ndarray) -> PathCost:  # replayed from the clip's start, judged
        got = cost.path_cost(nominal_states(humanoid, start, path, replace(couple, values=values).law(humanoid.nv)),
                             path, 0)  # fmt: skip
        return replace(got, total=got.total + couple.cost(values))

    try:
        best_values = couple.values
        before = replayed(targets, best_values)
        best, after, windows, passes = targets, before, [], []
        for p in range(cfg.passes):
            if p and not passes[-1]["kept"] and cfg.for_pass(p) == cfg.for_pass(p - 1):
                # From the same path with the same settings the pass would do what the dropped one did, bit for bit.
                passes.append({"cost": passes[-1]["cost"], "fell_at": passes[-1]["fell_at"], "kept": False,
                               "repeat_skipped": True})  # fmt: skip
                continue
            new, pass_windows, values = _sweep(humanoid, cost, start, best, cfg.for_pass(p), lqr,
                                               f"{name} pass {p + 1}", log, t0, replace(couple, values=best_values))
            windows += pass_windows
            result = replayed(new, values)
            better = result.total < after.total and (result.fell_at < 0 or after.fell_at >= 0)
            passes.append({"cost": result.total, "fell_at": result.fell_at, "kept": better})
            if better:
                best, after, best_values = new, result, values
            if log is not None:
                print(f"{name}: polish pass {p + 1}/{cfg.passes}: cost {result.total:.4g}"
                      f"{'' if better else ' (dearer or fell: dropped)'}", file=log, flush=True)  # fmt: skip
        if cfg.whole_iterations:
            whole, _, hist = ilqr_couple(humanoid, cost, start, best, 0, replace(cfg, iterations=cfg.whole_iterations),
                                         f"{name} whole path", log, None, replace(couple, values=best_values))
            passes.append({"whole_steps": len(hist) - 1, "cost": hist[-1]["cost"], "kept": len(hist) > 1})
            if len(hist) > 1:
                best, best_values = whole[:, : humanoid.nu], whole[:, humanoid.nu :]
                after = replayed(best, best_values)
            if log is not None:
                print(f"{name}: whole path, {len(hist) - 1} steps: cost {after.total:.4g}", file=log, flush=True)
        worse = best is targets
    finally:
        cost.close()
    summary = {
        "cost_before": before.total, "cost_after": after.total, "kept": not worse,
        "body_rms_mm_before": 1000 * float(np.sqrt(before.body.mean())),
        "body_rms_mm_after": 1000 * float(np.sqrt(after.body.mean())),
        "passes": passes, "windows": windows, "seconds": time.perf_counter() - t0, "couple": best_values,
    }  # fmt: skip
    if log is not None:
        print(f"{name}: polished, cost {before.total:.4g} -> {after.total:.4g}, body rms "
              f"{summary['body_rms_mm_before']:.1f} -> {summary['body_rms_mm_after']:.1f} mm"
              f"{' (worse: the searched path is kept)' if worse else ''}, {summary['seconds']:.0f} s", file=log,
              flush=True)  # fmt: skip
    return best, summary


def _sweep(humanoid: Humanoid, cost: BodyCost, start: np.ndarray, targets: np.ndarray, cfg: PolishConfig,
           lqr: LqrConfig | None, name: str, log: TextIO | None, t0: float,
           couple: Couple) -> tuple[np.ndarray, list, np.ndarray]:  # fmt: skip
    """One pass of windows over the path (see :func:`polish_couple`): its new targets, per window its iterations,
    and its new couple (F, 3)."""
    frames, nu = len(targets), humanoid.model.nu
    values = couple.values.copy()
    law = replace(couple, values=values).law(humanoid.nv)  # the current couple, held, for what is not optimised
    states = nominal_states(humanoid, start, targets, law)
    new = targets.copy()
    window = cfg.window or frames
    stride = cfg.stride or window
    firsts = list(range(0, max(1, frames - window + stride), stride))
    windows = []
    searched, track = states.copy(), None
    if lqr is not None and cfg.window:
        # The couple is a control of the path's LQR too, 100 N m priced as a target radian.
        a, b = linearise(humanoid, searched, targets, lqr.eps, law)
        b = np.concatenate([b, couple_columns(humanoid, searched, targets, law.forces)], axis=2)
        r = np.diag(np.concatenate([np.full(nu, lqr.control), np.full(3, lqr.control / COUPLE_UNIT**2)]))
        track = tracking_gain(a, b, np.diag(state_weights(humanoid, lqr)), r, name, log)
    changed = 0  # frames before this one have been a window's to change
    for j, s in enumerate(firsts):
        e = min(frames, s + window)
        tail = min(frames, e + cfg.lookahead) if cfg.window else e
        init = new[s:tail]
        if track is not None and tail > changed:
            gain = np.zeros((tail - s, *track.shape[1:]))
            gain[max(0, changed - s) :] = track[max(s, changed) : tail]
            unchanged = (np.arange(s, tail) >= changed)[:, None]
            base = np.where(unchanged, targets[s:tail], new[s:tail])
            turn = np.where(unchanged, couple.values[s:tail], values[s:tail])
            _, applied, blown = couple_rollout(humanoid, states[s], searched[s : tail + 1], base, turn,
                                               np.zeros(gain.shape[:2]), gain, np.zeros(1), lqr.limit)  # fmt: skip
            if not blown[0]:  # the couple the LQR gave these frames is where the window's iLQR starts
                init, values[s:tail] = applied[0, :, :nu], applied[0, :, nu:]
        label = f"{name} frames {s}-{e}"
        got, got_states, hist = ilqr_couple(humanoid, cost, states[s], init, s, cfg, label, log, e - s,
                                            replace(couple, values=values))  # fmt: skip
        new[s:tail], values[s:tail], states[s : tail + 1] = got[:, :nu], got[:, nu:], got_states
        changed = max(changed, e)
        windows.append({"first": s, "end": e, "iterations": hist, "searched": False})
        if log is not None:
            print(f"{label} ({j + 1}/{len(firsts)}): cost {hist[0]['cost']:.4g} -> {hist[-1]['cost']:.4g} in "
                  f"{len(hist) - 1} steps, {time.perf_counter() - t0:.0f} s", file=log, flush=True)  # fmt: skip
    return new, windows, values
