"""``compare-trackers``: one comparison report of SuperTrack and PPO runs, re-evaluated on one protocol.

Every run's checkpoint is re-evaluated with the shared evaluator (:func:`common.evaluation.evaluate.evaluate`)
on the same motions, start frames and seed, rather than trusting the numbers the runs logged; learning curves,
thresholds and world-model diagnostics come from the runs' ``metrics.jsonl``. Writes ``report.md``,
``report.html`` (self-contained), ``results.json`` (full-precision numbers) and the PNG figures into ``--out``.

Example::

    compare-trackers runs/st-walk runs/ppo-walk --out reports/walk
    compare-trackers runs/st-walk runs/ppo-walk --motions walk run --starts 8 --out reports/walk-run
"""

from __future__ import annotations

import argparse
import json
import shutil
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from common.bundled_configs import plain_help
from common.character.humanoid import Humanoid
from common.cli import (
    EXIT_RUN_FAILED,
    MAX_FRAMES,
    CommandParser,
    check_output_dir,
    fail,
    frame_count,
    non_negative_int,
    one_line_errors,
    os_error_line,
    positive_int,
)
from common.config import ConfigError
from common.evaluation.evaluate import EvalConfig, EvalResult, Policy, evaluate
from common.motion.dataset import bundled_clip_names, bundled_terrain_clip_names, load_motions
from common.motion.library import MotionLibrary
from common.motion.motion import MotionFormatError
from common.run.checkpoint import CheckpointError
from common.run.command_line import portable_path
from common.run.lock import DirectoryLock
from common.sim.pushes import PushConfig
from common.tools import render
from report import figures, tables
from report.html import markdown_to_html
from report.runs import ReportError, Run, export_module, load_run, unique_labels

PUSHES = PushConfig()  # the robustness protocol's schedule: one for every report


@dataclass
class Report:
    """What :func:`build_report` produced.

    Attributes:
        runs: The runs, in command-line order.
        results: Their re-evaluations, same order.
        protocol: The evaluation protocol used for every run.
        pushed: Their re-evaluations under pushes (the robustness protocol); empty when switched off.
        motions: The motion specs every run was evaluated on.
        notes: Warnings shown at the top of the report (mixed motion sets, physics, rendering).
        files: Paths written.
        oracles: {run label: (open-loop result from each clip's start, {clip: minutes})} of oracle runs (SAMCON).
    """

    runs: list[Run]
    results: list[EvalResult]
    protocol: EvalConfig
    motions: list[str]
    pushed: list[EvalResult] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    files: dict[str, Path] = field(default_factory=dict)
    oracles: dict[str, tuple[EvalResult, dict[str, float]]] = field(default_factory=dict)


def motion_union(lists: Sequence[Sequence[str]]) -> list[str]:
    """The runs' motion specs, each once, in order of appearance; with ``all`` (``terrain``) among them the bundled
    short (terrain) clips' own names are dropped (the group holds them, and a clip may be loaded once)."""
    out: list[str] = []
    for items in lists:
        out += [x for x in items if x not in out]
    for group, names in (("all", bundled_clip_names), ("terrain", bundled_terrain_clip_names)):
        if group in out:
            held = set(names())
            out = [x for x in out if x not in held]
    return out


def build_report(run_dirs: Sequence[str | Path], out: str | Path, checkpoint: int | None = None,
                 motions: Sequence[str] | None = None, starts: int | None = None, max_frames: int | None = None,
                 render_clips: int = 1, do_render: bool = True, pushes: bool = True,
                 video_clips: int | None = None) -> Report:  # fmt: skip
    """Re-evaluates every run and writes the report into ``out``.

    Args:
        run_dirs: Run directories.
        out: Report directory (created).
        checkpoint: Iteration of the checkpoint to evaluate in every run; None: each run's newest.
        motions: Motion specs to evaluate on; None: the union of the runs' training motions.
        starts: Start frames per clip; None: the first run's protocol.
        max_frames: Steps per evaluation episode; None: the first run's protocol.
        render_clips: Clips per run drawn as filmstrips.
        do_render: False skips the filmstrips and videos (no GL probing at all).
        pushes: Also re-evaluate every run under the robustness protocol (:class:`common.sim.pushes.PushConfig`).
        video_clips: Clips per method rendered as MP4 videos (the first run of each learner, i.e. its lowest seed);
            None: every clip; 0: none.

    Raises:
        ReportError: On a bad run directory, an unknown learner, motions that cannot be loaded, or an ``out`` that
            another command is writing.
    """
    if not run_dirs:
        raise ReportError("no run directory given")
    out = Path(out)
    runs = [load_run(p, checkpoint) for p in run_dirs]
    unique_labels(runs)
    notes: list[str] = []
    trained_on = {r.label: tuple(r.motions) for r in runs}
    if len(set(trained_on.values())) > 1:
        listed = "; ".join(f"{k}: {', '.join(v)}" for k, v in trained_on.items())
        notes.append(f"The runs were TRAINED on different motion sets ({listed}); all are evaluated on the same set.")
    specs = list(motions) if motions else motion_union([r.config.get("train", {}).get("motions", []) for r in runs])
    physics = runs[0].physics()
    if any(r.physics() != physics for r in runs[1:]):
        notes.append(f"The runs used different physics settings; all are evaluated with {runs[0].label}'s.")
    protocol = runs[0].eval_config()
    protocol = replace(protocol, starts_per_clip=starts or protocol.starts_per_clip,
                       max_frames=max_frames or protocol.max_frames)  # fmt: skip
    if any(r.eval_config() != runs[0].eval_config() for r in runs[1:]):
        notes.append("The runs logged their training curves with different evaluation protocols; the tables use one.")
    humanoid = Humanoid(physics)
    try:
        library = load_motions(specs, humanoid)
    except (MotionFormatError, FileNotFoundError, KeyError, ValueError) as e:
        raise ReportError(f"cannot load motions {specs}: {e}") from e
    # Made only now, so that a refused report leaves no folder behind; one that fails (a full disk) removes the
    # folders it made.
    made = next((p for p in reversed([out, *out.absolute().parents]) if not p.exists()), None)
    out.mkdir(parents=True, exist_ok=True)
    lock = DirectoryLock(out, ReportError, "--out")  # one report at a time in a folder (common.run.lock)
    try:
        lock.acquire()
        policies, results, pushed = [], [], []
        for run in runs:
            policy = export_module(run.learner).load_eval_policy(run.path, run.checkpoint, humanoid, library)
            policies.append(policy)
            results.append(evaluate(policy, library, humanoid, protocol))
            if pushes:
                pushed.append(evaluate(policy, library, humanoid, replace(protocol, pushes=PUSHES)))
        report = Report(runs, results, protocol, specs, pushed, notes)
        for run in runs:
            module = export_module(run.learner)
            if hasattr(module, "load_oracle"):
                # A per-clip oracle (SAMCON): its open-loop trajectory, scored from each clip's start.
                policy, minutes = module.load_oracle(run.path, run.checkpoint, humanoid, library)
                report.oracles[run.label] = (evaluate(policy, library, humanoid, replace(protocol, starts_per_clip=1)),
                                             minutes)  # fmt: skip
        report.files["curves"] = figures.learning_curves(runs, out / "learning_curves.png")
        wm = figures.world_model_curves(runs, out / "world_model.png")
        if wm is not None:
            report.files["world_model"] = wm
        strips, videos = _pictures(report, policies, library, humanoid, out, render_clips if do_render else 0,
                                   video_clips if do_render else 0)  # fmt: skip
        md = _markdown(report, strips, videos)
        (out / "report.md").write_text(md, encoding="utf-8")
        (out / "report.html").write_text(markdown_to_html(md, out, "Tracker comparison"), encoding="utf-8")
        (out / "results.json").write_text(json.dumps(_results_json(report), indent=1) + "\n", encoding="utf-8")
        report.files.update(markdown=out / "report.md", html=out / "report.html", results=out / "results.json")
    except BaseException as e:
        refused = isinstance(e, ReportError) and not lock.held  # another command writes the folder: it stays
        if made is not None and not refused:
            shutil.rmtree(made, ignore_errors=True)
        raise
    finally:
        lock.release()
    return report


def film_order(mpjpe_g: np.ndarray, count: int) -> list[int]:
    """The clips to film, ``count`` of them spread over the first run's per-clip MPJPE-g (C,): the best, then the
    worst, then evenly between (best, median, worst for 3), so that a reader sees what the run tracks and where it
    fails rather than the first clips of the alphabet. Clip indices in that order."""
    ranked = np.argsort(mpjpe_g, kind="stable")
    count = min(count, len(ranked))
    if count <= 0:
        return []
    picks = np.unique(np.rint(np.linspace(0, len(ranked) - 1, count)).astype(np.int64))
    order = [picks[0], *([picks[-1]] if len(picks) > 1 else []), *picks[1:-1]]
    return [int(ranked[i]) for i in order]


def _pictures(report: Report, policies: list[Policy], library: MotionLibrary, humanoid: Humanoid, out: Path,
              strip_clips: int, video_clips: int | None) -> tuple[dict[str, list[tuple[str, Path]]], ...]:  # fmt: skip
    """Filmstrips ({run label: [(clip, png)]}, ``strip_clips`` clips of every run) and MP4 videos ({run label:
    [(clip, mp4)]}, ``video_clips`` clips of the first run of each learner, None: every clip): the simulated
    character beside the translucent reference over the evaluation horizon from t = 0. Each rollout is simulated once
    for both. Adds a note saying why when something could not be rendered."""
    video_count = library.num_clips if video_clips is None else min(video_clips, library.num_clips)
    strip_count = min(strip_clips, library.num_clips)
    if strip_clips <= 0:
        report.notes.append("Filmstrips were not rendered (switched off with --no-render).")
    if strip_count <= 0 and video_count <= 0:
        return {}, {}
    backend, why = render.find_backend()
    if backend is None:
        if strip_count > 0:
            report.notes.append(f"Filmstrips were not rendered: {why}.")
        if video_count > 0:
            report.notes.append(f"Videos were not rendered: {why}.")
        return {}, {}
    strips: dict[str, list[tuple[str, Path]]] = {}
    videos: dict[str, list[tuple[str, Path]]] = {}
    filmed: set[str] = set()
    fps = humanoid.physics.control_hz
    # Filmstrips: best, worst and between by the first run's MPJPE-g; videos: clip order (their count may be all).
    chosen = film_order(report.results[0].per_clip["mpjpe_g"], strip_count)
    for run, policy in zip(report.runs, policies, strict=True):
        n_video = 0 if run.learner in filmed else video_count
        filmed.add(run.learner)
        stem = run.label.replace(":", "_").replace("#", "_")
        clips = chosen + [c for c in range(n_video) if c not in chosen]
        for c in clips:
            name = library.names[c]
            sim, ref = render.record_rollout(policy, library, humanoid, c, report.protocol.max_frames, report.protocol)
            if c in chosen:
                png = out / f"filmstrip_{stem}_{name}.png"
                try:
                    render.filmstrip(sim, ref, humanoid, png, backend, terrain=library.clips[c].terrain)
                    strips.setdefault(run.label, []).append((name, png))
                except (RuntimeError, OSError) as e:
                    report.notes.append(f"Filmstrip of {run.label} on {name} failed: {e}")
            if c < n_video:
                mp4 = out / f"video_{stem}_{name}.mp4"
                try:
                    render.video(sim, ref, humanoid, mp4, backend, fps, terrain=library.clips[c].terrain)
                    videos.setdefault(run.label, []).append((name, mp4))
                except (RuntimeError, OSError) as e:
                    report.notes.append(f"Video of {run.label} on {name} failed: {e}")
    return strips, videos


def _markdown(report: Report, strips: dict[str, list[tuple[str, Path]]],
              videos: dict[str, list[tuple[str, Path]]] | None = None) -> str:  # fmt: skip
    p = report.protocol
    labels = [r.label for r in report.runs]
    lines = ["# Tracker comparison", ""]
    lines += [f"- **Note:** {n}" for n in report.notes]
    lines += ["", f"Every run re-evaluated by `common.evaluation.evaluate` on motions `{', '.join(report.motions)}` "
              f"(clips: {', '.join(report.results[0].clips)}), {p.starts_per_clip} start(s) per clip, "
              f"{p.max_frames} frames per episode, seed {p.seed}. Best value of each row in bold.", ""]  # fmt: skip
    lines += [PROTOCOL if p.full_horizon else "The runs are scored until their first failure (the earlier protocol, "
              "`train.eval.full_horizon: false`): a method can score lower errors by failing sooner.", ""]  # fmt: skip
    lines += ["## Learning curves (from the training logs)", "", "![learning curves](learning_curves.png)", ""]
    lines += ["## Tracking metrics (re-evaluated)", "", tables.metric_tables(labels, report.results), ""]
    if report.pushed:
        q = PUSHES
        lines += ["## Robustness: pushes on the pelvis", "", f"The same protocol with an impulse of {q.impulse:g} N s "
                  f"on the pelvis, horizontal, in a seeded random direction (seed {q.seed}), at frame "
                  f"{q.first_frame} of every episode and every {q.interval} frames after.", "",
                  tables.robustness_table(labels, report.pushed), ""]  # fmt: skip
    if report.oracles:
        lines += ["## Oracle: SAMCON's open-loop trajectory from each clip's start, next to every run", "",
                  tables.oracle_table(report.oracles, labels, report.results), ""]  # fmt: skip
    spread = tables.spread_table(report.runs, report.results, report.pushed)
    if spread:
        lines += ["## Spread over seeds (mean ± std over each learner's runs, sample std)", "",
                  "### Spread: mean over clips", "", spread, ""]  # fmt: skip
        lines += ["### Spread per clip", "", tables.per_clip_spread_table(report.runs, report.results) or "", ""]
    lines += ["## Samples and wall-clock to reach thresholds (first logged evaluation)", "",
              tables.threshold_table(report.runs), ""]  # fmt: skip
    parity = tables.parity_table(report.runs)
    if parity:
        lines += ["## Samples and wall-clock to reach the other method's final MPJPE-g (logged evaluations)", "",
                  parity, ""]  # fmt: skip
    updates = tables.update_statistics_table(report.runs)
    if updates:
        lines += ["## PPO's update statistics (from the training logs)", "", updates, ""]
    wm = tables.world_model_table(report.runs)
    lines += ["## World-model diagnostics (SuperTrack)", ""]
    if wm:
        lines += [wm, "", "![world model](world_model.png)", ""]
    else:
        lines += ["No run logged world-model diagnostics.", ""]
    lines += ["## Filmstrips (simulated: opaque; reference: orange ghost)", ""]
    if not strips:
        lines += ["Not rendered (see the notes at the top).", ""]
    for label, items in strips.items():
        lines += [f"**{label}** on `{clip}`: ![{label} {clip}]({png.name})" for clip, png in items] + [""]
    if videos:
        lines += ["## Videos (MP4, simulated: opaque; reference: translucent; the first run of each method)", ""]
        lines += [f"- [{label} on {clip}]({mp4.name})" for label, items in videos.items() for clip, mp4 in items]
        lines += [""]
    lines += ["## Runs: machine, versions, seeds", "", tables.runs_table(report.runs), ""]
    lines += ["## Configs", "", tables.configs_block(report.runs)]
    return "\n".join(lines) + "\n"


PROTOCOL = ("**Protocol.** Every episode plays its whole horizon (the frames above, or to a one-shot clip's end). "
            "The failure rule (head height off by more than 25 cm after 48 frames) marks an episode failed at the "
            "frame it first fires but does not end it: the character plays on and its error keeps counting, so "
            "failing sooner never lowers a method's error. Survival: episodes the rule never failed; episode length: "
            "the share of the horizon before the first failure; success (UHC/PHC): no failure and a mean body error "
            "never above 0.5 m; `mpjpe_g_succ` / `mpjpe_l_succ`: the errors over the successful episodes only "
            "(PHC/UHC), to be read with the success rate.")  # fmt: skip


# The training logs' curves results.json keeps, so that a later report (a parity against another method's new runs)
# can be computed without the run directories.
RESULT_CURVES = ("eval/mpjpe_g", "eval/mpjpe_l", "eval/survival", "eval/success")


def _curves(run: Run) -> dict[str, dict[str, list]]:
    """The run's logged evaluations of :data:`RESULT_CURVES`: samples, training wall-clock (s) and value of each."""
    out = {}
    for key in RESULT_CURVES:
        samples, seconds, values = run.curve(key)
        if values:
            out[key] = {"samples": samples, "seconds": seconds, "values": values}
    return out


def _results_json(report: Report) -> dict[str, Any]:
    return {
        "motions": report.motions, "protocol": {"starts_per_clip": report.protocol.starts_per_clip,
                                                "max_frames": report.protocol.max_frames, "seed": report.protocol.seed},
        "notes": report.notes,
        "runs": [{"label": run.label, "learner": run.learner, "path": portable_path(str(run.path.absolute())),
                  "checkpoint": portable_path(str(run.checkpoint.absolute())),
                  "clips": res.clips, "overall": res.overall,
                  "per_clip": {k: v.tolist() for k, v in res.per_clip.items()},
                  "curves": _curves(run),
                  **({"pushed": {"overall": report.pushed[i].overall,
                                 "per_clip": {k: v.tolist() for k, v in report.pushed[i].per_clip.items()}}}
                     if report.pushed else {})}
                 for i, (run, res) in enumerate(zip(report.runs, report.results, strict=True))],
        "oracles": {label: {"clips": res.clips, "minutes": minutes,
                            "per_clip": {k: res.per_clip[k].tolist() for k in ("mpjpe_g", "mpjpe_l", "survival")}}
                    for label, (res, minutes) in report.oracles.items()},
        "parity": tables.parity(report.runs),
    }  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    parser = CommandParser(prog="compare-trackers", description=plain_help(__doc__.split("\n\n")[0]),
                           formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("runs", nargs="+", metavar="RUN_DIR", help="training run directories")
    parser.add_argument("--out", required=True, help="report directory")
    parser.add_argument("--checkpoint", type=non_negative_int, default=None, metavar="ITER",
                        help="evaluate checkpoint ckpt_<ITER>.pt of every run (default: the newest)")  # fmt: skip
    parser.add_argument("--motions", nargs="+", default=None,
                        help="motions to evaluate on (default: the union of the runs' training motions)")  # fmt: skip
    parser.add_argument("--starts", type=positive_int, default=None,
                        help="start frames per clip (default: first run's)")  # fmt: skip
    parser.add_argument("--max-frames", type=frame_count, default=None,
                        help=f"steps per episode (default: first run's; at most {MAX_FRAMES})")  # fmt: skip
    parser.add_argument("--render-clips", type=non_negative_int, default=1,
                        help="clips per run drawn as filmstrips: the best, the worst and evenly between by the first "
                             "run's MPJPE-g")  # fmt: skip
    parser.add_argument("--no-render", action="store_true", help="skip the filmstrips and videos")
    parser.add_argument("--video-clips", type=non_negative_int, default=None, metavar="N",
                        help="clips per method rendered as MP4 (first run of each learner; default: every "
                             "clip)")  # fmt: skip
    parser.add_argument("--no-pushes", action="store_true",
                        help="skip the robustness re-evaluation (pushes on the pelvis)")  # fmt: skip
    parser.add_argument("--threads", type=positive_int, default=1, help="torch threads")
    return parser


def main(argv: Sequence[str] | None = None) -> None:
    """``compare-trackers``: bad input ends in one line and exit status 2 with no report written; a report that
    cannot be written (a full disk) in one line and exit status 1."""
    with one_line_errors(ReportError, ConfigError, MotionFormatError, CheckpointError):
        args = build_parser().parse_args(argv)
        check_output_dir(args.out)
        torch.set_num_threads(args.threads)
        try:
            report = build_report(args.runs, args.out, args.checkpoint, args.motions, args.starts, args.max_frames,
                                  args.render_clips, not args.no_render, not args.no_pushes,
                                  args.video_clips)  # fmt: skip
        except OSError as e:  # a full disk while writing the report; the folders it made are removed again
            fail(f"--out {args.out}: cannot write the report: {os_error_line(e)}", EXIT_RUN_FAILED)
    for label, result in zip((r.label for r in report.runs), report.results, strict=True):
        print(f"== {label}\n{result.table()}")
    for note in report.notes:
        print(f"note: {note}")
    print(f"report: {report.files['html']}")


if __name__ == "__main__":
    main()
