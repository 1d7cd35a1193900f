"""Matplotlib figures of the comparison report (Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 - the backend must be chosen first

from report.runs import Run  # noqa: E402

CURVES = (
    ("eval/mpjpe_g", "MPJPE-g (mm)"),
    ("eval/success", "success rate"),
    ("eval/episode_len_ratio", "episode length / max frames"),
)
WORLD_MODEL_PREFIX = "world_model/val_pos_err_h"


def _colors(runs: list[Run]) -> dict[str, str]:
    """One colour per learner, so that several seeds of one method read as one family."""
    cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    learners = sorted({r.learner for r in runs})
    return {name: cycle[i % len(cycle)] for i, name in enumerate(learners)}


def learning_curves(runs: list[Run], out: Path) -> Path:
    """MPJPE-g, success and episode length against samples (top row) and wall-clock (bottom row).

    Returns:
        The PNG written.
    """
    colors = _colors(runs)
    fig, axes = plt.subplots(2, len(CURVES), figsize=(5 * len(CURVES), 7), squeeze=False)
    for col, (key, title) in enumerate(CURVES):
        for run in runs:
            samples, seconds, values = run.curve(key)
            style = {"color": colors[run.learner], "marker": "o", "markersize": 3, "label": run.label}
            axes[0, col].plot(samples, values, **style)
            axes[1, col].plot([s / 60.0 for s in seconds], values, **style)
        axes[0, col].set_title(title)
        axes[0, col].set_xlabel("environment samples")
        axes[1, col].set_xlabel("training wall-clock (min)")
        for row in range(2):
            axes[row, col].grid(alpha=0.3)
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
