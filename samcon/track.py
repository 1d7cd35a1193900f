"""``track-samcon``: SAMCON open-loop trajectories and linear feedback policies for clips, as a run directory.

For every clip: SAMCON from the clip's start (:mod:`samcon.search`), a linear feedback policy per segment regressed
from its samples (:mod:`samcon.feedback`), optionally refined by re-running SAMCON around it; then both judged by
the shared evaluator: the open-loop trajectory from the clip's start (one episode per clip), the feedback policy
under the run's protocol. The run directory holds ``config.yaml``, ``run_info.json``, ``samcon.h5``,
``progress.log`` and ``results.json``.

Example::

    track-samcon --motions walk run --out runs/samcon-walk-run
    track-samcon --config configs/samcon/debug.yaml --motions walk --out runs/samcon-debug
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import zlib
from collections.abc import Sequence
from dataclasses import replace
from datetime import datetime
from typing import Any

import numpy as np

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from common.motion.library import MotionLibrary
from common.motion.motion import MotionFormatError
from common.train.config import ConfigError, atomic_output, load_config
from common.train.evaluate import EvalResult, evaluate
from common.train.run import RunDir, RunDirError
from samcon import store
from samcon.config import FeedbackConfig, SamconConfig
from samcon.cost import COST_TERMS
from samcon.feedback import ClipPlan, FeedbackPolicy, fit_linear, open_loop_policy
from samcon.search import Trajectory, horizon, samcon

LEARNER = "samcon"


def fit_policies(traj: Trajectory, config: FeedbackConfig,
                 extra: Sequence[Trajectory] = ()) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """One linear map per segment from its regression samples: gain (S, nu, D), bias (S, nu)."""
    return anchored(traj, config, *fit_samples(traj, config, extra))


def fit_samples(traj: Trajectory, config: FeedbackConfig,
                extra: Sequence[Trajectory] = ()) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The lectures' regression on every segment's samples: gain (S, nu, D), bias (S, nu).

    ``extra`` are searches started later in the clip (``feedback.starts``) on the same segment grid: their samples of
    a segment join ``traj``'s in that segment's regression.
    """
    fits = []
    for k, (s, a) in enumerate(zip(traj.features, traj.actions, strict=True)):
        for e in extra:
            j = k - pooled_offset(traj, e)
            if 0 <= j < len(e.features):
                s, a = np.concatenate([s, e.features[j]]), np.concatenate([a, e.actions[j]])
        fits.append(fit_linear(s, a, config.ridge))
    return np.stack([m for m, _ in fits]), np.stack([b for _, b in fits])


def pooled_offset(traj: Trajectory, later: Trajectory) -> int:
    """Segments of ``traj`` before ``later``'s first (both on one grid from frame 0)."""
    return int(np.searchsorted(traj.bounds, later.bounds[0]))


def extra_starts(library: MotionLibrary, clip: int, frames: int, segment_frames: int, count: int,
                 rng: np.random.Generator) -> list[int]:  # fmt: skip
    """``count`` distinct segment-aligned start frames after 0, drawn within the clip's first cycle (loop clips) or
    the tracked range (one-shot clips), where the evaluator's episodes start; none left: fewer."""
    span = int(np.ceil(library.duration[clip] / library.dt - 1e-9)) if library.loop[clip] else frames
    grid = np.arange(segment_frames, min(span, frames), segment_frames)
    return sorted(int(f) for f in rng.choice(grid, size=min(count, len(grid)), replace=False))


def anchored(traj: Trajectory, config: FeedbackConfig, gain: np.ndarray, bias: np.ndarray) -> tuple[np.ndarray, ...]:
    """With ``feedback.anchor: path`` (or ``nearest``, whose first path is this one), the bias that puts ``traj``'s
    offsets at its own start features."""
    if config.anchor in ("path", "nearest"):
        bias = traj.offsets - np.einsum("kad,kd->ka", gain, traj.path_features)
    return gain, bias


def path_anchors(traj: Trajectory, extra: Sequence[Trajectory] = ()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every searched path's start features and offsets per segment of ``traj``'s grid (NaN where a path does not
    cover a segment), path 0 being ``traj``, and the features' spread over all regression samples.

    Returns:
        anchor_features (S, P, D), anchor_offsets (S, P, nu), feature_scale (D,).
    """
    paths = [traj, *extra]
    (nseg, dim), nu = traj.path_features.shape, traj.offsets.shape[1]
    features, offsets = np.full((nseg, len(paths), dim), np.nan), np.full((nseg, len(paths), nu), np.nan)
    for p, path in enumerate(paths):
        first = pooled_offset(traj, path)
        if first + len(path.offsets) != nseg or first >= nseg or traj.bounds[first] != path.bounds[0]:
            raise ValueError(f"{traj.clip}: a search from frame {path.bounds[0]} is not on the clip's segment grid")
        features[first:, p], offsets[first:, p] = path.path_features, path.offsets
    pooled = np.concatenate([s for path in paths for s in path.features])
    return features, offsets, np.maximum(pooled.std(axis=0), 1e-6)


def track_clip(cfg: SamconConfig, humanoid: Humanoid, library: MotionLibrary, clip: int, rng: np.random.Generator,
               log: Any) -> tuple[Trajectory, ClipPlan]:  # fmt: skip
    """SAMCON on one clip, the feedback fit, and its refinements; prints progress per segment into ``log``."""
    name, frames = library.names[clip], horizon(library, clip, cfg.train.max_frames)

    def progress(k: int, segments: int, best: float, seconds: float, back: int | None) -> None:
        again = "" if back is None else f": every kept sample fell, back to segment {back + 1}"
        print(f"{name} segment {k + 1}/{segments} cost {best:.4g} {seconds:.0f} s{again}", file=log, flush=True)

    fb = cfg.feedback
    common = dict(threads=cfg.train.threads, max_speed=cfg.gym.max_speed, regression_samples=fb.samples,
                  fresh_share=fb.fresh_share, rsi_lift=cfg.train.eval.rsi_lift, progress=progress)  # fmt: skip
    traj = samcon(humanoid, library, clip, frames, cfg.search, cfg.cost, rng, **common)
    extra = []
    for first in extra_starts(library, clip, frames, cfg.search.segment_frames, fb.starts, rng):
        print(f"{name}: a search from frame {first} for the feedback regression", file=log, flush=True)
        extra.append(samcon(humanoid, library, clip, frames, cfg.search, cfg.cost, rng, start_frame=first, **common))
    feedback_seconds = sum(e.seconds for e in extra)
    feedback_samples = sum(e.samples for e in extra)
    gain, bias = fit_policies(traj, cfg.feedback, extra)
    around = replace(cfg.search, sigma_init=cfg.feedback.refine_sigma, mean_carry=0.0)
    for _ in range(cfg.feedback.refine_iterations):
        g, b = gain, bias

        def guide(k: int, s: np.ndarray, g: np.ndarray = g, b: np.ndarray = b) -> np.ndarray:
            return s @ g[k].T + b[k]

        again = samcon(humanoid, library, clip, frames, around, cfg.cost, rng, guide=guide, **common)
        # The open-loop trajectory stays the better of the two searches (the policy is anchored on it); the samples
        # and time add up.
        best = again if again.segment_cost.sum() < traj.segment_cost.sum() else traj
        traj = replace(best, samples=traj.samples + again.samples, seconds=traj.seconds + again.seconds,
                       backtracks=traj.backtracks + again.backtracks)
        gain, bias = anchored(traj, cfg.feedback, *fit_samples(again, cfg.feedback, extra))
    # The oracle's minutes are the open-loop search's; the feedback's extra searches are counted apart.
    traj.feedback_seconds, traj.feedback_samples = feedback_seconds, feedback_samples
    plan = ClipPlan(traj.targets, traj.bounds, gain, bias)
    if cfg.feedback.anchor == "nearest":
        plan.anchor_features, plan.anchor_offsets, plan.feature_scale = path_anchors(traj, extra)
    return traj, plan


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
            "minutes_per_motion_second": traj.seconds / 60.0 / seconds_of_motion,
            "open_loop": {k: float(open_loop.per_clip[k][c]) for k in ("mpjpe_g", "mpjpe_l", "survival")},
            "feedback": {k: float(feedback.per_clip[k][c]) for k in ("mpjpe_g", "mpjpe_l", "survival", "success")},
            "cost_total": float(traj.segment_cost.sum()), **diagnose(traj, cfg),
        }  # fmt: skip
    return rows


def clip_generator(seed: int, name: str) -> np.random.Generator:
    """The draws of one clip: from the run's seed and the clip's name alone, so that a clip's search is the same
    whichever clips run before it (one generator through the run made a clip's result depend on them: dance_b fell
    at frame 210 as the fifth clip of a run in session 9, and tracked to its end with no fall as the only one)."""
    return np.random.default_rng([seed, zlib.crc32(name.encode("utf-8"))])


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="track-samcon", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--config", default="configs/samcon/default.yaml", help="YAML config file")
    parser.add_argument("--motions", nargs="+", default=None, help="motions to track, overriding train.motions")
    parser.add_argument("--out", default=None, help="run directory (default: runs/samcon-<date>-<time>); must be new")
    parser.add_argument("--seed", type=int, default=None, help="sampling seed (train.seed)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override any config value, e.g. --set search.samples=400 (repeatable)")  # fmt: skip
    return parser


def main(argv: Sequence[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    overrides = list(args.overrides)
    if args.motions is not None:
        overrides.append("train.motions=[" + ", ".join(repr(m) for m in args.motions) + "]")
    if args.seed is not None:
        overrides.append(f"train.seed={args.seed}")
    try:
        cfg = load_config(SamconConfig, args.config, overrides)
        humanoid = Humanoid(cfg.gym.physics)
        library = load_motions(list(cfg.train.motions), humanoid)
        run_dir = RunDir(args.out or f"runs/{LEARNER}-{datetime.now().strftime('%Y%m%d-%H%M%S')}", resume=False)
    except (ConfigError, RunDirError, MotionFormatError, FileNotFoundError) as e:
        sys.exit(f"error: {e}")
    run_dir.save_config(cfg)
    info = run_dir.write_run_info({"learner": LEARNER, "seed": cfg.train.seed, "motions": list(library.names)})
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
        feedback = evaluate(FeedbackPolicy(plans, library, humanoid), library, humanoid, ev)
        print(f"open loop from each clip's start:\n{open_loop.table()}", file=log, flush=True)
        print(f"linear feedback ({ev.starts_per_clip} starts per clip):\n{feedback.table()}", file=log, flush=True)
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
    if path_only is not None:
        out["feedback_path_anchor_overall"] = path_only.overall
        for c, name in enumerate(library.names):
            keys = ("mpjpe_g", "mpjpe_l", "survival", "success")
            out["clips"][name]["feedback_path_anchor"] = {k: float(path_only.per_clip[k][c]) for k in keys}
    with atomic_output(run_dir.path / "results.json") as tmp:
        tmp.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
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
