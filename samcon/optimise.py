"""Closed-loop optimisation of reduced feedback gains with CMA-ES, on top of a SAMCON run's regressed policies.

The regressed policies (:mod:`samcon.feedback`) are fitted to the samples of open-loop searches; measured on walk
(session 15) their gains added about 3 % of the evaluation horizon over none, because what a least-squares fit of
search samples rewards is not what keeps a closed loop up. Liu et al. (2012) tune linear feedback gains by CMA-ES
on the closed loop itself, and Ding et al. (2015) learn reduced-order feedback policies that way: few features,
few actuators, scored by simulating the policy. Here every segment's offset becomes

    a = regressed(k, s) + R_g(k) (s - s*),

with s the deviation from the reference (:func:`samcon.cost.feedback_features`) and s* that of the nearest anchor
path's state (``feedback.anchor: nearest``; the correction is zero on a searched path, which the regressed policy
replays; without anchors s* = 0, the reference), R_g nonzero only from the configured
features (each divided by its spread under the regressed policy) to the configured actuators, g the segment's
group, and each actuator's correction clipped to ``max_correction``. CMA-ES (the ``cma`` package, Hansen's reference
implementation) searches the nonzero entries: each candidate runs from the same random reference starts of the clip,
all candidates and starts batched in one gym under the evaluator's failure rule, and costs per frame 1 once failed,
else its mean body position error over ``error_scale`` (at most 1), averaged over frames and starts. The starts are
drawn at random, anew every generation, not the evaluator's fixed evenly spaced ones, so that the gains are not
fitted to the episodes they are judged on.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import cma
import mujoco
import numpy as np

from common.character.humanoid import Humanoid, mirror_name
from common.evaluation import metrics as M
from common.evaluation.evaluate import EvalConfig
from common.motion.library import MotionLibrary
from common.sim.gym import GymConfig, TrackingGym
from samcon.config import OptimiseConfig
from samcon.cost import FEATURE_NAMES
from samcon.feedback import ClipPlan, FeedbackPolicy


def _actuator_ids(humanoid: Humanoid, names: list[str], key: str) -> list[int]:
    out = []
    for name in names:
        a = mujoco.mj_name2id(humanoid.model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)
        if a < 0:
            known = [mujoco.mj_id2name(humanoid.model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(humanoid.nu)]
            raise ValueError(f"optimise.{key}: no actuator '{name}'; actuators: {', '.join(known)}")
        out.append(a)
    if len(set(out)) < len(out):
        raise ValueError(f"optimise.{key}: actuators must not repeat")
    return out


def reduced_indices(humanoid: Humanoid, config: OptimiseConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The feature and actuator indices the gains connect, and the actuators whose open-loop offsets are searched.

    Raises:
        ValueError: Naming the config key and the unknown name.
    """
    features = []
    for name in config.features:
        if name not in FEATURE_NAMES:
            raise ValueError(f"optimise.features: no feature '{name}'; features: {', '.join(FEATURE_NAMES)}")
        features.append(FEATURE_NAMES.index(name))
    if len(set(features)) < len(features):
        raise ValueError("optimise.features: features must not repeat")
    actuators = _actuator_ids(humanoid, config.actuators, "actuators")
    offsets = _actuator_ids(humanoid, config.offsets, "offsets")
    if config.mirror:
        fpart, _, apart, _ = mirror_maps(humanoid)
        missing = [FEATURE_NAMES[f] for f in fpart[features] if f not in features]
        missing += [humanoid.model.actuator(int(a)).name for a in apart[actuators] if a not in actuators]
        if missing:
            raise ValueError(f"optimise.mirror needs the left-right partner of every listed feature and actuator; "
                             f"missing: {', '.join(missing)}")  # fmt: skip
    return np.array(features, dtype=np.int64), np.array(actuators, dtype=np.int64), np.array(offsets, dtype=np.int64)


def mirror_maps(humanoid: Humanoid) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The sagittal mirror (y -> -y in the heading frame, x forward, y left, z up) of features and actuators.

    A reflection S = diag(1, -1, 1) maps a rotation about axis n by theta to one about -S n by theta: about x and z
    it negates the angle, about y it keeps it; vectors (velocity, foot offsets) negate their y. An actuator's partner
    is its left-right namesake; its sign comes from the model's joint axes at the zero pose, so a model whose
    partners' axes are not mirror images is refused.

    Returns:
        feature partner (D,), feature sign (D,), actuator partner (nu,), actuator sign (nu,): the mirror of state s
        is ``sign * s[partner]``, that of offsets a likewise.
    """
    fpart = np.array([FEATURE_NAMES.index(mirror_name(n)) for n in FEATURE_NAMES])
    rotation = ("root_tilt_", "root_ang_vel_")
    fsign = np.array([(-1.0 if n[-1] in "xz" else 1.0) if n.startswith(rotation) else (-1.0 if n[-1] == "y" else 1.0)
                      for n in FEATURE_NAMES])  # fmt: skip
    fsign[FEATURE_NAMES.index("root_height")] = 1.0
    m = humanoid.model
    data = mujoco.MjData(m)
    data.qpos[3] = 1.0
    mujoco.mj_kinematics(m, data)
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in range(m.nu)]
    apart = np.array([names.index(mirror_name(n)) for n in names])
    axes = data.xaxis[m.actuator_trnid[:, 0]]
    asign = np.einsum("ad,ad->a", axes[apart], -axes * np.array([1.0, -1.0, 1.0]))
    if not np.allclose(np.abs(asign), 1.0, atol=1e-6):
        raise ValueError(f"{humanoid.xml_path}: left and right joint axes are not mirror images")
    return fpart, fsign, apart, np.round(asign)


@dataclass
class GainLayout:
    """Where a parameter vector's entries go: first ``groups`` gain matrices (nu, D), each nonzero at (actuators x
    features), the features divided by ``scale``, in group-major, then actuator-major order; then, with
    ``offset_actuators``, one open-loop offset per segment of the plan (``segments``) and listed actuator, in
    segment-major order. With ``mirror`` (the partner indices and signs of :func:`mirror_maps`), only the first half
    of the groups is free and group ``g + groups / 2`` is the mirror image of group g:
    ``R'[a, f] = sign_a sign_f R[partner a, partner f]``; the offsets are not mirrored."""

    groups: int
    nu: int
    features: np.ndarray
    actuators: np.ndarray
    scale: np.ndarray
    mirror: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
    offset_actuators: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    segments: int = 0

    def __post_init__(self) -> None:
        if self.mirror is not None:
            fpart, _, apart, _ = self.mirror
            if self.groups % 2:
                raise ValueError(f"optimise.mirror needs an even number of groups, got {self.groups}")
            if set(fpart[self.features]) != set(self.features) or set(apart[self.actuators]) != set(self.actuators):
                raise ValueError("optimise.mirror needs the left-right partner of every listed feature and actuator")

    @property
    def free_groups(self) -> int:
        return self.groups // 2 if self.mirror is not None else self.groups

    @property
    def gain_size(self) -> int:
        return self.free_groups * len(self.actuators) * len(self.features)

    @property
    def size(self) -> int:
        return self.gain_size + self.segments * len(self.offset_actuators)

    def gains(self, theta: np.ndarray) -> np.ndarray:
        """Gain matrices of parameter vectors ``theta`` (..., size). Shape: (..., groups, nu, D)."""
        lead = theta.shape[:-1]
        blocks = theta[..., : self.gain_size].reshape(*lead, self.free_groups, len(self.actuators), len(self.features))
        out = np.zeros((*lead, self.free_groups, self.nu, len(FEATURE_NAMES)))
        out[..., self.actuators[:, None], self.features[None, :]] = blocks / self.scale[self.features]
        if self.mirror is None:
            return out
        fpart, fsign, apart, asign = self.mirror
        mirrored = out[..., apart[:, None], fpart[None, :]] * asign[:, None] * fsign[None, :]
        return np.concatenate([out, mirrored], axis=-3)

    def offsets(self, theta: np.ndarray) -> np.ndarray:
        """Per-segment open-loop offsets of parameter vectors ``theta`` (..., size). Shape: (..., segments, nu)."""
        lead = theta.shape[:-1]
        out = np.zeros((*lead, self.segments, self.nu))
        tail = theta[..., self.gain_size :]
        out[..., self.offset_actuators] = tail.reshape(*lead, self.segments, len(self.offset_actuators))
        return out


class CandidatePolicy(FeedbackPolicy):
    """The regressed policy of one clip plus, per character, its own reference gains (groups, nu, D) and, if given,
    its own per-segment offsets (S, nu)."""

    def __init__(self, plan: ClipPlan, name: str, library: MotionLibrary, humanoid: Humanoid, gains: np.ndarray,
                 limit: float, offsets: np.ndarray | None = None) -> None:  # fmt: skip
        super().__init__({name: plan}, library, humanoid)
        self.gains, self.limit, self.offsets = gains, limit, offsets
        self.deviations: list[np.ndarray] = []  # every deviation the gains were applied to

    def _offset(self, i: int, plan: ClipPlan, k: int, s: np.ndarray) -> np.ndarray:
        gain = self.gains[i, plan.group(k, self.gains.shape[1])]
        base, diff = plan.regressed(k, s)
        self.deviations.append(diff)
        out = base + np.clip(gain @ diff, -self.limit, self.limit)
        return out if self.offsets is None else out + self.offsets[i, k]


def rollout_cost(plan: ClipPlan, name: str, library: MotionLibrary, humanoid: Humanoid, gains: np.ndarray,
                 limit: float, times: np.ndarray, frames: int, ev: EvalConfig, error_scale: float, threads: int = 1,
                 collect: list[np.ndarray] | None = None,
                 offsets: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Each of C candidates' gains from each of S starts, batched in one gym (evaluator's failure rule, no autoreset).

    Args:
        gains: Per candidate. Shape: (C, groups, nu, D).
        limit: The largest correction ``|R s|`` per actuator (rad).
        times: Start times in the clip (s). Shape: (S,).
        frames: Steps per episode (cut at a one-shot clip's last frame).
        collect: If given, the deviations the gains were applied to (D,) are appended to it.
        offsets: Per candidate, open-loop offsets added to every segment's (plan segments). Shape: (C, K, nu).

    Returns:
        cost (C,): mean over starts and frames of 1 once failed, else min(body error / error_scale, 1);
        played (C,): mean share of the frames played before the first failure.
    """
    ncand, nstart = len(gains), len(times)
    clip = library.clip_index(name)
    left = frames if library.loop[clip] else int(library.num_frames[clip] - 1 - np.floor(times.max() / library.dt))
    horizon = max(1, min(frames, left))
    gym = TrackingGym(GymConfig(num_envs=ncand * nstart, threads=threads, seed=ev.seed, physics=humanoid.physics,
                                termination=ev.termination, rsi_lift=ev.rsi_lift), library, humanoid)  # fmt: skip
    each = None if offsets is None else np.repeat(offsets, nstart, axis=0)
    policy = CandidatePolicy(plan, name, library, humanoid, np.repeat(gains, nstart, axis=0), limit, each)
    try:
        result = gym.reset(clips=np.full(ncand * nstart, clip), times=np.tile(times, ncand))
        alive = np.ones(ncand * nstart, dtype=bool)
        total, length = np.zeros(ncand * nstart), np.zeros(ncand * nstart)
        for _ in range(horizon):
            result = gym.step(policy(result), autoreset=False)
            err = M.mean_body_pos_error_m(result.final_sim.body_pos, result.final_ref.body_pos)
            length += alive  # the evaluator counts the step a failure fires on as played
            alive &= ~result.terminated
            total += np.where(alive, np.minimum(err / error_scale, 1.0), 1.0)
    finally:
        gym.close()
    if collect is not None:
        collect.extend(policy.deviations)
    per = total.reshape(ncand, nstart) / horizon
    return per.mean(axis=1), (length.reshape(ncand, nstart) / horizon).mean(axis=1)


def draw_starts(library: MotionLibrary, name: str, count: int, frames: int, rng: np.random.Generator) -> np.ndarray:
    """Start times (s) on the clip's frame grid, stratified: one uniform draw in each of ``count`` equal stretches
    of the clip (a loop clip: its cycle; a one-shot clip: what leaves ``frames`` steps where it can), so that every
    generation covers the whole clip (less noise between candidates than independent draws) at new frames."""
    clip = library.clip_index(name)
    if library.loop[clip]:
        last = int(np.ceil(library.duration[clip] / library.dt - 1e-9))
    else:
        last = max(1, int(library.num_frames[clip]) - 1 - frames)
    return np.floor((np.arange(count) + rng.random(count)) * last / count) * library.dt


def optimise_gains(plan: ClipPlan, name: str, library: MotionLibrary, humanoid: Humanoid, config: OptimiseConfig,
                   ev: EvalConfig, rng: np.random.Generator, threads: int = 1,
                   log: Any = None) -> tuple[ClipPlan, dict[str, Any]]:  # fmt: skip
    """CMA-ES over the reduced reference gains of one clip's plan (and, with ``config.offsets``, its per-segment
    open-loop offsets on those actuators).

    Returns:
        The plan with ``ref_gain`` (and ``ref_offset``) set to the search's final mean, and a history
        {"generation", "cost_mean", "cost_best", "played_best", "cost_at_mean", "played_at_mean"} of lists.
    """
    features, actuators, offset_actuators = reduced_indices(humanoid, config)
    # The deviations' spread under the regressed policy alone, from one batch of starts (the gains' units): the
    # median absolute deviation, as a standard deviation, so that the falls' huge deviations do not set it.
    seen: list[np.ndarray] = []
    zero = np.zeros((1, config.groups, humanoid.nu, len(FEATURE_NAMES)))
    times = draw_starts(library, name, config.starts, config.frames, rng)
    base_cost, base_played = rollout_cost(plan, name, library, humanoid, zero, 0.0, times, config.frames, ev,
                                          config.error_scale, threads, collect=seen)  # fmt: skip
    # Floored: over a short rollout some features hardly move, and a tiny spread would make their gains huge.
    seen_all = np.stack(seen)
    mad = np.median(np.abs(seen_all - np.median(seen_all, axis=0)), axis=0)
    scale = np.maximum(1.4826 * mad, config.min_spread)
    # The mirror's scale: a feature and its partner share the larger spread, so mirrored gains mean the same.
    mirror = mirror_maps(humanoid) if config.mirror else None
    if mirror is not None:
        scale = np.maximum(scale, scale[mirror[0]])
    layout = GainLayout(config.groups, humanoid.nu, features, actuators, scale, mirror, offset_actuators,
                        len(plan.bounds) - 1 if len(offset_actuators) else 0)  # fmt: skip
    # One step size, per-coordinate scales: the offsets (rad) start at offset_sigma, the gains at sigma.
    stds = np.concatenate([np.ones(layout.gain_size), np.full(layout.size - layout.gain_size,
                                                                config.offset_sigma / config.sigma)])  # fmt: skip
    es = cma.CMAEvolutionStrategy(np.zeros(layout.size), config.sigma,
                                  {"popsize": config.population, "seed": int(rng.integers(1, 2**31 - 1)),
                                   "verbose": -9, "CMA_stds": stds})  # fmt: skip
    history: dict[str, list[float]] = {k: [] for k in ("generation", "cost_mean", "cost_best", "played_best",
                                                      "cost_at_mean", "played_at_mean")}  # fmt: skip
    _say(log, f"{name}: closed-loop gains ({layout.size} parameters, {layout.size - layout.gain_size} of them "
              f"offsets): regressed policy alone costs "
              f"{base_cost[0]:.3f}, plays {base_played[0]:.0%} of {config.frames} frames")  # fmt: skip
    for gen in range(config.generations):
        candidates = np.asarray(es.ask())
        # The distribution's mean rides along as one more candidate: the learning curve of what is returned.
        theta = np.concatenate([candidates, es.mean[None]])
        times = draw_starts(library, name, config.starts, config.frames, rng)
        offsets = layout.offsets(theta) if layout.segments else None
        cost, played = rollout_cost(plan, name, library, humanoid, layout.gains(theta), config.max_correction, times,
                                    config.frames, ev, config.error_scale, threads, offsets=offsets)  # fmt: skip
        es.tell(list(candidates), list(cost[:-1]))
        b = int(np.argmin(cost[:-1]))
        for key, value in zip(history, (gen + 1, float(cost[:-1].mean()), float(cost[b]), float(played[b]),
                                        float(cost[-1]), float(played[-1])), strict=True):  # fmt: skip
            history[key].append(value)
        _say(log, f"{name}: generation {gen + 1}/{config.generations}: cost best {cost[b]:.3f} mean "
                  f"{cost[:-1].mean():.3f}; the mean's {cost[-1]:.3f}, plays {played[-1]:.0%}; "
                  f"step {es.sigma:.3g}")  # fmt: skip
    summary = {"parameters": layout.size, "base_cost": float(base_cost[0]), "base_played": float(base_played[0])}
    ref_offset = layout.offsets(es.mean) if layout.segments else None
    new = replace(plan, ref_gain=layout.gains(es.mean), ref_limit=config.max_correction, ref_offset=ref_offset)
    return new, {**summary, **history}


def plot_history(histories: dict[str, dict[str, Any]], path: Any) -> None:
    """The closed-loop gain searches' learning curves, one panel per clip: the cost of the distribution's mean (what
    is returned) and of the best candidate per generation, and the share of the episodes' frames the mean played
    before a fall."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(histories), figsize=(5 * len(histories), 3.5), squeeze=False)
    for ax, (name, h) in zip(axes[0], histories.items(), strict=True):
        ax.plot(h["generation"], h["cost_at_mean"], label="cost at the mean")
        ax.plot(h["generation"], h["cost_best"], label="best candidate's cost", alpha=0.6)
        ax.plot(h["generation"], h["played_at_mean"], label="share played (mean)", linestyle="--")
        ax.axhline(h["base_cost"], color="grey", linewidth=0.8, label="regressed policy alone")
        ax.set_title(f"{name}: {h['parameters']} gains")
        ax.set_xlabel("generation")
        ax.set_ylim(0.0, 1.05)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _say(log: Any, text: str) -> None:
    if log is not None:
        print(text, file=log, flush=True)
