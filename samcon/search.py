"""SAMCON: sampling-based tracking of one clip, segment by segment (Liu et al. 2010; the 2015 distribution update).

A clip's first ``F`` control steps are cut into segments of ``segment_frames`` steps. For each segment, from the
saved full MuJoCo states of the ``keep`` samples kept at the end of the previous one (the clip's start state for the
first), ``samples`` candidates are simulated, one character each, in one batched rollout: candidate i starts from
kept state ``i mod keep`` and holds the PD targets ``reference next-frame hinge angles + offset_i`` for the whole
segment, ``offset_i = guide(s_i) + mean + sigma * z_i`` with z standard normal and s the kept state's feedback
features (``guide`` is 0 unless the search is re-run around linear feedback policies; with a ``centre`` path its
targets replace the reference's angles). Each candidate is scored by the tracking cost averaged over the segment's
frames. After each of ``iterations`` rounds, mean and sigma (one per actuator, CMA-style diagonal) move to the
log-weighted ``elite`` of the round; the best ``keep`` of all rounds are kept. When even the cheapest kept sample
has fallen (the evaluator's head rule), the search goes back ``backtrack_segments`` segments and searches them again
with more rounds. At the end, the lowest-cost kept sample is traced back through its parents: the open-loop
trajectory.

The physics is :class:`common.sim.physics.BatchedSim`, stepped one control step per rollout like the gym, so that the
trajectory replays bit-exactly in the shared evaluator from the same start state (MuJoCo's solver warm start is
reset at every rollout call, so a segment simulated as one long rollout would not).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import numpy as np

from common.character.humanoid import Humanoid
from common.character.kinematics import ForwardKinematics
from common.character.state import CharacterState
from common.motion.library import MotionLibrary
from common.sim.gym import GymConfig, TrackingGym
from common.sim.physics import BatchedSim
from samcon.config import CostConfig, SearchConfig
from samcon.cost import COST_TERMS, feedback_features, tracking_cost


class SearchAbandoned(Exception):
    """A search stopped because every path it could still return already costs more than ``cost_limit``."""

    def __init__(self, segment: int, bound: float, samples: int, seconds: float) -> None:
        super().__init__(f"abandoned at segment {segment + 1}: its cheapest kept path already costs {bound:.4g}")
        self.samples, self.seconds = samples, seconds


Guide = Callable[[int, np.ndarray], np.ndarray]
"""(segment k, feedback features (n, D)) -> base offsets (n, nu)."""


class ExternalForce(Protocol):
    """An external generalised force on the character (MuJoCo's ``qfrc_applied``, see
    :class:`common.sim.physics.BatchedSim`), a function of the clip frame and the state, held over each control step
    like the PD targets. The tracker itself applies none (the gym and the evaluator have no such force); the search, the
    replay, the linearisation and the polish take one so that a path can be made and judged under it. A path made
    with one is still open loop: replayed with the same force from the same start it passes through the same states.

    ``force(f, qpos (n, nq), qvel (n, nv))`` is the force held over step f -> f + 1, (n, nv);
    ``force.jacobian(f, qpos, qvel)`` its derivative with respect to the state's tangent coordinates (MuJoCo's:
    ``mj_differentiatePos`` of qpos, then qvel), (n, nv, 2 nv), which the linearisation of :mod:`samcon.lqr` adds
    to the dynamics' own.
    """

    def __call__(self, frame: int, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray: ...

    def jacobian(self, frame: int, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray: ...

Progress = Callable[[int, int, float, float, "int | None"], None]
"""(segment k, segments, cost of the best kept sample, seconds so far, the segment a backtrack returns to or None)."""


@dataclass
class Trajectory:
    """SAMCON's result for one clip. S segments, F frames, D features.

    Attributes:
        clip: Clip name.
        start_state: The full MuJoCo state it starts from (the gym's reset at t = 0). Shape: (nstate,).
        targets: Absolute PD targets of every control step from ``bounds[0]``. Shape: (F - bounds[0], nu).
        offsets: The chosen offset of every segment (on the reference's next-frame hinge angles, or on the search's
            ``centre``). Shape: (S, nu).
        bounds: First frame of every segment and the last frame F (the first is 0 unless the search started later).
            Shape: (S + 1,).
        segment_cost: Tracking cost of the chosen sample in every segment. Shape: (S,).
        segment_terms: Its unweighted cost terms (mean over the segment), {name: (S,)}; ``fallen``: frames fallen.
        end_states: Full state of the chosen sample at every segment's end. Shape: (S, nstate).
        samples: Candidates simulated in all.
        seconds: Wall-clock of the search.
        features: Per segment, the feedback features of the regression samples' start states, [(n_k, D)].
        actions: Per segment, their offsets, [(n_k, nu)].
        kept_cost: Per segment, the costs of the samples kept, lowest first, [(keep,)].
        path_features: Feedback features of the chosen path at every segment's start. Shape: (S, D).
        backtracks: Times the search went back because every kept sample of a segment had fallen.
        feedback_seconds: Wall-clock of the extra searches for the feedback regression (``feedback.starts``).
        feedback_samples: Candidates they simulated.
        sigma: The ``sigma_init`` of the search (rad).
        optimise: With ``optimise.generations`` > 0, the closed-loop gain search's summary and learning curve
            (:func:`samcon.optimise.optimise_gains`) and its ``seconds``.
        lqr: With ``lqr.enabled``, the LQR paths' summary (:func:`samcon.lqr.grow_paths`).
        polish: With ``polish.iterations`` > 0, the iLQR polish's summary (:func:`samcon.polish.polish`); the
            targets, offsets (then each segment's mean), segment costs (then without the look-ahead), terms and end
            states are the polished path's.
        visits: With ``feedback.visit_iterations`` > 0, per round: the share of its episodes that fell before the
            round's searches, and how many searches it ran.
    """

    clip: str
    start_state: np.ndarray
    targets: np.ndarray
    offsets: np.ndarray
    bounds: np.ndarray
    segment_cost: np.ndarray
    segment_terms: dict[str, np.ndarray]
    end_states: np.ndarray
    samples: int
    seconds: float
    features: list[np.ndarray]
    actions: list[np.ndarray]
    kept_cost: list[np.ndarray]
    path_features: np.ndarray
    backtracks: int = 0
    feedback_seconds: float = 0.0
    feedback_samples: int = 0
    sigma: float = 0.0
    optimise: dict[str, Any] | None = None
    visits: list[dict[str, Any]] | None = None
    lqr: dict[str, Any] | None = None
    polish: dict[str, Any] | None = None

    @property
    def frames(self) -> int:
        """Control steps tracked (from the first segment's start)."""
        return int(self.bounds[-1] - self.bounds[0])


def horizon(library: MotionLibrary, clip: int, max_frames: int) -> int:
    """Control steps the shared evaluator plays from the clip's start (loop clips: max_frames)."""
    return int(max_frames if library.loop[clip] else min(max_frames, library.num_frames[clip] - 1))


def searched_frames(library: MotionLibrary, clip: int, frames: int, lookahead: int) -> int:
    """Control steps a search of a clip's first ``frames`` plays from its start, ``lookahead`` more past the last
    segment included (a one-shot clip: at most to its last frame); an external force must cover as many."""
    beyond = lookahead if library.loop[clip] else min(lookahead, max(0, library.num_frames[clip] - 1 - frames))
    return int(frames + beyond)


def start_state(library: MotionLibrary, humanoid: Humanoid, clip: int, rsi_lift: bool = False,
                time: float = 0.0) -> np.ndarray:  # fmt: skip
    """The full MuJoCo state the gym resets clip ``clip`` to at ``time`` (s). Shape: (nstate,)."""
    gym = TrackingGym(GymConfig(num_envs=1, threads=1, physics=humanoid.physics, rsi_lift=rsi_lift), library, humanoid)
    try:
        gym.reset(clips=np.array([clip]), times=np.array([time]))
        return gym.sim.state[0].copy()
    finally:
        gym.close()


def cycle_frames(library: MotionLibrary, clip: int) -> int:
    """Control steps of one cycle of a loop clip (the evaluator's rule), 0 for a one-shot clip."""
    return int(round(library.duration[clip] / library.dt)) if library.loop[clip] else 0


def segment_bounds(library: MotionLibrary, clip: int, frames: int, segment_frames: int,
                   align_cycle: bool = False) -> np.ndarray:  # fmt: skip
    """First frame of every segment of frames [0, ``frames``) and ``frames`` itself. Shape: (S + 1,).

    Every ``segment_frames`` from 0; with ``align_cycle`` and a loop clip of C frames per cycle, each cycle is cut
    into m = round(C / segment_frames) segments at ``q C + round(j C / m)``, j < m, the same phases in every cycle.
    """
    cycle = cycle_frames(library, clip)
    if not (align_cycle and cycle):
        return np.append(np.arange(0, frames, segment_frames), frames)
    m = max(1, int(round(cycle / segment_frames)))
    phases = np.rint(np.arange(m) * cycle / m).astype(np.int64)
    starts = (np.arange(int(np.ceil(frames / cycle)))[:, None] * cycle + phases).ravel()
    return np.append(starts[starts < frames], frames)


def reference_frames(library: MotionLibrary, clip: int, frames: int) -> CharacterState:
    """The reference at frames 0..F, each time computed as the gym does (previous time + dt). Leading shape (F+1,)."""
    dt = library.dt
    times = np.concatenate([[0.0], np.arange(frames) * dt + dt])
    return library.query(np.full(frames + 1, clip), times)


def _log_weights(n: int) -> np.ndarray:
    """CMA-ES recombination weights ln(n + 1/2) - ln(i), normalised. Shape: (n,)."""
    w = np.log(n + 0.5) - np.log(np.arange(1, n + 1))
    return w / w.sum()


def samcon(humanoid: Humanoid, library: MotionLibrary, clip: int, frames: int, search: SearchConfig,
           cost: CostConfig, rng: np.random.Generator, *, threads: int = 1, max_speed: float = 1000.0,
           guide: Guide | None = None, regression_samples: int = 60,
           regression: Literal["cheapest", "per_state"] = "cheapest", fresh_share: float = 0.0,
           fresh_states: int = 1, fresh_noise: tuple[float, float] = (0.0, 0.0),
           rsi_lift: bool = False, progress: Progress | None = None, start_frame: int = 0,
           end_frame: int | None = None, cost_limit: float = np.inf,
           start: np.ndarray | None = None, force: ExternalForce | None = None,
           centre: np.ndarray | None = None) -> Trajectory:  # fmt: skip
    """Tracks the first ``frames`` control steps of clip ``clip`` from its start (see the module docstring).

    Args:
        guide: Base offsets from the feedback features (None: 0).
        regression_samples: Lowest-cost candidates per segment kept for the feedback regression (``cheapest``).
        regression: ``cheapest``: those; ``per_state``: for every distinct start state of the segment (each kept
            state, and the reference for the fresh candidates), its lowest-cost candidate of all rounds, so that
            the regression sees the best offset as a function of the start state, not which states were cheapest.
        fresh_share: Share of each round's candidates started on the reference state at the segment's start instead
            of a kept state (as an evaluation episode starts): they enter the regression only, never the kept states
            (the trajectory must be continuous) nor the distribution update.
        fresh_states: Distinct such states per segment, drawn once per segment: candidate i of the fresh ones
            starts from state ``i mod fresh_states``.
        fresh_noise: Standard deviations of the root's linear (m/s) and angular (rad/s) velocity added to those
            states' reference velocities, so that the regression sees the pushes and stumbles the policy must
            correct (0, 0: all are the reference state).
        rsi_lift: The gym's start lift (must match the evaluator's).
        start_frame: Start on the reference state of this frame (a segment start of the grid of ``frames``, see
            :func:`segment_bounds`, so that the segments are those of a search from frame 0) and track to frame
            ``end_frame``: the feedback regression's samples from states a search from the clip's start never visits.
        end_frame: The last frame tracked, a segment start of that grid or ``frames`` (None: ``frames``).
        start: The full MuJoCo state (nstate,) to start from at ``start_frame`` instead of the reference's there
            (e.g. one the feedback policy reached: the searches of ``feedback.visit_iterations``).
        force: An external generalised force on every candidate at every step, from its state (None: none, as in
            the gym); it must cover :func:`searched_frames` steps from frame 0. The trajectory replays with it
            (:func:`replay`'s ``force``).
        cost_limit: Raise :class:`SearchAbandoned` as soon as the cheapest kept sample's cost summed along its
            parents exceeds this: costs are never negative, so a trajectory through the kept samples can only cost
            more (a later backtrack could in principle re-search the last segments cheaper; it is not waited for).
        centre: PD targets of steps 0, 1, ... (G, nu) that the candidates' offsets are drawn around instead of the
            reference's next-frame hinge angles (steps past G: the reference's): a search around a path made
            another way (e.g. under an external force that is then taken away). The offsets are then on it.
    """
    grid = segment_bounds(library, clip, frames, search.segment_frames, search.align_cycle)
    end_frame = frames if end_frame is None else end_frame
    if start_frame not in grid[:-1] or end_frame not in grid or end_frame <= start_frame:
        raise ValueError(f"start_frame {start_frame} and end_frame {end_frame} must be segment starts of the grid "
                         f"of {frames} frames (or its end), in order")
    t0 = time.perf_counter()
    n, nu, hinge = search.samples, humanoid.nu, humanoid.hinge_qpos
    # The reference past the last frame too, for the look-ahead (a one-shot clip only to its end).
    ref = reference_frames(library, clip, searched_frames(library, clip, frames, search.lookahead_frames))
    centres = ref.qpos[1:, hinge].copy()  # the targets an offset of 0 gives at step f -> f + 1
    if centre is not None:
        g = min(len(centre), len(centres))
        centres[:g] = np.asarray(centre, dtype=float)[:g]
    bounds = grid[(grid >= start_frame) & (grid <= end_frame)]
    nseg = len(bounds) - 1
    sim = BatchedSim(humanoid, n, threads, max_speed, applied=force is not None)
    fk = ForwardKinematics(humanoid, threads)
    # The start time as the gym reaches frame start_frame from 0 (previous time + dt), as reference_frames does.
    t_start = 0.0 if start_frame == 0 else (start_frame - 1) * library.dt + library.dt
    start = start_state(library, humanoid, clip, rsi_lift, t_start) if start is None else np.array(start, dtype=float)
    nq, nv = humanoid.nq, humanoid.nv
    fresh = np.arange(n) >= n - int(round(fresh_share * n))
    n_fresh_states = max(1, fresh_states) if fresh_noise[0] > 0 or fresh_noise[1] > 0 else 1
    fresh_of = np.where(fresh, np.arange(n) % n_fresh_states, 0)
    fresh_state = np.zeros((n_fresh_states, len(start)))
    # What segment k starts from: the kept states and the previous segment's final mean (a backtrack returns here).
    kept_at: dict[int, tuple[np.ndarray, np.ndarray]] = {0: (start[None], np.zeros(nu))}
    prefix_at = {0: np.zeros(1)}  # per kept state: the cost of its path so far
    rounds_of = np.full(nseg, search.iterations)
    sigma_of = np.full(nseg, search.sigma_init)
    history: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray], np.ndarray]] = []
    features: list[np.ndarray] = []
    actions: list[np.ndarray] = []
    samples = backtracks = 0
    k = 0
    try:
        while k < nseg:
            f0, f1 = int(bounds[k]), int(bounds[k + 1])
            kept, mean = kept_at[k]
            kept_fk = fk(kept[:, 1 : 1 + nq].copy(), kept[:, 1 + nq : 1 + nq + nv].copy())
            kept_feat = feedback_features(humanoid, kept_fk, ref[np.full(len(kept), f0)])
            mean, sigma = search.mean_carry * mean, np.full(nu, sigma_of[k])
            fresh_state[:, 1 : 1 + nq], fresh_state[:, 1 + nq : 1 + nq + nv] = ref.qpos[f0], ref.qvel[f0]
            if n_fresh_states > 1:
                # The free joint's velocity: linear (world frame) then angular (body frame; the noise is isotropic).
                fresh_state[:, 1 + nq : 1 + nq + 3] += fresh_noise[0] * rng.standard_normal((n_fresh_states, 3))
                fresh_state[:, 1 + nq + 3 : 1 + nq + 6] += fresh_noise[1] * rng.standard_normal((n_fresh_states, 3))
            fresh_qvel = fresh_state[:, 1 + nq : 1 + nq + nv]
            fresh_feat = feedback_features(humanoid, fk(fresh_state[:, 1 : 1 + nq].copy(), fresh_qvel.copy()),
                                           ref[np.full(n_fresh_states, f0)])  # fmt: skip
            rounds = []
            for r in range(int(rounds_of[k])):
                parent = np.arange(n) % len(kept)
                starts, feat = kept[parent], kept_feat[parent]
                starts[fresh], feat[fresh] = fresh_state[fresh_of[fresh]], fresh_feat[fresh_of[fresh]]
                base = guide(k, feat) if guide is not None else np.zeros((n, nu))
                # The last round samples narrower around the elite's mean (search.final_scale).
                width = sigma * (search.final_scale if r == rounds_of[k] - 1 and r > 0 else 1.0)
                noise = mean + width * rng.standard_normal((n, nu))
                offset = base + noise
                c, terms, end = _simulate(sim, fk, humanoid, cost, starts, offset, ref, f0, f1, centres,
                                          search.lookahead_frames, search.lookahead_weight, force)  # fmt: skip
                rounds.append((parent, offset, c, end, terms, feat, fresh))
                elite = np.flatnonzero(~fresh)[np.argsort(c[~fresh], kind="stable")[: search.elite]]
                w = _log_weights(len(elite))
                mean = w @ noise[elite]
                spread = np.sqrt(w @ (noise[elite] - mean) ** 2)
                sigma = np.maximum(search.sigma_min, (1 - search.sigma_rate) * sigma + search.sigma_rate * spread)
            samples += n * len(rounds)
            parent, offset, c, end, _, feat, was_fresh = (np.concatenate([r[i] for r in rounds]) if i != 4 else None
                                                          for i in range(7))  # fmt: skip
            terms = {key: np.concatenate([r[4][key] for r in rounds]) for key in rounds[0][4]}
            order = np.argsort(c, kind="stable")
            best = order[~was_fresh[order]][: search.keep]
            if terms["fallen"][best[0]] > 0 and backtracks < search.max_backtracks and search.backtrack_segments > 0:
                # Even the cheapest sample fell: search the last few segments again, each with more rounds.
                back = max(0, k - search.backtrack_segments)
                rounds_of[back : k + 1] = np.minimum(rounds_of[back : k + 1] + search.iterations, search.max_rounds)
                if search.backtrack_sigma is not None:
                    sigma_of[back : k + 1] = np.maximum(sigma_of[back : k + 1], search.backtrack_sigma)
                del history[back:], features[back:], actions[back:]
                backtracks += 1
                if progress is not None:
                    progress(k, nseg, float(c[best[0]]), time.perf_counter() - t0, back)
                k = back
                continue
            if regression == "per_state":
                # One per start state: its cheapest candidate (fresh ones: per fresh state).
                state = np.where(was_fresh, -1 - np.tile(fresh_of, len(rounds)), parent)
                first = np.unique(state[order], return_index=True)[1]
                good = order[np.sort(first)]
                good = good[np.isfinite(c[good])]
            else:
                good = order[:regression_samples][np.isfinite(c[order[:regression_samples]])]
            features.append(feat[good])
            actions.append(offset[good])
            history.append((parent[best], offset[best], c[best], end[best], {k_: v[best] for k_, v in terms.items()},
                            kept_feat[parent[best]]))  # fmt: skip
            kept_at[k + 1] = (end[best], mean)
            prefix_at[k + 1] = prefix_at[k][parent[best]] + c[best]
            if progress is not None:
                progress(k, nseg, float(c[best[0]]), time.perf_counter() - t0, None)
            if prefix_at[k + 1].min() > cost_limit:
                raise SearchAbandoned(k, float(prefix_at[k + 1].min()), samples, time.perf_counter() - t0)
            k += 1
    finally:
        sim.close()
        fk.close()
    traj = _trace_back(library.names[clip], start, history, centres, bounds, samples, time.perf_counter() - t0,
                       features, actions)  # fmt: skip
    traj.backtracks, traj.sigma = backtracks, search.sigma_init
    return traj


def _simulate(sim: BatchedSim, fk: ForwardKinematics, humanoid: Humanoid, cost: CostConfig, starts: np.ndarray,
              offset: np.ndarray, ref: CharacterState, f0: int, f1: int, centres: np.ndarray, lookahead: int = 0,
              lookahead_weight: float = 1.0,
              force: ExternalForce | None = None) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:  # fmt: skip
    """Simulates every candidate through frames [f0, f1) from ``starts`` (n, nstate) with targets ``centres[f]`` +
    ``offset`` at step f (the reference's next-frame hinge angles unless the search has a centre path; and, with
    ``force``, the generalised force it gives each over every step).

    With ``lookahead`` > 0 each candidate plays on for that many frames past the segment (the same offset held,
    at most to the reference's last frame), and ``lookahead_weight`` times that stretch's mean cost joins its
    cost: a state that tracks the segment well but cannot go on (a take-off short of height) ranks lower. The end
    state and the terms stay the segment's own.

    Returns:
        cost: Mean tracking cost over the segment's frames (plus the weighted look-ahead cost), inf for a blown-up
            simulation. Shape: (n,).
        terms: Mean unweighted terms of the segment, {name: (n,)}; ``fallen``: frames fallen.
        end: Full state at the segment's end. Shape: (n, nstate).
    """
    n = len(starts)
    sim.state[:] = starts
    total = np.zeros(n)
    sums = {key: np.zeros(n) for key in (*COST_TERMS, "fallen")}
    blown = np.zeros(n, dtype=bool)
    for f in range(f0, f1):
        blown |= sim.step(centres[f][None] + offset, _force(force, f, sim))
        # A blown-up character is put back on its start so that no NaN reaches the kinematics; it is never kept.
        sim.state[blown] = starts[blown]
        now = fk(sim.qpos.copy(), sim.qvel.copy())
        c, terms = tracking_cost(humanoid, cost, now, ref[np.full(n, f + 1)])
        total += c
        for key in sums:
            sums[key] += terms[key]
    frames = f1 - f0
    end = sim.state.copy()
    total /= frames
    ahead = range(f1, min(f1 + lookahead, len(ref.qpos) - 1))
    if len(ahead):
        more = np.zeros(n)
        for f in ahead:
            blown_ahead = sim.step(centres[f][None] + offset, _force(force, f, sim))
            sim.state[blown_ahead | blown] = end[blown_ahead | blown]
            more += tracking_cost(humanoid, cost, fk(sim.qpos.copy(), sim.qvel.copy()), ref[np.full(n, f + 1)])[0]
        total += lookahead_weight * more / len(ahead)
    total = np.where(blown, np.inf, total)
    return total, {k: v / (frames if k != "fallen" else 1) for k, v in sums.items()}, end


def _force(force: ExternalForce | None, frame: int, sim: BatchedSim) -> np.ndarray | None:
    return None if force is None else force(frame, sim.qpos, sim.qvel)


def _trace_back(name: str, start: np.ndarray, history: list, centres: np.ndarray, bounds: np.ndarray,
                samples: int, seconds: float, features: list[np.ndarray],
                actions: list[np.ndarray]) -> Trajectory:  # fmt: skip
    """The lowest-cost kept sample of the last segment, traced back through its parents to the start."""
    nseg = len(history)
    j = int(np.argmin(history[-1][2]))
    chosen = np.zeros(nseg, dtype=np.int64)
    for k in range(nseg - 1, -1, -1):
        chosen[k] = j
        j = int(history[k][0][j])
    offsets = np.stack([history[k][1][chosen[k]] for k in range(nseg)])
    per_frame = np.repeat(offsets, np.diff(bounds), axis=0)
    targets = centres[int(bounds[0]) : int(bounds[-1])] + per_frame
    return Trajectory(
        clip=name, start_state=start, targets=targets, offsets=offsets, bounds=bounds,
        segment_cost=np.array([history[k][2][chosen[k]] for k in range(nseg)]),
        segment_terms={key: np.array([history[k][4][key][chosen[k]] for k in range(nseg)]) for key in history[0][4]},
        end_states=np.stack([history[k][3][chosen[k]] for k in range(nseg)]), samples=samples, seconds=seconds,
        features=features, actions=actions, kept_cost=[h[2] for h in history],
        path_features=np.stack([history[k][5][chosen[k]] for k in range(nseg)]),
    )  # fmt: skip


def replay(humanoid: Humanoid, start: np.ndarray, targets: np.ndarray, max_speed: float = 1000.0,
           force: ExternalForce | None = None, first: int = 0) -> np.ndarray:  # fmt: skip
    """Plays PD targets (F, nu) open loop from a full state (nstate,), with ``force`` the external force of every
    step too (``start`` at clip frame ``first``); the state after every step, (F, nstate)."""
    sim = BatchedSim(humanoid, 1, 0, max_speed, applied=force is not None)
    out = np.zeros((len(targets), len(start)))
    try:
        sim.state[0] = start
        for f, target in enumerate(targets):
            sim.step(target[None], _force(force, first + f, sim))
            out[f] = sim.state[0]
    finally:
        sim.close()
    return out
