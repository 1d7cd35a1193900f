"""The one evaluator both learners use: a policy run deterministically over every clip of a motion set.

Every clip is played from ``starts_per_clip`` fixed start frames (evenly spaced, the first at t = 0), all
episodes in parallel in one gym with a fixed seed and no autoreset. An episode lasts ``max_frames`` steps, or until
a one-shot clip ends, or until the evaluation's termination rule fires (by default SuperTrack's: head height off
by more than 25 cm after 48 frames). Each frame is scored with :mod:`common.metrics` on the simulated state against
the reference at the same time; per-clip numbers average the frames of that clip's episodes, and the overall
numbers average the clips (each clip counts once, whatever its length).

A policy is any callable from the gym's :class:`~common.gym.StepResult` to PD targets (N, nu); learners pass their
deterministic (mean, no noise) policy.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from common import metrics as M
from common.gym import GymConfig, StepResult, TrackingGym
from common.humanoid import Humanoid
from common.motion_library import MotionLibrary
from common.rewards import TerminationConfig

Policy = Callable[[StepResult], np.ndarray]
FRAME_METRICS = ("mpjpe_g", "mpjpe_l", "root_pos_err", "root_rot_err", "body_rot_err", "joint_vel_err",
                 "root_vel_err", "root_ang_vel_err")  # fmt: skip


@dataclass(frozen=True)
class EvalConfig:
    """The evaluation protocol (the same for every method compared).

    Attributes:
        starts_per_clip: Episodes per clip, starting at evenly spaced frames (the first at t = 0).
        max_frames: Steps per episode (SuperTrack's 512); one-shot clips end earlier at their last frame.
        seed: Seed of the evaluation gym.
        threads: MuJoCo rollout threads.
        termination: The rule that ends a failed episode.
    """

    starts_per_clip: int = 4
    max_frames: int = 512
    seed: int = 0
    threads: int = 2
    termination: TerminationConfig = field(
        default_factory=lambda: TerminationConfig(max_episode_frames=None, grace_frames=48, head_height_error=0.25)
    )

    def __post_init__(self) -> None:
        if self.starts_per_clip < 1 or self.max_frames < 1:
            raise ValueError("starts_per_clip and max_frames must be >= 1")


@dataclass
class EvalResult:
    """Per-clip table and overall means.

    Attributes:
        clips: Clip names, in library order.
        per_clip: {metric: (C,)} for every metric in :data:`common.metrics.METRIC_NAMES`.
        overall: {metric: mean over clips}.
        episode_length: Steps played per episode. Shape: (C, starts_per_clip).
        episode_max: Steps each episode could have played. Shape: (C, starts_per_clip).
        frames: Steps simulated per character (the longest episode).
    """

    clips: list[str]
    per_clip: dict[str, np.ndarray]
    overall: dict[str, float]
    episode_length: np.ndarray
    episode_max: np.ndarray
    frames: int

    def as_metrics(self, prefix: str = "eval/") -> dict[str, float]:
        """Overall numbers keyed for the metrics log, e.g. ``eval/mpjpe_g``."""
        return {prefix + k: v for k, v in self.overall.items()}

    def table(self) -> str:
        """A plain-text per-clip table with the overall row."""
        keys = list(M.METRIC_NAMES)
        width = {k: max(9, len(k) + 2) for k in keys}
        head = f"{'clip':<20}" + "".join(f"{k:>{width[k]}}" for k in keys)
        rows = [head]
        for i, name in enumerate(self.clips):
            rows.append(f"{name:<20}" + "".join(f"{self.per_clip[k][i]:>{width[k]}.4g}" for k in keys))
        rows.append(f"{'mean over clips':<20}" + "".join(f"{self.overall[k]:>{width[k]}.4g}" for k in keys))
        return "\n".join(rows)


def evaluate(
    policy: Policy, library: MotionLibrary, humanoid: Humanoid, config: EvalConfig | None = None
) -> EvalResult:
    """Runs ``policy`` over every clip of ``library`` from fixed starts and scores it.

    Args:
        policy: Maps the gym's current :class:`StepResult` to PD targets. Shape of its output: (N, nu).
        library: The motion set.
        humanoid: The model (its physics config sets the control rate).
        config: The protocol.
    """
    config = config or EvalConfig()
    nclip, k = library.num_clips, config.starts_per_clip
    clips = np.repeat(np.arange(nclip), k)
    # Start frames evenly spaced over the frames that leave at least one step to play.
    playable = np.where(library.loop, np.ceil(library.duration / library.dt - 1e-9), library.num_frames - 1)
    start_frame = np.floor(np.tile(np.arange(k) / k, nclip) * playable[clips]).astype(np.int64)
    times = start_frame * library.dt
    remaining = np.where(library.loop[clips], config.max_frames, library.num_frames[clips] - 1 - start_frame)
    episode_max = np.minimum(config.max_frames, remaining)
    gym = TrackingGym(
        GymConfig(num_envs=len(clips), threads=config.threads, seed=config.seed, physics=humanoid.physics,
                  termination=config.termination),
        library, humanoid,
    )  # fmt: skip
    try:
        result = gym.reset(clips=clips, times=times)
        n, horizon = len(clips), int(episode_max.max())
        per_frame = {key: np.zeros((horizon, n)) for key in FRAME_METRICS}
        body_err = np.zeros((horizon, n))
        valid = np.zeros((horizon, n), dtype=bool)
        alive = np.ones(n, dtype=bool)
        terminated = np.zeros(n, dtype=bool)
        hinge_dof = humanoid.hinge_dof
        root = humanoid.root_index
        for t in range(horizon):
            result = gym.step(policy(result), autoreset=False)
            sim, ref = result.final_sim, result.final_ref
            valid[t] = alive
            per_frame["mpjpe_g"][t] = M.mpjpe_global_mm(sim.body_pos, ref.body_pos)
            per_frame["mpjpe_l"][t] = M.mpjpe_local_mm(sim.body_pos, ref.body_pos, root_index=root)
            per_frame["root_pos_err"][t] = M.root_pos_error_m(sim.body_pos[:, root], ref.body_pos[:, root])
            per_frame["root_rot_err"][t] = M.root_rot_error_rad(sim.body_rot[:, root], ref.body_rot[:, root])
            per_frame["body_rot_err"][t] = M.body_rot_error_rad(sim.body_rot, ref.body_rot)
            per_frame["joint_vel_err"][t] = M.joint_vel_error(sim.qvel[:, hinge_dof], ref.qvel[:, hinge_dof])
            per_frame["root_vel_err"][t] = M.root_lin_vel_error(sim.body_linvel[:, root], ref.body_linvel[:, root])
            per_frame["root_ang_vel_err"][t] = M.root_ang_vel_error(sim.body_angvel[:, root],
                                                                     ref.body_angvel[:, root])  # fmt: skip
            body_err[t] = M.mean_body_pos_error_m(sim.body_pos, ref.body_pos)
            terminated |= alive & result.terminated
            alive &= ~result.terminated & (t + 1 < episode_max)
            if not alive.any():
                break
        played = int(t + 1)
    finally:
        gym.close()
    valid, body_err = valid[:played], body_err[:played]
    length = valid.sum(axis=0)
    succeeded = M.success(body_err.T, valid=valid.T, terminated=terminated)
    per_clip: dict[str, np.ndarray] = {key: np.zeros(nclip) for key in M.METRIC_NAMES}
    for c in range(nclip):
        eps = clips == c
        means = M.summarise({key: v[:played, eps] for key, v in per_frame.items()}, valid[:, eps])
        for key, value in means.items():
            per_clip[key][c] = value
        per_clip["success"][c] = succeeded[eps].mean()
        per_clip["survival"][c] = (~terminated[eps]).mean()
        per_clip["episode_len_ratio"][c] = np.mean(length[eps] / episode_max[eps])
    overall = {key: float(np.mean(v)) for key, v in per_clip.items()}
    return EvalResult(
        clips=list(library.names), per_clip=per_clip, overall=overall,
        episode_length=length.reshape(nclip, k), episode_max=episode_max.reshape(nclip, k), frames=played,
    )  # fmt: skip


def reference_policy(result: StepResult, humanoid: Humanoid) -> np.ndarray:
    """Open-loop playback: PD targets = the reference's hinge angles at the next frame (the baseline to beat)."""
    return result.ref_next.qpos[:, humanoid.hinge_qpos]
