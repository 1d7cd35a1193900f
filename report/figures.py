"""Matplotlib figures of the comparison report (Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 - the backend must be chosen first

from report.runs import Run, method_groups  # noqa: E402

# (metric, title, y-axis scale). MPJPE-g spans four decades in one run (metres after a fall, tens of millimetres
# once it tracks): on a linear axis everything under ~500 mm is one flat line, where the targets (40-100 mm) lie.
CURVES = (
    ("eval/mpjpe_g", "MPJPE-g (mm, log scale)", "log"),
    ("eval/success", "success rate", "linear"),
    ("eval/episode_len_ratio", "episode length / max frames", "linear"),
)
WORLD_MODEL_PREFIX = "world_model/val_pos_err_h"


def _band(xs: list[list[float]], ys: list[list[float]], points: int = 50) -> tuple[np.ndarray, ...] | None:
    """Mean, min and max over runs of curves y(x), interpolated on a grid spanning the x range all runs cover."""
    xs_ok = [(np.asarray(x, float), np.asarray(y, float)) for x, y in zip(xs, ys, strict=True) if len(x) >= 2]
    if len(xs_ok) < 2:
        return None
    lo, hi = max(x[0] for x, _ in xs_ok), min(x[-1] for x, _ in xs_ok)
    if hi <= lo:
        return None
    grid = np.linspace(lo, hi, points)
    stack = np.stack([np.interp(grid, x, y) for x, y in xs_ok])
    return grid, stack.mean(axis=0), stack.min(axis=0), stack.max(axis=0)


def learning_curves(runs: list[Run], out: Path) -> Path:
    """MPJPE-g, success and episode length against samples (top row) and wall-clock (bottom row).

    A method with several runs (seeds of one config, :func:`report.runs.method_groups`) is drawn as thin per-seed
    lines, their mean (thick) and a band from the lowest to the highest seed, over the range of samples / minutes
    that every seed reached.

    Returns:
        The PNG written.
    """
    groups = {name: [runs[i] for i in idx] for name, idx in method_groups(runs).items()}
    cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    colors = {name: cycle[i % len(cycle)] for i, name in enumerate(groups)}
    fig, axes = plt.subplots(2, len(CURVES), figsize=(5 * len(CURVES), 7), squeeze=False)
    for col, (key, title, scale) in enumerate(CURVES):
        for method, members in groups.items():
            curves = [run.curve(key) for run in members]
            several = len(members) > 1
            for run, (samples, seconds, values) in zip(members, curves, strict=True):
                style = {"color": colors[method], "marker": "o", "markersize": 2 if several else 3,
                         "linewidth": 0.8 if several else 1.5, "alpha": 0.45 if several else 1.0,
                         "label": None if several else run.label}  # fmt: skip
                axes[0, col].plot(samples, values, **style)
                axes[1, col].plot([s / 60.0 for s in seconds], values, **style)
            if not several:
                continue
            for row, xs in ((0, [c[0] for c in curves]), (1, [[s / 60.0 for s in c[1]] for c in curves])):
                band = _band(xs, [c[2] for c in curves])
                if band is None:
                    continue
                grid, mean, low, high = band
                axes[row, col].plot(grid, mean, color=colors[method], linewidth=2.2,
                                    label=f"{method}: mean of {len(members)} seeds (band: min-max)")  # fmt: skip
                axes[row, col].fill_between(grid, low, high, color=colors[method], alpha=0.18)
        axes[0, col].set_title(title)
        axes[0, col].set_xlabel("environment samples")
        axes[1, col].set_xlabel("training wall-clock (min)")
        for row in range(2):
            axes[row, col].set_yscale(scale)
            axes[row, col].grid(alpha=0.3, which="both" if scale == "log" else "major")
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out


def world_model_keys(run: Run) -> list[tuple[int, str]]:
    """(horizon, key) of the held-out world-model position errors the run logged, by horizon."""
    keys = {k for m in run.metrics for k in m if k.startswith(WORLD_MODEL_PREFIX)}
    return sorted((int(k.removeprefix(WORLD_MODEL_PREFIX)), k) for k in keys if k[len(WORLD_MODEL_PREFIX) :].isdigit())


def world_model_curves(runs: list[Run], out: Path) -> Path | None:
    """Held-out world-model position error per open-loop horizon against samples; None when no run logged it."""
    with_wm = [r for r in runs if world_model_keys(r)]
    if not with_wm:
        return None
    fig, ax = plt.subplots(figsize=(6, 4))
    for run in with_wm:
        for horizon, key in world_model_keys(run):
            samples, _, values = run.curve(key)
            ax.plot(samples, values, marker="o", markersize=3, label=f"{run.label} h={horizon}")
    ax.set_yscale("log")
    ax.set_xlabel("environment samples")
    ax.set_ylabel("position error (held-out)")
    ax.set_title("SuperTrack world model: open-loop prediction error")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out
