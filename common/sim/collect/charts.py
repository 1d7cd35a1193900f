"""What the collector counts while it steps, and the chart keys both learners log from it (one scheme, so that the
report and ``benchmarks/run_curve.py`` read either learner's run).

A source sums, over its characters and a block's steps: the reward, each unweighted reward term, the gym's event
counts (``diverged``, ``term/<rule>``), the episodes that ended, their lengths and how many failed. The sums of
several sources (or several blocks) add up; :func:`chart_metrics` turns them into log keys.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from common.sim.gym import StepResult

# Always present: reward and character-step totals, ended episodes, their frames, the failed ones, stepping time.
CHART_KEYS = ("reward_sum", "steps", "episodes", "episode_frames", "terminated", "collect_s")
# Prefixes of the sums that depend on the gym's config: reward terms and the gym's event counts (StepResult.info).
TERM_PREFIX, EVENT_PREFIX = "reward/", "event/"


def new_charts() -> dict[str, float]:
    """Zero sums for a block."""
    return dict.fromkeys(CHART_KEYS, 0.0)


def add_step(charts: dict[str, float], res: StepResult, episode_frame: np.ndarray) -> None:
    """Adds one gym step of n characters to ``charts``.

    Args:
        charts: The sums, updated in place.
        res: The step's result.
        episode_frame: Frames of each character's episode before the step (the state the step started from).
            Shape: (n,).
    """
    done = res.terminated | res.truncated
    charts["reward_sum"] += float(res.reward.sum())
    charts["steps"] += len(done)
    charts["episodes"] += float(done.sum())
    charts["episode_frames"] += float((episode_frame[done] + 1).sum())
    charts["terminated"] += float(res.terminated.sum())
    for name, value in res.reward_terms.items():
        key = TERM_PREFIX + name
        charts[key] = charts.get(key, 0.0) + float(value.sum())
    for name, count in res.info.items():
        key = EVENT_PREFIX + name
        charts[key] = charts.get(key, 0.0) + float(count)


def sum_charts(charts: list[Mapping[str, float]]) -> dict[str, float]:
    """The sums of several sources or blocks, key by key (keys in order of first appearance)."""
    keys = dict.fromkeys(k for c in charts for k in c)
    return {k: float(sum(c.get(k, 0.0) for c in charts)) for k in keys}


def chart_metrics(charts: Mapping[str, float]) -> dict[str, float]:
    """The log keys of collected sums (empty for no steps):

    - ``charts/reward``: mean reward per character step;
    - ``reward/<term>``: mean unweighted reward term per character step;
    - ``charts/<event>_per_1k``: gym events (``diverged``, ``term/<rule>``: episode ends by termination rule, one
      episode may break several) per 1000 character steps;
    - ``charts/episode_length`` (frames) and ``charts/terminated_share`` (failed, not truncated) of the episodes
      that ended, when any did;
    - ``perf/collect_s``: seconds spent stepping (summed over collector processes).
    """
    steps = charts.get("steps", 0.0)
    if not steps:
        return {}
    out = {"charts/reward": charts["reward_sum"] / steps, "perf/collect_s": charts["collect_s"]}
    out.update({k: v / steps for k, v in charts.items() if k.startswith(TERM_PREFIX)})
    out.update({f"charts/{k.removeprefix(EVENT_PREFIX)}_per_1k": 1000.0 * v / steps for k, v in charts.items()
                if k.startswith(EVENT_PREFIX)})  # fmt: skip
    if charts["episodes"]:
        out["charts/episode_length"] = charts["episode_frames"] / charts["episodes"]
        out["charts/terminated_share"] = charts["terminated"] / charts["episodes"]
    return out
