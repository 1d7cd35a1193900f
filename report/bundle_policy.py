"""A trained run reduced to its policy, to ship with the project: ``pretrained/<name>/``.

The bundle is a run directory that every command reads like any other (``watch-policy pretrained``,
``compare-trackers pretrained:NAME``, ``export-policy``): the run's ``config.yaml``, a ``run_info.json`` that names the
learner, the policy file and where the policy came from (the run, its checkpoint iteration, samples, training
minutes, machine, command and a note), and ``policy.pt``: the checkpoint's learner state cut to what the learner's
evaluation policy reads (the registry's ``policy_keys``, :mod:`report.learners`; SuperTrack: the policy and its
moving average; PPO: sizes, normaliser and network), so a few MB at most. ``policy.pt`` is written like a
checkpoint, with its SHA-256 in ``latest.json`` beside it, and read like one (``weights_only``).

Maintainers' tool, run from the repository root::

    python -m report.bundle_policy runs/st-split --name general --note "SuperTrack on the split's training clips"
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from common.bundled_configs import PRETRAINED_ROOT, plain_help
from common.run.checkpoint import load_checkpoint_file, recorded_digest, save_checkpoint_file, write_pointer
from common.run.command_line import portable_command_text, portable_path
from report.learners import LEARNERS
from report.runs import ReportError, load_run

POLICY_FILE = "policy.pt"


def bundle(run_dir: str | Path, out: Path, iteration: int | None = None, note: str = "") -> Path:
    """Writes the bundle of ``run_dir``'s checkpoint (``iteration``; None: the newest) into the new folder ``out``.

    Raises:
        ReportError: If the run does not load, its learner has no network policy, or ``out`` exists.
    """
    run = load_run(run_dir, iteration)
    keys = LEARNERS[run.learner].policy_keys  # what its load_eval_policy reads (load_run knows the learner)
    if not keys:
        raise ReportError(f"{run.path}: a {run.learner} run holds no network policy to bundle")
    if out.exists():
        raise ReportError(f"{out}: already exists; remove it or choose another --name")
    state = load_checkpoint_file(run.checkpoint, sha256=recorded_digest(run.checkpoint))
    learner = {k: v for k, v in state["learner"].items() if k in keys}
    out.mkdir(parents=True)
    shutil.copyfile(run.path / "config.yaml", out / "config.yaml")
    record = save_checkpoint_file({"learner": learner, "iteration": run.iteration, "meta": state.get("meta", {})},
                                  out / POLICY_FILE)  # fmt: skip
    write_pointer(out, POLICY_FILE, {POLICY_FILE: record})
    # The bundle ships: its record names the run and its command without the training machine's paths.
    command = run.info.get("command")
    info = {
        "learner": run.learner, "policy_file": POLICY_FILE, "motions": run.motions, "note": note,
        "source": {"run": portable_path(str(run.path.absolute())), "iteration": run.iteration, "samples": run.samples,
                   "train_minutes": round(run.train_seconds / 60.0, 1), "seed": run.info.get("seed"),
                   "command": portable_command_text(command) if isinstance(command, str) else command,
                   "machine": {k: run.info.get(k) for k in ("cpu", "cpu_count", "gpu", "torch", "mujoco")}},
        "samples": run.samples, "train_seconds": run.train_seconds,
    }  # fmt: skip
    (out / "run_info.json").write_text(json.dumps(info, indent=1) + "\n", encoding="utf-8")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m report.bundle_policy", description=plain_help(__doc__),
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("run", metavar="RUN_DIR", help="a SuperTrack or PPO run directory")
    parser.add_argument("--name", required=True, help=f"the bundle's name: written to {PRETRAINED_ROOT}/NAME")
    parser.add_argument("--checkpoint", type=int, metavar="ITER", help="checkpoint iteration (default: the newest)")
    parser.add_argument("--note", default="", help="how the policy was trained and what it tracks, for run_info.json")
    parser.add_argument("--root", type=Path, default=PRETRAINED_ROOT,
                        help="folder of the bundles (default: %(default)s)")  # fmt: skip
    args = parser.parse_args(argv)
    try:
        out = bundle(args.run, args.root / args.name, args.checkpoint, args.note)
    except ReportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    size = sum(f.stat().st_size for f in out.iterdir())
    print(f"wrote {out} ({size / 1e6:.2f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
