"""One-command head-to-head: train SuperTrack and PPO on a suite of clips, several seeds, the same wall-clock; report.

Every (seed, learner) run trains in its own process (a fresh interpreter: nothing shared between methods) for the
same training wall-clock (``--minutes``; evaluation and SuperTrack's compile warm-up stay off that clock, as in
``common.train.training``). Then ``compare-trackers`` re-evaluates every final checkpoint on one protocol and writes the
report: learning curves with the spread over seeds, per-clip tables as mean ± std over seeds, samples and minutes to
each threshold per seed, the world-model diagnostics, the robustness table and an MP4 per method and clip.

Scheduling (``--parallel``):
- ``1`` (default): one run at a time with the configs' threads (the whole machine to each run).
- ``P > 1``: P runs at a time, each on one core (``gym.threads=1``, ``train.torch_threads=1``,
  ``train.eval.threads=1``); runs start seed by seed, both learners of a seed side by side, so that the methods
  meet the same machine load.

A run directory that already holds a finished run of the same command is reused; an unfinished one is resumed
(``--resume``), so an interrupted suite continues where it stopped.

Suites: walk, run, jump, locomotion (walk, jog, run, stealthy_walk, zombie_walk), all20 (the 20 bundled clips),
terrain (walk, jog and run fitted to stairs, a slope and rough ground: the 9 bundled clips of
``benchmarks/terrain_clips.py``, trained with each learner's terrain observation on, :data:`SUITE_SETTINGS`, and judged
on them in ``report/`` and on the flat locomotion set in ``report-flat/``), and split, the generalisation protocol:
train on SPLIT_TRAIN (15 short clips and the 9 long ones), judge on SPLIT_TEST (5 short clips never trained on:
``report/``) and on the training clips (``report-train/``). The split was fixed once, before any run was judged on it,
and is never tuned: one clip of each motion family whose other members are in training (walk: stealthy_walk,
zombie_walk, long_walk*; jog: run; sideflip: backflip, cartwheel; kick: spinkick, punch; dance_b: dance_a,
dance_spin).

Run:   ``.venv/bin/python benchmarks/compare_trackers.py --suite walk --seeds 2 --minutes 30 --parallel 2 \
        --out runs/suite-walk``
Other suites' runs judged beside the suite's (``--also-judge``): the flat-trained locomotion runs on the terrain clips,
        ``... --suite terrain --out runs/suite-terrain --also-judge runs/suite-locomotion/runs/*``
Smoke: ``.venv/bin/python benchmarks/compare_trackers.py --debug --seeds 2 --minutes 0.1 --out /tmp/compare-smoke``
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common.cli import non_negative_int  # noqa: E402
from common.run.logs import read_metrics  # noqa: E402
from common.strict_json import parse_json  # noqa: E402
from report.compare import main as compare_main  # noqa: E402
from report.learners import LEARNERS, trainable  # noqa: E402

SUITES = {
    "walk": ["walk"],
    "run": ["run"],
    "jump": ["jump"],
    "locomotion": ["walk", "jog", "run", "stealthy_walk", "zombie_walk"],
    "all20": ["all"],
    "terrain": ["terrain"],
}
SPLIT_TEST = ["walk", "jog", "sideflip", "kick", "dance_b"]
SPLIT_TRAIN = ["backflip", "cartwheel", "crawl", "dance_a", "dance_spin", "getup_facedown", "getup_faceup", "jump",
               "punch", "roll", "run", "spin", "spinkick", "stealthy_walk", "zombie_walk", "long"]  # fmt: skip
SUITES["split"] = SPLIT_TRAIN
JUDGED = {"split": SPLIT_TEST}  # suites judged on other clips than they train on (and on their own in report-train/)
# Further reports of a suite, (folder, clips): the terrain-trained runs on flat ground, against the flat-trained ones.
ALSO_JUDGED = {"terrain": [("report-flat", SUITES["locomotion"])]}
# PARC's terrain observation: a 1 m heightmap at 0.1 m (the key's documented PARC value) and the reference's contact
# labels at the default's future frames (PARC observes each target frame's contacts); SuperTrack reads the same and its
# W predicts contacts (weight 1: untuned). Per learner, before the command's own --set, so that those override them.
PARC_FRAMES = "[1, 2, 4, 8, 16]"
PARC_OBSERVATION = ["observation.heightmap_extent=1.0", f"observation.contact_frames={PARC_FRAMES}"]
SUITE_SETTINGS = {
    "terrain": {
        "supertrack": ["terrain.heightmap_extent=1.0", "terrain.contact_weight=1.0",
                       f"terrain.contact_frames={PARC_FRAMES}"],
        "ppo": PARC_OBSERVATION,
        "rsl_rl": PARC_OBSERVATION,
    },
}  # fmt: skip
ONE_CORE = ["gym.threads=1", "train.torch_threads=1", "train.eval.threads=1"]
COMMAND_FILE = "suite_command.json"  # the command a suite ran in a run directory (reuse only on the same command)


@dataclass
class Job:
    """One training run of the suite."""

    learner: str
    seed: int
    out: Path
    cmd: list[str]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="compare_trackers.py", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split(
                                         "\n\n", 1)[1])  # fmt: skip
    parser.add_argument("--out", required=True, help="output directory (runs/, logs/ and report/ inside)")
    clips = parser.add_mutually_exclusive_group()
    clips.add_argument("--suite", choices=sorted(SUITES), default=None, help="a named clip set (default: walk)")
    clips.add_argument("--motions", nargs="+", default=None, help="clip(s) both methods train and are judged on")
    parser.add_argument("--minutes", type=float, default=12.0, help="training wall-clock per run, minutes")
    parser.add_argument("--seeds", type=int, default=1, help="seeds per method (0 .. N-1), for the spread")
    parser.add_argument("--parallel", type=int, default=1,
                        help="runs at a time; above 1 every run gets one core (see the scheduling notes)")  # fmt: skip
    parser.add_argument("--learners", nargs="+", choices=sorted(trainable()),
                        default=[n for n in trainable() if LEARNERS[n].suite_default],
                        help="methods to train (default: supertrack and ppo; the learner registry, report/learners.py, "
                             "lists them)")  # fmt: skip
    parser.add_argument("--evals", type=int, default=8, help="evaluations logged per run (learning-curve points)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="config override passed to every run (repeatable)")  # fmt: skip
    parser.add_argument("--debug", action="store_true", help="the tiny debug configs (tests and smoke runs)")
    parser.add_argument("--starts", type=int, default=None, help="start frames per clip of the final evaluation")
    parser.add_argument("--no-render", action="store_true", help="skip the filmstrips and videos")
    parser.add_argument("--video-clips", type=non_negative_int, default=None, metavar="N",
                        help="clips per method rendered as MP4 (default: every clip; a 20-clip suite's 40 videos "
                             "take about 25 minutes, at about 36 s each)")  # fmt: skip
    parser.add_argument("--no-pushes", action="store_true", help="skip the robustness re-evaluation")
    parser.add_argument("--train-only", action="store_true", help="train (or reuse) the runs, build no report")
    parser.add_argument("--oracle", action="append", default=[], metavar="SAMCON_RUN_DIR",
                        help="a track-samcon run directory whose open-loop paths join the report as the oracle row "
                             "(repeatable; checked before any training starts)")  # fmt: skip
    parser.add_argument("--also-judge", nargs="+", action="extend", default=[], metavar="RUN_DIR",
                        help="finished runs of another suite judged beside the suite's runs in every report (e.g. "
                             "the flat-trained locomotion runs on --suite terrain; checked before any training "
                             "starts)")  # fmt: skip
    return parser


def check_oracles(dirs: list[str], option: str = "--oracle") -> None:
    """Refuses, before anything trains, an --oracle that is not a finished track-samcon run directory, or (``option``
    ``--also-judge``) a directory that is not a run directory, or a track-samcon one."""
    from report.runs import ReportError, load_run

    for d in dirs:
        try:
            run = load_run(d)
        except ReportError as e:
            raise SystemExit(f"error: {option} {d}: {e}") from e
        if option == "--oracle" and run.learner != "samcon":
            raise SystemExit(f"error: --oracle {d}: a {run.learner} run, not a track-samcon run")
        if option != "--oracle" and run.learner == "samcon":
            raise SystemExit(f"error: {option} {d}: a track-samcon run; give it with --oracle")


def suite_motions(args: argparse.Namespace) -> list[str]:
    """The clips every run trains on."""
    if args.motions:
        return list(args.motions)
    return list(SUITES[args.suite or "walk"])


def judged_motions(args: argparse.Namespace) -> list[tuple[str, list[str]]]:
    """The reports to write, (folder name, clips judged): ``report`` on the suite's test clips, and for a suite
    judged on held-out clips also ``report-train`` on the clips it trained on."""
    if args.suite in JUDGED:
        return [("report", list(JUDGED[args.suite])), ("report-train", suite_motions(args))]
    return [("report", suite_motions(args)), *((f, list(m)) for f, m in ALSO_JUDGED.get(args.suite, []))]


def jobs(args: argparse.Namespace, out: Path) -> list[Job]:
    """The suite's runs, seed-major (both learners of a seed next to each other)."""
    preset = "debug" if args.debug else "default"
    sets = list(args.set)
    if args.debug:
        sets.append("train.max_iterations=null")  # the debug presets stop after a few iterations; the clock rules
    else:
        sets.append(f"train.eval_every_minutes={args.minutes / max(args.evals, 1)}")
    if args.parallel > 1:
        sets += ONE_CORE
    out_jobs = []
    for seed in range(args.seeds):
        for learner in args.learners:
            run_dir = out / "runs" / f"{learner}-s{seed}"
            spec = LEARNERS[learner]
            config = ROOT / "configs" / str(spec.configs) / f"{preset}.yaml"
            cmd = [sys.executable, "-m", str(spec.train), "--config", str(config),
                   "--out", str(run_dir), "--seed", str(seed), "--max-minutes", str(args.minutes),
                   "--motions", *suite_motions(args)]  # fmt: skip
            for s in [*SUITE_SETTINGS.get(args.suite or "", {}).get(learner, []), *sets]:
                cmd += ["--set", s]
            out_jobs.append(Job(learner, seed, run_dir, cmd))
    return out_jobs


def finished(run_dir: Path, minutes: float) -> bool:
    """True when the run's log ends with the final evaluation of a spent wall-clock budget."""
    try:
        rows = read_metrics(run_dir)
    except (OSError, ValueError):
        return False
    if not rows or not (run_dir / "checkpoints" / "latest.json").exists():
        return False
    last = rows[-1]
    return "eval/mpjpe_g" in last and float(last.get("wall_clock_s", 0.0)) >= 60.0 * minutes


def _log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def _start(job: Job, args: argparse.Namespace, logs: Path) -> subprocess.Popen | None:
    """Starts a job's process; None when the run directory already holds it finished."""
    marker = job.out / COMMAND_FILE
    same = marker.exists() and parse_json(marker.read_text()).get("args") == job.cmd[1:]
    if job.out.exists() and finished(job.out, args.minutes) and (same or not marker.exists()):
        _log(f"{job.learner} seed {job.seed}: finished run in {job.out}, reused")
        return None
    cmd = list(job.cmd)
    if (job.out / "checkpoints" / "latest.json").exists():
        cmd.append("--resume")
    elif job.out.exists() and any(job.out.iterdir()):
        raise SystemExit(f"error: {job.out} holds files but no checkpoint; move it away or delete it")
    _log(f"{job.learner} seed {job.seed}: {shlex.join(cmd)}")
    logs.mkdir(parents=True, exist_ok=True)
    with open(logs / f"{job.learner}-s{job.seed}.log", "a", encoding="utf-8") as log:  # the child keeps its copy
        return subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)


def train_all(args: argparse.Namespace, out: Path) -> list[Job]:
    """Runs the suite's jobs, ``--parallel`` at a time.

    A run that fails stops the suite from starting more, but the runs already going finish (their minutes are not
    thrown away; a rerun of the same command reuses them); then SystemExit names the failed run's log.
    """
    todo, running, failed = jobs(args, out), [], []
    pending = list(todo)
    while pending or running:
        while pending and not failed and len(running) < max(1, args.parallel):
            job = pending.pop(0)
            proc = _start(job, args, out / "logs")
            if proc is not None:
                running.append((job, proc))
        if not running:
            break
        time.sleep(0.2 if args.debug else 5.0)
        for job, proc in list(running):
            if proc.poll() is None:
                continue
            running.remove((job, proc))
            log = out / "logs" / f"{job.learner}-s{job.seed}.log"
            if proc.returncode != 0:
                _log(f"{job.learner} seed {job.seed}: exited with {proc.returncode} (see {log}); no new runs start")
                failed.append(f"{job.learner} seed {job.seed} exited with {proc.returncode}; see {log}")
                continue
            (job.out / COMMAND_FILE).write_text(json.dumps({"args": job.cmd[1:]}, indent=1) + "\n")
            _log(f"{job.learner} seed {job.seed}: done")
    if failed:
        raise SystemExit("error: " + "; ".join(failed))
    return todo


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.seeds < 1 or args.parallel < 1 or args.minutes <= 0:
        raise SystemExit("error: --seeds and --parallel must be >= 1 and --minutes > 0")
    out = Path(args.out)
    check_oracles(args.oracle)
    check_oracles(args.also_judge, "--also-judge")
    todo = train_all(args, out)
    if args.train_only:
        return 0
    options = [] if args.starts is None else ["--starts", str(args.starts)]
    options += ["--no-render"] * args.no_render + ["--no-pushes"] * args.no_pushes
    options += [] if args.video_clips is None else ["--video-clips", str(args.video_clips)]
    for folder, motions in judged_motions(args):
        compare_main([*(str(j.out) for j in todo), *args.also_judge, *args.oracle, "--out", str(out / folder),
                      "--motions", *motions, *options])  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
