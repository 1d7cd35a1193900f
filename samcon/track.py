"""``track-samcon``: SAMCON open-loop trajectories and linear feedback policies for clips, as a run directory.

For every clip: SAMCON from the clip's start (:mod:`samcon.search`), a linear feedback policy per segment regressed
from its samples (:mod:`samcon.feedback`), optionally refined by re-running SAMCON around it; then both judged by
the shared evaluator: the open-loop trajectory from the clip's start (one episode per clip), the feedback policy
under the run's protocol. The run directory holds ``config.yaml``, ``run_info.json``, ``samcon.h5``,
``progress.log`` and ``results.json`` (with ``optimise.generations`` > 0 also ``optimise.png``, the closed-loop gain
search's learning curves).

Example::

    track-samcon --motions walk run --out runs/samcon-walk-run
    track-samcon --config configs/samcon/debug.yaml --motions walk --out runs/samcon-debug
"""

from __future__ import annotations

import argparse
import json
import time
import zlib
from collections.abc import Sequence
from dataclasses import replace
from datetime import datetime
from typing import Any

import numpy as np

from common.bundled_configs import config_help, default_config, resolve_config
from common.character.humanoid import Humanoid
from common.character.kinematics import ForwardKinematics
from common.cli import CommandParser, fail, non_negative_int, one_line_errors, os_error_line
from common.config import ConfigError, atomic_output, load_config
from common.evaluation.evaluate import EvalConfig, EvalResult, evaluate
from common.motion.dataset import load_motions
from common.motion.library import MotionLibrary
from common.motion.motion import MotionFormatError
from common.run.directory import RunDir, RunDirError
from samcon import store
from samcon.config import FeedbackConfig, SamconConfig
from samcon.cost import COST_TERMS, tracking_cost
from samcon.feedback import ClipPlan, FeedbackPolicy, fit_linear, open_loop_policy
from samcon.lqr import evaluation_policy, grow_paths, play_until_falls
from samcon.optimise import optimise_gains, plot_history, reduced_indices
from samcon.polish import Searcher, polish
from samcon.search import (
    ExternalForce,
    Progress,
    SearchAbandoned,
    Trajectory,
    cycle_frames,
    horizon,
    reference_frames,
    replay,
    samcon,
)

LEARNER = "samcon"


def fit_policies(traj: Trajectory, config: FeedbackConfig, extra: Sequence[Trajectory] = (),
                 cycle_segments: int = 0) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """One linear map per segment (or per segment of the cycle) from its regression samples: gain (K, nu, D),
    bias (K, nu)."""
    return anchored(traj, config, *fit_samples(traj, config, extra, cycle_segments))


def _segment_keys(first: int, count: int, cycle_segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Where segments ``first``, ... ``first + count - 1`` of the grid go: their policy (the segment itself, or
    the segment of the cycle with ``cycle_segments`` > 0) and their cycle (0 without). Shapes: (count,) each."""
    g = first + np.arange(count)
    return (g, np.zeros_like(g)) if not cycle_segments else (g % cycle_segments, g // cycle_segments)


def fit_samples(traj: Trajectory, config: FeedbackConfig, extra: Sequence[Trajectory] = (),
                cycle_segments: int = 0) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The lectures' regression on every segment's samples: gain (K, nu, D), bias (K, nu).

    ``extra`` are searches started later in the clip (``feedback.starts``) on the same segment grid: their samples of
    a segment join ``traj``'s in that segment's regression. With ``cycle_segments`` (m) > 0 there is one policy per
    segment of a loop clip's cycle (``feedback.index: phase``): segment g of the grid is policy g mod m, fitted on the
    samples of that phase in every cycle of every search (K = m); else K is ``traj``'s number of segments.
    """
    keys = cycle_segments or len(traj.features)
    groups: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in range(keys)]
    for path in (traj, *extra):
        key_of = _segment_keys(pooled_offset(traj, path), len(path.features), cycle_segments)[0]
        for key, s, a in zip(key_of, path.features, path.actions, strict=True):
            groups[key].append((s, a))
    fits = [fit_linear(np.concatenate([s for s, _ in g]), np.concatenate([a for _, a in g]), config.ridge)
            for g in groups]  # fmt: skip
    return np.stack([m for m, _ in fits]), np.stack([b for _, b in fits])


def pooled_offset(traj: Trajectory, later: Trajectory) -> int:
    """Segments of ``traj`` before ``later``'s first (both on one grid from frame 0)."""
    return int(np.searchsorted(traj.bounds, later.bounds[0]))


def extra_starts(grid: np.ndarray, cycle: int, count: int, rng: np.random.Generator) -> list[int]:
    """``count`` segment starts after 0 of ``grid`` (see :func:`samcon.search.segment_bounds`) within the clip's
    first cycle (loop clips, ``cycle`` frames) or the tracked range (one-shot clips, ``cycle`` 0), where the
    evaluator's episodes start: distinct ones drawn with ``rng``; more than there are: each in turn, then a draw of
    the rest. Sorted."""
    span = cycle if cycle else int(grid[-1])
    choices = grid[(grid > 0) & (grid < min(span, int(grid[-1])))]
    if count <= len(choices):
        return sorted(int(f) for f in rng.choice(choices, size=count, replace=False))
    whole, rest = divmod(count, len(choices))
    return sorted(int(f) for f in np.concatenate([np.tile(choices, whole), rng.choice(choices, rest, replace=False)]))


def anchored(traj: Trajectory, config: FeedbackConfig, gain: np.ndarray, bias: np.ndarray) -> tuple[np.ndarray, ...]:
    """With ``feedback.anchor: path`` (or ``nearest``, whose first path is this one), the bias that puts ``traj``'s
    offsets at its own start features (per segment of the cycle: its first cycle's)."""
    if config.anchor in ("path", "nearest"):
        k = len(gain)
        bias = traj.offsets[:k] - np.einsum("kad,kd->ka", gain, traj.path_features[:k])
    return gain, bias


def path_anchors(traj: Trajectory, extra: Sequence[Trajectory] = (),
                 cycle_segments: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Every searched path's start features and offsets per segment of ``traj``'s grid (NaN where a path does not
    cover a segment), path 0 being ``traj``, and the features' spread over all regression samples. With
    ``cycle_segments`` (m) > 0, per segment of the cycle: column ``p Q + q`` holds path p's segment of that phase
    in cycle q (Q cycles at most).

    Returns:
        anchor_features (K, P Q, D), anchor_offsets (K, P Q, nu), feature_scale (D,).
    """
    paths = [traj, *extra]
    (nseg, dim), nu = traj.path_features.shape, traj.offsets.shape[1]
    keys, cycles = (nseg, 1) if not cycle_segments else (cycle_segments, -(-nseg // cycle_segments))
    features = np.full((keys, len(paths) * cycles, dim), np.nan)
    offsets = np.full((keys, len(paths) * cycles, nu), np.nan)
    for p, path in enumerate(paths):
        first = pooled_offset(traj, path)
        if first + len(path.offsets) > nseg or first >= nseg or traj.bounds[first] != path.bounds[0]:
            raise ValueError(f"{traj.clip}: a search from frame {path.bounds[0]} is not on the clip's segment grid")
        key, cycle = _segment_keys(first, len(path.offsets), cycle_segments)
        features[key, p * cycles + cycle], offsets[key, p * cycles + cycle] = path.path_features, path.offsets
    pooled = np.concatenate([s for path in paths for s in path.features])
    return features, offsets, np.maximum(pooled.std(axis=0), 1e-6)


def visited_states(plan: ClipPlan, name: str, library: MotionLibrary, humanoid: Humanoid, grid: np.ndarray,
                   span: int, segments: int, fb: FeedbackConfig, ev: EvalConfig, rng: np.random.Generator,
                   threads: int = 1) -> tuple[list[tuple[int, np.ndarray]], float]:  # fmt: skip
    """Where the policy of ``plan`` goes wrong: it plays ``fb.visit_episodes`` episodes from the reference at segment
    starts of ``grid`` before frame ``span`` (stratified draws), under the evaluator's failure rule, for at most
    ``fb.visit_frames`` steps within the grid; of each episode that fails at frame t, the simulated state at the last
    segment start at or before ``t - fb.visit_lead`` (not before the episode's start) from which ``segments`` segments
    remain on the grid.

    Returns:
        [(frame, full MuJoCo state (nstate,))] of the failed episodes, and the share of the episodes that failed.
    """
    clip = library.clip_index(name)
    starts = grid[:-1][grid[:-1] < max(1, span)]
    n = fb.visit_episodes
    # Stratified over the start segments: one draw in each of n equal stretches of them.
    first = starts[np.minimum(((np.arange(n) + rng.random(n)) * len(starts) / n).astype(np.int64), len(starts) - 1)]
    on_grid = {int(f): i for i, f in enumerate(grid)}
    steps = int(min(fb.visit_frames, grid[-1] - first.min()))
    states, failed = play_until_falls(FeedbackPolicy({name: plan}, library, humanoid), library, humanoid, clip, first,
                                      steps, int(grid[-1]), on_grid, ev, threads)  # fmt: skip
    out = []
    for i in np.flatnonzero(failed >= 0):
        ok = [f for f in states[i] if f <= failed[i] - fb.visit_lead and on_grid[f] + segments <= len(grid) - 1]
        if ok:
            out.append((max(ok), states[i][max(ok)]))
    return out, float(np.mean(failed >= 0))


def _plan_bounds(traj: Trajectory, m: int) -> np.ndarray:
    """The segments a plan's policies index: the first cycle's with m > 0 policies per cycle, else all of them."""
    return traj.bounds[: m + 1] if m else traj.bounds


def _plan(traj: Trajectory, fb: FeedbackConfig, paths: Sequence[Trajectory], m: int) -> ClipPlan:
    """The feedback policies fitted on ``traj`` and ``paths``: per segment, or per segment of the cycle (m > 0),
    whose plan segments are then the first cycle's (the evaluator's policy maps later frames back to it)."""
    plan = ClipPlan(traj.targets, _plan_bounds(traj, m), *fit_policies(traj, fb, paths, m))
    if fb.anchor == "nearest":
        plan.anchor_features, plan.anchor_offsets, plan.feature_scale = path_anchors(traj, paths, m)
    return plan


def segment_progress(name: str, log: Any) -> Progress:
    """The search's progress line per segment (and per backtrack) for clip ``name``, into ``log``."""

    def progress(k: int, segments: int, best: float, seconds: float, back: int | None) -> None:
        again = "" if back is None else f": every kept sample fell, back to segment {back + 1}"
        print(f"{name} segment {k + 1}/{segments} cost {best:.4g} {seconds:.0f} s{again}", file=log, flush=True)

    return progress


def track_clip(cfg: SamconConfig, humanoid: Humanoid, library: MotionLibrary, clip: int, rng: np.random.Generator,
               log: Any) -> tuple[Trajectory, ClipPlan]:  # fmt: skip
    """SAMCON on one clip, the feedback fit, and its refinements; prints progress per segment into ``log``."""
    name, frames = library.names[clip], horizon(library, clip, cfg.train.max_frames)

    progress = segment_progress(name, log)
    fb = cfg.feedback
    common = dict(threads=cfg.train.threads, max_speed=cfg.gym.max_speed, regression_samples=fb.samples,
                  regression=fb.regression, fresh_share=fb.fresh_share, fresh_states=fb.fresh_states,
                  fresh_noise=(fb.fresh_linvel_noise, fb.fresh_angvel_noise), rsi_lift=cfg.train.eval.rsi_lift,
                  progress=progress)  # fmt: skip
    choices = cfg.search.sigma_choices
    search = replace(cfg.search, sigma_init=choices[0]) if choices else cfg.search
    traj = samcon(humanoid, library, clip, frames, search, cfg.cost, rng, **common)
    costs = [f"{traj.sigma:g}: {traj.segment_cost.sum():.17g}"]
    for sigma in choices[1:]:
        print(f"{name}: searched at sigma {traj.sigma:g}, now at {sigma:g}", file=log, flush=True)
        try:
            # Stopped once it cannot beat the best so far (the choice is the same, the minutes fewer).
            other = samcon(humanoid, library, clip, frames, replace(search, sigma_init=sigma), cfg.cost, rng,
                           cost_limit=float(traj.segment_cost.sum()), **common)  # fmt: skip
        except SearchAbandoned as e:
            costs.append(f"{sigma:g}: {e}")
            traj = replace(traj, samples=traj.samples + e.samples, seconds=traj.seconds + e.seconds)
            continue
        costs.append(f"{sigma:g}: {other.segment_cost.sum():.17g}")
        best = other if other.segment_cost.sum() < traj.segment_cost.sum() else traj
        traj = replace(best, samples=traj.samples + other.samples, seconds=traj.seconds + other.seconds)
    if choices:
        print(f"{name}: kept the search at sigma {traj.sigma:g} (total cost by sigma: {', '.join(costs)})", file=log,
              flush=True)  # fmt: skip
        search = replace(search, sigma_init=traj.sigma)
    grid, cycle = traj.bounds, cycle_frames(library, clip)
    # Per segment of the cycle (feedback.index: phase) where the search covers a whole cycle; else per segment.
    m = int(np.sum(grid[:-1] < cycle)) if fb.index == "phase" and cycle and grid[-1] >= cycle else 0
    extra = []
    for first in extra_starts(grid, cycle, fb.starts, rng):
        i = int(np.searchsorted(grid, first))
        end = int(grid[min(i + fb.start_segments, len(grid) - 1)]) if fb.start_segments else frames
        print(f"{name}: a search from frame {first} to {end} for the feedback regression", file=log, flush=True)
        extra.append(samcon(humanoid, library, clip, frames, search, cfg.cost, rng, start_frame=first,
                            end_frame=end, **common))  # fmt: skip
    from_reference = list(extra)  # the feedback.starts searches (each also gets an LQR with lqr.enabled)
    feedback_seconds = sum(e.seconds for e in extra)
    feedback_samples = sum(e.samples for e in extra)
    plan = _plan(traj, fb, extra, m)
    around = replace(search, sigma_init=fb.refine_sigma, mean_carry=0.0)
    guided: list[Trajectory] = []
    for _ in range(fb.refine_iterations):

        def guide(k: int, s: np.ndarray, plan: ClipPlan = plan) -> np.ndarray:
            k = k % m if m else k
            if plan.anchor_features is None:
                return s @ plan.gain[k].T + plan.bias[k]
            return np.stack([plan.offset(k, x) for x in s])

        again = samcon(humanoid, library, clip, frames, around, cfg.cost, rng, guide=guide, **common)
        # The open-loop trajectory stays the better of the two searches (the policy is anchored on it); the samples
        # and time add up.
        best = again if again.segment_cost.sum() < traj.segment_cost.sum() else traj
        traj = replace(best, samples=traj.samples + again.samples, seconds=traj.seconds + again.seconds,
                       backtracks=traj.backtracks + again.backtracks)
        if fb.anchor == "nearest":
            # Every guided search joins the regression and the anchors (Liu et al. 2016 pool their iterations).
            guided.append(again)
            plan = _plan(traj, fb, [*extra, *guided], m)
        else:
            plan = ClipPlan(traj.targets, _plan_bounds(traj, m), *anchored(traj, fb, *fit_samples(again, fb, extra, m)))
    if cfg.polish.iterations:
        # The open-loop path is final here; the regressed feedback stays anchored on the searched one.
        searches = {"samples": 0}

        def searcher(first: int, end: int, state: np.ndarray) -> np.ndarray | None:
            if not (first in grid and end in grid):
                return None
            quiet = {**common, "progress": None}
            path = samcon(humanoid, library, clip, frames, search, cfg.cost, rng, start_frame=first, end_frame=end,
                          start=state, **quiet)  # fmt: skip
            searches["samples"] += path.samples
            return None if path.segment_terms["fallen"].sum() else path.targets

        traj = polished(traj, cfg, humanoid, library, clip, log, searcher if cfg.polish.search else None)
        traj.samples += searches["samples"]
        plan.targets = traj.targets
    visit_rounds = []
    for it in range(fb.visit_iterations):
        segments = max(1, fb.start_segments)
        visits, share = visited_states(plan, name, library, humanoid, grid, cycle or frames, segments, fb,
                                       cfg.train.eval, rng, cfg.train.threads)  # fmt: skip
        print(f"{name}: visit round {it + 1}/{fb.visit_iterations}: {share:.0%} of {fb.visit_episodes} episodes "
              f"fell; searches from {len(visits)} of their states", file=log, flush=True)  # fmt: skip
        for first, state in visits:
            end = int(grid[int(np.searchsorted(grid, first)) + segments])
            print(f"{name}: a search from the policy's state at frame {first} to {end}", file=log, flush=True)
            path = samcon(humanoid, library, clip, frames, search, cfg.cost, rng, start_frame=first, end_frame=end,
                          start=state, **common)  # fmt: skip
            extra.append(path)
            feedback_seconds += path.seconds
            feedback_samples += path.samples
        plan = _plan(traj, fb, [*extra, *guided], m)
        visit_rounds.append({"round": it + 1, "fell": share, "searches": len(visits)})
    # The oracle's minutes are the open-loop search's; the feedback's extra searches are counted apart.
    traj.feedback_seconds, traj.feedback_samples = feedback_seconds, feedback_samples
    traj.visits = visit_rounds or None
    if cfg.optimise.generations:
        t0 = time.perf_counter()
        plan, history = optimise_gains(plan, name, library, humanoid, cfg.optimise, cfg.train.eval, rng,
                                       threads=cfg.train.threads, log=log)  # fmt: skip
        traj.optimise = {"seconds": time.perf_counter() - t0, **history}
    if cfg.lqr.enabled:

        def recovery(first: int, end: int, state: np.ndarray) -> Trajectory:
            print(f"{name}: a recovery search from the LQR policy's state at frame {first} to {end}", file=log,
                  flush=True)  # fmt: skip
            return samcon(humanoid, library, clip, frames, search, cfg.cost, rng, start_frame=first, end_frame=end,
                          start=state, **common)  # fmt: skip

        plan.lqr, traj.lqr = grow_paths(traj, library, humanoid, cfg.lqr, cfg.train.eval, recovery, rng, log,
                                        extra=from_reference)  # fmt: skip
        plan.lqr_limit = cfg.lqr.limit
        print(f"{name}: LQR on {len(plan.lqr)} paths in {traj.lqr['seconds']:.0f} s", file=log, flush=True)
    return traj, plan


def polished(traj: Trajectory, cfg: SamconConfig, humanoid: Humanoid, library: MotionLibrary, clip: int,
             log: Any, searcher: Searcher | None = None,
             force: ExternalForce | None = None) -> Trajectory:  # fmt: skip
    """``traj`` (from the clip's start) after the iLQR polish (:mod:`samcon.polish`), its per-segment record
    recomputed along the polished path (unchanged where the polish was dropped); the polish's seconds count in the
    oracle's. With ``force`` (an external force, :class:`samcon.search.ExternalForce`) the polish and the replay
    apply it too."""
    hinge = humanoid.hinge_qpos
    ref = reference_frames(library, clip, traj.frames)
    ref_targets = ref.qpos[1:, hinge]
    targets, summary = polish(humanoid, traj.start_state, traj.targets, ref, ref_targets, cfg.polish,
                              cfg.cost.fall_head_error, traj.clip, log, lqr=cfg.lqr, searcher=searcher,
                              force=force)  # fmt: skip
    summary["windows"] = [{k: w[k] for k in ("first", "end", "searched")} | {"steps": len(w["iterations"]) - 1}
                          for w in summary["windows"]]  # fmt: skip
    if not summary["kept"]:
        return replace(traj, seconds=traj.seconds + summary["seconds"], polish=summary)
    states = replay(humanoid, traj.start_state, targets, cfg.gym.max_speed, force)
    m = humanoid.model
    fk = ForwardKinematics(humanoid, threads=0)
    try:
        sim = fk(states[:, 1 : 1 + m.nq], states[:, 1 + m.nq : 1 + m.nq + m.nv])
    finally:
        fk.close()
    per_frame, terms = tracking_cost(humanoid, cfg.cost, sim, ref[1:])
    seg = np.repeat(np.arange(len(traj.bounds) - 1), np.diff(traj.bounds))
    count = np.bincount(seg)

    def mean(values: np.ndarray) -> np.ndarray:
        return np.bincount(seg, weights=values) / count

    return replace(
        traj, targets=targets,
        offsets=np.stack([(targets - ref_targets)[seg == k].mean(axis=0) for k in range(len(count))]),
        segment_cost=mean(per_frame),
        segment_terms={k: mean(terms[k]) for k in COST_TERMS} | {"fallen": np.bincount(seg, terms["fallen"] * 1.0)},
        end_states=states[traj.bounds[1:] - 1], seconds=traj.seconds + summary["seconds"], polish=summary,
    )  # fmt: skip


def diagnose(traj: Trajectory, cfg: SamconConfig) -> dict[str, Any]:
    """Where the trajectory is worst: the largest weighted cost term, and the first frame it fell (None: never)."""
    weighted = {k: float(getattr(cfg.cost, k) * traj.segment_terms[k].mean()) for k in COST_TERMS}
    fell = np.flatnonzero(traj.segment_terms["fallen"] > 0)
    return {"largest_term": max(weighted, key=weighted.get), "weighted_terms": weighted,
            "first_fall_frame": int(traj.bounds[fell[0]]) if len(fell) else None}  # fmt: skip


def _clip_rows(library: MotionLibrary, results: list[tuple[Trajectory, ClipPlan]],
               open_loop: EvalResult, feedback: EvalResult, cfg: SamconConfig) -> dict[str, Any]:  # fmt: skip
    rows = {}
    for c, (traj, _) in enumerate(results):
        seconds_of_motion = traj.frames * library.dt
        rows[traj.clip] = {
            "frames": traj.frames, "samples": traj.samples, "backtracks": traj.backtracks,
            "minutes": traj.seconds / 60.0, "feedback_search_minutes": traj.feedback_seconds / 60.0,
            "feedback_search_samples": traj.feedback_samples,
            "minutes_per_motion_second": traj.seconds / 60.0 / seconds_of_motion, "sigma_init": traj.sigma,
            "open_loop": {k: float(open_loop.per_clip[k][c]) for k in ("mpjpe_g", "mpjpe_l", "survival")},
            "feedback": {k: float(feedback.per_clip[k][c]) for k in ("mpjpe_g", "mpjpe_l", "survival", "success")},
            "cost_total": float(traj.segment_cost.sum()), **diagnose(traj, cfg),
        }  # fmt: skip
        if traj.optimise is not None:
            rows[traj.clip]["optimise"] = traj.optimise
        if traj.visits is not None:
            rows[traj.clip]["visits"] = traj.visits
        if traj.lqr is not None:
            rows[traj.clip]["lqr"] = traj.lqr
        if traj.polish is not None:
            rows[traj.clip]["polish"] = traj.polish
    return rows


def clip_generator(seed: int, name: str) -> np.random.Generator:
    """The draws of one clip: from the run's seed and the clip's name alone, so that a clip's search is the same
    whichever clips run before it (one generator through the run made a clip's result depend on them: dance_b fell
    at frame 210 as the fifth clip of a run in session 9, and tracked to its end with no fall as the only one)."""
    return np.random.default_rng([seed, zlib.crc32(name.encode("utf-8"))])


def build_parser() -> argparse.ArgumentParser:
    parser = CommandParser(
        prog="track-samcon", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="SAMCON open-loop trajectories and linear feedback policies for clips, as a run directory.",
        epilog="examples:\n  track-samcon --motions walk run --out runs/samcon-walk-run\n"
               "  track-samcon --config debug --motions walk --out runs/samcon-debug",
    )  # fmt: skip
    parser.add_argument("--config", default=str(default_config("samcon")), help=config_help("samcon"))
    parser.add_argument("--motions", nargs="+", default=None, help="motions to track, overriding train.motions")
    parser.add_argument("--out", default=None, help="run directory (default: runs/samcon-<date>-<time>); must be new")
    parser.add_argument("--seed", type=non_negative_int, default=None, help="sampling seed (train.seed)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override any config value, e.g. --set search.samples=400 (repeatable)")  # fmt: skip
    return parser


def cli_overrides(args: argparse.Namespace) -> list[str]:
    """The config overrides of a command's ``--set``, ``--motions`` and ``--seed`` options, in that order."""
    overrides = list(args.overrides)
    if args.motions is not None:
        overrides.append("train.motions=[" + ", ".join(repr(m) for m in args.motions) + "]")
    if args.seed is not None:
        overrides.append(f"train.seed={args.seed}")
    return overrides


def main(argv: Sequence[str] | None = None) -> None:
    """``track-samcon``: bad input ends in one line and exit status 2 with no run directory made; a failure during
    the run (a full disk) in one line and exit status 1 (:mod:`common.cli`)."""
    with one_line_errors(ConfigError, RunDirError, MotionFormatError):
        _main(argv)


def _main(argv: Sequence[str] | None) -> None:
    args = build_parser().parse_args(argv)
    overrides = cli_overrides(args)
    try:
        args.config = str(resolve_config(args.config, "samcon"))
        cfg = load_config(SamconConfig, args.config, overrides)
        humanoid = Humanoid(cfg.gym.physics)
        library = load_motions(list(cfg.train.motions), humanoid)
        try:  # unknown feature or actuator names: refused before any output
            reduced_indices(humanoid, cfg.optimise)  # names of features, gain and offset actuators
        except ValueError as e:
            raise ConfigError(f"{args.config}: {e}") from None
        run_dir = RunDir(args.out or f"runs/{LEARNER}-{datetime.now().strftime('%Y%m%d-%H%M%S')}", resume=False,
                         create=False)  # fmt: skip
    except OSError as e:  # a config or motion file that cannot be read
        fail(os_error_line(e))
    run_dir.lock()  # refused in one line while another command writes it
    try:
        run_dir.create()
        _track(cfg, humanoid, library, run_dir)
    finally:
        run_dir.unlock()


def _track(cfg: SamconConfig, humanoid: Humanoid, library: MotionLibrary, run_dir: RunDir) -> None:
    """Tracks every clip into the created and locked ``run_dir``: its config, run info, plans and results."""
    try:
        run_dir.save_config(cfg)
        info = run_dir.write_run_info({"learner": LEARNER, "seed": cfg.train.seed, "motions": list(library.names)})
    except OSError as e:
        fail(f"run directory {run_dir.path}: cannot write {os_error_line(e)}")
    t0 = time.perf_counter()
    with open(run_dir.path / "progress.log", "a", encoding="utf-8") as log:
        results = [track_clip(cfg, humanoid, library, c, clip_generator(cfg.train.seed, name), log)
                   for c, name in enumerate(library.names)]  # fmt: skip
        seconds = time.perf_counter() - t0
        store.save(run_dir.path / store.FILE_NAME, humanoid.physics.control_hz, results)
        plans = {traj.clip: plan for traj, plan in results}
        ev = cfg.train.eval
        open_loop = evaluate(open_loop_policy(plans, library, humanoid), library, humanoid,
                             replace(ev, starts_per_clip=1, max_frames=cfg.train.max_frames))  # fmt: skip
        feedback = evaluate(evaluation_policy(plans, library, humanoid), library, humanoid, ev)
        print(f"open loop from each clip's start:\n{open_loop.table()}", file=log, flush=True)
        kind = "LQR (clips with paths) and linear" if cfg.lqr.enabled else "linear"
        print(f"{kind} feedback ({ev.starts_per_clip} starts per clip):\n{feedback.table()}", file=log, flush=True)
        regressed = None
        if cfg.lqr.enabled:
            # The same searches' regressed per-segment policies: what the LQR replaces.
            regressed = evaluate(FeedbackPolicy(plans, library, humanoid), library, humanoid, ev)
            print(f"the regressed linear feedback alone:\n{regressed.table()}", file=log, flush=True)
        path_only = None
        if cfg.feedback.anchor == "nearest":
            # The same searches and gains anchored on the path from frame 0 alone: what the other paths add.
            alone = {k: replace(p, anchor_features=None, anchor_offsets=None, feature_scale=None)
                     for k, p in plans.items()}  # fmt: skip
            path_only = evaluate(FeedbackPolicy(alone, library, humanoid), library, humanoid, ev)
            print(f"the same, anchored on the path from frame 0 alone:\n{path_only.table()}", file=log, flush=True)
    samples = int(sum(traj.samples for traj, _ in results))
    out = {"clips": _clip_rows(library, results, open_loop, feedback, cfg), "seconds": seconds, "samples": samples,
           "open_loop_overall": open_loop.overall, "feedback_overall": feedback.overall}  # fmt: skip
    if regressed is not None:
        out["feedback_regressed_overall"] = regressed.overall
        for c, name in enumerate(library.names):
            keys = ("mpjpe_g", "mpjpe_l", "survival", "success")
            out["clips"][name]["feedback_regressed"] = {k: float(regressed.per_clip[k][c]) for k in keys}
    if path_only is not None:
        out["feedback_path_anchor_overall"] = path_only.overall
        for c, name in enumerate(library.names):
            keys = ("mpjpe_g", "mpjpe_l", "survival", "success")
            out["clips"][name]["feedback_path_anchor"] = {k: float(path_only.per_clip[k][c]) for k in keys}
    with atomic_output(run_dir.path / "results.json") as tmp:
        tmp.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    histories = {traj.clip: traj.optimise for traj, _ in results if traj.optimise is not None}
    if histories:
        plot_history(histories, run_dir.path / "optimise.png")
    # The report takes the run's policy from this file (a SAMCON run has no training checkpoints).
    info.update(policy_file=store.FILE_NAME, samples=samples, train_seconds=seconds)
    with atomic_output(run_dir.run_info_path) as tmp:
        tmp.write_text(json.dumps(info, indent=2, default=str) + "\n", encoding="utf-8")
    for name, row in out["clips"].items():
        ol, fb = row["open_loop"], row["feedback"]
        alone = row.get("feedback_path_anchor")
        also = "" if alone is None else f" (anchored on the first path alone: {alone['survival']:.0%})"
        print(f"{name}: open loop MPJPE-g {ol['mpjpe_g']:.1f} mm, MPJPE-l {ol['mpjpe_l']:.1f} mm, survived "
              f"{ol['survival']:.0%}; feedback survival {fb['survival']:.0%}{also}, MPJPE-g {fb['mpjpe_g']:.1f} mm; "
              f"{row['minutes_per_motion_second']:.2f} min per s of motion, {row['samples']} samples")  # fmt: skip
    print(f"run: {run_dir.path}")


if __name__ == "__main__":
    main()
