"""Markdown tables of the comparison report: per-clip metrics, thresholds, world model, runs."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from common.evaluation import metrics as M
from common.evaluation.evaluate import EvalResult
from common.run.command_line import portable_command_text
from report.figures import world_model_keys
from report.runs import Run, method_groups

NUMBER_FORMAT = ".6g"  # enough digits that the tables reproduce the evaluator's numbers to 1e-5 relative


@dataclass(frozen=True)
class Threshold:
    """A level of a logged eval metric that a method may reach during training.

    Attributes:
        label: Display name.
        key: Metrics-log key.
        reached: Test on the logged value.
    """

    label: str
    key: str
    reached: Callable[[float], bool]


THRESHOLDS = (
    Threshold("survival >= 90 %", "eval/survival", lambda v: v >= 0.9),
    Threshold("MPJPE-g <= 100 mm", "eval/mpjpe_g", lambda v: v <= 100.0),
    Threshold("MPJPE-g <= 60 mm", "eval/mpjpe_g", lambda v: v <= 60.0),
)


def fmt(value: float) -> str:
    return "nan" if not np.isfinite(value) else format(float(value), NUMBER_FORMAT)


def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A GitHub-flavoured Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def _metric_rows(values: dict[str, list[float]]) -> list[list[str]]:
    """One row per metric; the best value(s) of the row in bold (unmarked when all are equal or NaN, and in a row of
    the reference's own figure, which ranks no method)."""
    rows = []
    for key in M.METRIC_NAMES:
        info, row = M.METRICS[key], values[key]
        best = row[M.best_index(key, row)] if info.ranked and np.isfinite(row).any() else np.nan
        # Ties are all marked; a row where every method is equal marks none (there is nothing to pick).
        mark = [v == best for v in row] if not all(v == best for v in row) else [False] * len(row)
        unit = f" ({info.unit})" if info.unit else ""
        cells = [f"**{fmt(v)}**" if m else fmt(v) for v, m in zip(row, mark, strict=True)]
        rank = f"{'higher' if info.higher_is_better else 'lower'} better"
        rank = rank if info.ranked else "the reference's, not ranked"
        rows.append([f"{key}{unit}, {rank}", *cells])
    return rows


def metric_tables(labels: list[str], results: list[EvalResult]) -> str:
    """The overall table, with several clips a clip-per-row summary, then one table per clip: rows are the
    evaluator's metrics, columns the runs."""
    parts = ["#### Mean over clips\n", table(["metric", *labels], _metric_rows(
        {k: [r.overall[k] for r in results] for k in M.METRIC_NAMES}))]  # fmt: skip
    if len(results[0].clips) > 1:
        glance = clip_summary_table(labels, results, ("survival", "mpjpe_g", "mpjpe_l"))
        parts += ["\n#### Per clip at a glance\n", glance]
        parts += ["\n#### Motion quality per clip\n", clip_summary_table(labels, results, MOTION_QUALITY)]
    for c, clip in enumerate(results[0].clips):
        values = {k: [float(r.per_clip[k][c]) for r in results] for k in M.METRIC_NAMES}
        parts += [f"\n#### Clip `{clip}`\n", table(["metric", *labels], _metric_rows(values))]
    return "\n".join(parts)


MOTION_QUALITY = ("accel_err", "vel_err", "foot_slide", "foot_slide_ref", "target_jitter")
_SHORT_NAMES = {"survival": "survival", "mpjpe_g": "MPJPE-g (mm)", "mpjpe_l": "MPJPE-l (mm)",
                "accel_err": "accel (mm/frame^2)", "vel_err": "vel (mm/frame)", "foot_slide": "foot slide (mm/frame)",
                "foot_slide_ref": "reference's (mm/frame)", "target_jitter": "target jitter (rad/frame^2)"}  # fmt: skip


def clip_summary_table(labels: list[str], results: list[EvalResult], keys: Sequence[str]) -> str:
    """A row per clip, a column per run holding ``keys`` as "a / b / ...", the mean over clips last."""
    rows = [[f"`{clip}`", *[" / ".join(fmt(r.per_clip[k][c]) for k in keys) for r in results]]
            for c, clip in enumerate(results[0].clips)]  # fmt: skip
    rows.append(["mean", *[" / ".join(fmt(r.overall[k]) for k in keys) for r in results]])
    names = " / ".join(_SHORT_NAMES.get(k, k) for k in keys)
    return table(["clip", *[f"{label}: {names}" for label in labels]], rows)


def robustness_table(labels: list[str], results: list[EvalResult]) -> str:
    """Per clip and run under pushes: survival and MPJPE-g (full horizon), the mean over clips last."""
    return clip_summary_table(labels, results, ("survival", "mpjpe_g"))


def _duration(seconds: float) -> str:
    return f"{seconds:.1f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


def threshold_table(runs: list[Run]) -> str:
    """Samples and training wall-clock (evaluation time excluded) at the first logged evaluation reaching each one."""
    rows = []
    for run in runs:
        row = [run.label]
        for t in THRESHOLDS:
            samples, seconds, values = run.curve(t.key)
            hit = next((i for i, v in enumerate(values) if t.reached(v)), None)
            row.append("not reached" if hit is None else f"{samples[hit]:,} samples / {_duration(seconds[hit])}")
        rows.append(row)
    return table(["run", *(t.label for t in THRESHOLDS)], rows)


def parity(runs: list[Run], key: str = "eval/mpjpe_g") -> list[dict]:
    """What one method needs to reach another's final figure, for every ordered pair of methods (A, B).

    B's final figure: the mean over B's runs of their last logged ``key`` (MPJPE-g; lower is better). Per run of A
    (by seed): the samples and training wall-clock at A's first logged evaluation at or below it, and their ratios to
    B's mean samples and wall-clock at B's last evaluation; ``samples`` None where A's curve does not reach it.
    Methods without a logged curve (SAMCON) take no part; fewer than two methods give an empty list.

    Returns:
        One dict per pair: ``method`` (A), ``target_method`` (B), ``target`` (B's final figure), ``target_samples``,
        ``target_seconds`` (B's means at its end) and ``runs``: per run of A its ``label``, ``seed``, ``samples``,
        ``seconds``, ``sample_ratio``, ``time_ratio`` (None where never reached).
    """
    groups = method_groups(runs)
    if len(groups) < 2:
        return []
    finals: dict[str, tuple[float, float, float]] = {}  # method: (value, samples, seconds), means over its runs
    for name, idx in groups.items():
        ends = []
        for i in idx:
            samples, seconds, values = runs[i].curve(key)
            if values:
                ends.append((values[-1], samples[-1], seconds[-1]))
        if ends:
            value, samples_end, seconds_end = (float(np.mean(col)) for col in zip(*ends, strict=True))
            finals[name] = (value, samples_end, seconds_end)
    pairs = []
    for a, idx in groups.items():
        if a not in finals:  # no logged curve (a SAMCON oracle): nothing to reach with
            continue
        for b, (target, b_samples, b_seconds) in finals.items():
            if a == b:
                continue
            reached = []
            for i in idx:
                samples, seconds, values = runs[i].curve(key)
                hit = next((j for j, v in enumerate(values) if v <= target), None)
                entry: dict = {"label": runs[i].label, "seed": runs[i].seed, "samples": None, "seconds": None,
                               "sample_ratio": None, "time_ratio": None}  # fmt: skip
                if hit is not None:
                    entry.update(samples=int(samples[hit]), seconds=float(seconds[hit]),
                                 sample_ratio=float(samples[hit] / b_samples),
                                 time_ratio=float(seconds[hit] / b_seconds))  # fmt: skip
                reached.append(entry)
            pairs.append({"method": a, "target_method": b, "target": target, "target_samples": b_samples,
                          "target_seconds": b_seconds, "runs": reached})  # fmt: skip
    return pairs


def parity_table(runs: list[Run], key: str = "eval/mpjpe_g") -> str | None:
    """:func:`parity` as a Markdown table: one row per ordered pair of methods, the runs of A by seed. None with
    fewer than two methods."""
    pairs = parity(runs, key)
    if not pairs:
        return None
    rows = []
    for pair in pairs:
        cells = []
        for r in pair["runs"]:
            where = f"seed {r['seed']}" if r["seed"] is not None else r["label"]
            if r["samples"] is None:
                cells.append(f"{where}: never")
            else:
                cells.append(f"{where}: {r['samples']:,} samples ({r['sample_ratio']:.2f}x), "
                             f"{_duration(r['seconds'])} ({r['time_ratio']:.2f}x)")  # fmt: skip
        rows.append([pair["method"], f"{pair['target_method']}: {pair['target']:.1f}", "; ".join(cells)])
    return table(["method", "reaches the final MPJPE-g (mm) of", "first evaluation at or below it, per seed "
                  "(ratio to the other's samples and minutes at its end)"], rows)  # fmt: skip


def world_model_table(runs: list[Run]) -> str | None:
    """Last logged held-out world-model position error per horizon; None when no run logged one."""
    rows = []
    for run in runs:
        for horizon, key in world_model_keys(run):
            samples, _, values = run.curve(key)
            rows.append([run.label, str(horizon), fmt(values[-1]), f"{samples[-1]:,}"])
    return table(["run", "horizon (frames)", "position error", "at samples"], rows) if rows else None


# PPO's update statistics (both PPO arms log them under these names): what says whether an update stays in PPO's
# normal regime (approximate KL per update about 0.01-0.03, a clip fraction under about 0.2).
UPDATE_STATISTICS = (
    ("approx. KL (k3)", "losses/approx_kl"), ("KL of the Gaussians", "losses/kl"),
    ("clip fraction", "losses/clip_frac"), ("explained variance", "charts/explained_variance"),
    ("actor learning rate", "charts/learning_rate"),
)  # fmt: skip


def update_statistics_table(runs: list[Run]) -> str | None:
    """Median of each of :data:`UPDATE_STATISTICS` over the logged iterations of the last half of each run's training
    wall-clock (the first and last value beside it); None when no run logged any."""
    rows = []
    for run in runs:
        cells, found = [], False
        for _, key in UPDATE_STATISTICS:
            _, seconds, values = run.curve(key)
            if not values:
                cells.append("-")
                continue
            found = True
            half = [v for t, v in zip(seconds, values, strict=True) if t >= seconds[-1] / 2]
            cells.append(f"{fmt(float(np.median(half)))} ({fmt(values[0])} -> {fmt(values[-1])})")
        if found:
            rows.append([run.label, *cells])
    header = ["run", *(f"{name}: median, last half (first -> last)" for name, _ in UPDATE_STATISTICS)]
    return table(header, rows) if rows else None


def runs_table(runs: list[Run]) -> str:
    """Machine, versions, seed and checkpoint of every run."""
    rows = []
    for run in runs:
        i = run.info
        rows.append([
            run.label, run.learner, str(run.seed), ", ".join(run.motions), f"{run.iteration} ({run.checkpoint.name})",
            f"{run.samples:,}", f"{run.train_seconds / 60:.2f}", f"{i.get('cpu')} x{i.get('cpu_count')}",
            str(i.get("torch_threads")), str(i.get("gpu") or "none"),
            f"python {i.get('python')}, torch {i.get('torch')}, mujoco {i.get('mujoco')}, numpy {i.get('numpy')}",
        ])  # fmt: skip
    header = ["run", "learner", "seed", "trained on", "iteration (checkpoint)", "samples", "train min", "CPU",
              "torch threads", "GPU", "versions"]  # fmt: skip
    return table(header, rows)


def configs_block(runs: list[Run]) -> str:
    """Every run's resolved config and command line (without the training machine's paths), as fenced JSON."""
    parts = []
    for run in runs:
        command = run.info.get("command")
        parts.append(f"**{run.label}** (`{portable_command_text(command) if isinstance(command, str) else '?'}`)\n")
        parts.append("```json\n" + json.dumps(run.config, indent=1, default=str) + "\n```\n")
    return "\n".join(parts)


def mean_std(values: Sequence[float]) -> str:
    """``mean ± std (n=N)`` with the sample standard deviation (ddof 1; 0 for one value); NaNs left out."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return "nan"
    return f"{fmt(v.mean())} ± {fmt(v.std(ddof=1) if len(v) > 1 else 0.0)} (n={len(v)})"


def spread_table(runs: list[Run], results: list[EvalResult], pushed: list[EvalResult] | None = None) -> str | None:
    """Mean ± std over the runs of each learner (several seeds); None when every learner has one run.

    With ``pushed`` (the same runs under the robustness protocol), its survival and MPJPE-g are rows too.
    """
    groups = method_groups(runs)
    if all(len(g) < 2 for g in groups.values()):
        return None
    rows = [[key, *(mean_std([results[i].overall[key] for i in idx]) for idx in groups.values())]
            for key in M.METRIC_NAMES]  # fmt: skip
    if pushed:
        for key in ("survival", "mpjpe_g"):
            rows.append([f"{key} under pushes",
                         *(mean_std([pushed[i].overall[key] for i in idx]) for idx in groups.values())])  # fmt: skip
    return table(["metric", *groups], rows)


PER_CLIP_SPREAD = ("mpjpe_g", "mpjpe_l", "survival", "success", "accel_err", "foot_slide")


def per_clip_spread_table(runs: list[Run], results: list[EvalResult]) -> str | None:
    """Per clip, each learner's mean ± std over its seeds of MPJPE-g / -l, survival, success, acceleration error and
    foot sliding; None when every learner has one run."""
    groups = method_groups(runs)
    if all(len(g) < 2 for g in groups.values()):
        return None
    rows = []
    for c, clip in enumerate(results[0].clips):
        for key in PER_CLIP_SPREAD:
            rows.append([f"`{clip}`", key, *(mean_std([results[i].per_clip[key][c] for i in idx])
                                              for idx in groups.values())])  # fmt: skip
    return table(["clip", "metric", *groups], rows)


def oracle_table(oracles: dict[str, tuple[EvalResult, dict[str, float]]], labels: list[str],
                 results: list[EvalResult]) -> str:  # fmt: skip
    """Per clip: the oracle run that tracked it (the lowest MPJPE-g if several did), its open-loop MPJPE-g / -l from
    the clip's start (mm, whole), whether it fell and its minutes, then every run's MPJPE-g / -l under the standard
    protocol; an oracle run on a clip it did not track says so (its policy there only plays the reference)."""
    header = ["clip", "oracle run", "open loop MPJPE-g / -l (mm)", "fell", "minutes"]
    header += [f"{x} MPJPE-g / -l (mm)" for x in labels]

    def mm(res: EvalResult, c: int) -> str:
        return " / ".join("nan" if not np.isfinite(v) else f"{v:.0f}"
                          for v in (res.per_clip["mpjpe_g"][c], res.per_clip["mpjpe_l"][c]))  # fmt: skip

    rows = []
    for c, clip in enumerate(results[0].clips):
        tracked = [(res.per_clip["mpjpe_g"][c], label, res, minutes[clip])
                   for label, (res, minutes) in oracles.items() if clip in minutes]  # fmt: skip
        if tracked:
            _, label, res, minutes = min(tracked, key=lambda t: t[0])
            row = [clip, label, mm(res, c), "no" if res.per_clip["survival"][c] == 1.0 else "yes", f"{minutes:.1f}"]
        else:
            row = [clip, "not tracked", "", "", ""]
        row += ["not tracked" if label in oracles and clip not in oracles[label][1] else mm(r, c)
                for label, r in zip(labels, results, strict=True)]  # fmt: skip
        rows.append(row)
    return table(header, rows)
