"""The one evaluator both learners use: a policy run deterministically over every clip of a motion set.

Every clip is played from ``starts_per_clip`` fixed start frames (evenly spaced, the first at t = 0), all
episodes in parallel in one gym with a fixed seed and no autoreset. Each frame is scored with
:mod:`common.evaluation.metrics` on the simulated state against the reference at the same time; per-clip numbers average
the frames of that clip's episodes, and the overall numbers average the clips (each clip counts once, whatever its
length).

**The protocol (full horizon, the default).** Every episode plays its whole horizon: ``max_frames`` steps (512), or
to a one-shot clip's last frame. The failure rule (by default SuperTrack's: head height off by more than 25 cm after
48 frames) does not end an episode: it marks it failed at the frame it first fires, and the character plays on, so
a policy that falls is charged for every frame it spends fallen while the reference moves on; failing early can
never lower its error. A simulation that blows up is scored from then on as if frozen in its last state before the
blow-up. Survival is the share of episodes no rule failed; episode length / max is the share of the horizon played
before the first failure; success (UHC/PHC) needs no failure and a mean body error never above 0.5 m. Beside the
full-horizon errors, ``mpjpe_g_succ`` / ``mpjpe_l_succ`` are the field's success-only figures (PHC, UHC): the error
over the episodes that succeeded, to be read with the success rate (NaN for a clip with none; the overall figure
averages the clips that have one). ``full_horizon=False`` is the earlier protocol: an episode ends at its first
failure and only the frames before it are scored (a method can look better there by failing sooner).

**Robustness** (``pushes``): the same protocol with an impulse on the pelvis at fixed frames of every episode
(:class:`common.sim.pushes.PushConfig`: by default 30 N s, horizontal, in a seeded random direction, at frame 60 and
every 2 s after), applied between two control steps so that the policy sees it.

**Motion quality** (:mod:`common.evaluation.metrics`): ``vel_err`` and ``accel_err`` (UHC/PHC: the first and second
differences of every body's position against the reference's, mm/frame and mm/frame^2), ``foot_slide`` and
``foot_slide_ref`` (the horizontal speed of a foot while its lowest point is less than 2 cm above the ground, in
mm/frame, of the character and of the reference: the clip's own sliding), ``target_jitter`` (the second difference of
the PD targets the policy returned, rad/frame^2). Differences run over consecutive scored frames of one episode only
(the start state before the first step is not one), so they follow MPJPE's rule: under the full horizon a failed
episode's frames count; a blown-up character, scored frozen, moves no more and its targets are held at the last ones
before the blow-up. Velocity, acceleration and jitter average their differences like the other per-frame figures; the
foot sliding averages over the (foot, step) pairs in contact, and over the clips with any.

**Terrain.** A clip with a terrain is played and judged on it, with no setting to change: its characters are
simulated on it (:mod:`common.sim.terrain`), the failure rules compare heights above the ground under the point
measured (:func:`common.sim.rewards.termination`), a foot touches the ground while its clearance above the terrain
under it is below 2 cm (:class:`_MotionTrace`), and a push is the same impulse (its velocity change depends on the
pose alone, :mod:`common.sim.pushes`). Clips without a terrain get the flat judge's numbers to the bit.

A policy is any callable from the gym's :class:`~common.sim.gym.StepResult` to PD targets (N, nu); learners pass their
deterministic (mean, no noise) policy.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from common.character.humanoid import BodyGeometry, Humanoid
from common.character.state import CharacterState
from common.evaluation import metrics as M
from common.motion.library import MotionLibrary
from common.sim.gym import GymConfig, StepResult, TrackingGym
from common.sim.pushes import PushConfig, push_schedule
from common.sim.rewards import TerminationConfig
from common.sim.terrain import ClipTerrains, ground_clearance

Policy = Callable[[StepResult], np.ndarray]
FRAME_METRICS = ("mpjpe_g", "mpjpe_l", "root_pos_err", "root_rot_err", "body_rot_err", "joint_vel_err",
                 "root_vel_err", "root_ang_vel_err")  # fmt: skip
DIFF_METRICS = {"vel_err": 1, "accel_err": 2, "target_jitter": 2}  # key: order of the finite difference
SLIDE_METRICS = ("foot_slide", "foot_slide_ref")
CLIPS_WITH_ANY = ("mpjpe_g_succ", "mpjpe_l_succ", *SLIDE_METRICS)  # overall: mean over the clips that have a value


@dataclass(frozen=True)
class EvalConfig:
    """The evaluation protocol (the same for every method compared).

    Attributes:
        starts_per_clip: Episodes per clip, starting at evenly spaced frames (the first at t = 0).
        max_frames: Steps per episode (SuperTrack's 512); one-shot clips end earlier at their last frame.
        seed: Seed of the evaluation gym.
        threads: MuJoCo rollout threads.
        termination: The rule that marks an episode failed.
        full_horizon: Score every episode over its whole horizon, failed or not (see the module docstring); False
            ends an episode at its first failure and scores only the frames before it.
        pushes: The robustness protocol's impulses on the pelvis (:mod:`common.sim.pushes`); None: no pushes.
        rsi_lift: Start a character whose reference pose pushes a body into the ground lifted clear of it
            (:class:`common.sim.gym.GymConfig`); the learners' gyms must use the same setting.
    """

    starts_per_clip: int = 4
    max_frames: int = 512
    seed: int = 0
    threads: int = 2
    termination: TerminationConfig = field(
        default_factory=lambda: TerminationConfig(max_episode_frames=None, grace_frames=48, head_height_error=0.25)
    )
    full_horizon: bool = True
    pushes: PushConfig | None = None
    rsi_lift: bool = False

    def __post_init__(self) -> None:
        if self.starts_per_clip < 1 or self.max_frames < 1:
            raise ValueError("starts_per_clip and max_frames must be >= 1")


@dataclass
class EvalResult:
    """Per-clip table and overall means.

    Attributes:
        clips: Clip names, in library order.
        per_clip: {metric: (C,)} for every metric in :data:`common.evaluation.metrics.METRIC_NAMES`.
        overall: {metric: mean over clips}.
        episode_length: Steps played per episode before its first failure. Shape: (C, starts_per_clip).
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
    clips, times, episode_max = episode_starts(library, config)
    gym = TrackingGym(
        GymConfig(num_envs=len(clips), threads=config.threads, seed=config.seed, physics=humanoid.physics,
                  termination=config.termination, rsi_lift=config.rsi_lift),
        library, humanoid,
    )  # fmt: skip
    try:
        result = gym.reset(clips=clips, times=times)
        n, horizon = len(clips), int(episode_max.max())
        per_frame = {key: np.zeros((horizon, n)) for key in FRAME_METRICS}
        motion = _MotionTrace(humanoid, horizon, n, ClipTerrains.of(library), clips)
        body_err = np.zeros((horizon, n))
        valid = np.zeros((horizon, n), dtype=bool)
        alive = np.ones(n, dtype=bool)  # no failure yet
        frozen = np.zeros(n, dtype=bool)  # blew up: scored in its last state before that from then on
        held = result.sim
        length = np.zeros(n, dtype=np.int64)
        push_frames, impulses = push_schedule(config.pushes, n, horizon) if config.pushes else (np.zeros(0), None)
        for t in range(horizon):
            if t in push_frames:  # between steps, so the policy sees the push; frozen characters are left alone
                hit = np.flatnonzero((t < episode_max) & ~frozen)
                gym.push(hit, impulses[int(np.searchsorted(push_frames, t)), hit])
            before = result.sim
            targets = policy(result)
            result = gym.step(targets, autoreset=False)
            newly = result.diverged & ~frozen
            held = _with_rows(held, newly, before)
            frozen |= newly
            sim, ref = _with_rows(result.final_sim, frozen, held), result.final_ref
            motion.add(t, sim, ref, targets, frozen)
            in_horizon = t < episode_max
            valid[t] = in_horizon & (alive | config.full_horizon)
            length += alive & in_horizon
            _score(per_frame, body_err, t, sim, ref, humanoid)
            alive &= ~(result.terminated & in_horizon)
            if not config.full_horizon and not (alive & (t + 1 < episode_max)).any():
                break
        played = int(t + 1)
    finally:
        gym.close()
    valid, body_err = valid[:played], body_err[:played]
    terminated = ~alive
    succeeded = M.success(body_err.T, valid=valid.T, terminated=terminated)
    per_clip: dict[str, np.ndarray] = {key: np.zeros(nclip) for key in M.METRIC_NAMES}
    diff_valid = motion.diff_valid(valid)
    for c in range(nclip):
        eps = clips == c
        means = M.summarise({key: v[:played, eps] for key, v in per_frame.items()}, valid[:, eps])
        for key, value in means.items():
            per_clip[key][c] = value
        for key, order in DIFF_METRICS.items():
            per_clip[key][c] = M.summarise({key: motion.per_frame[key][:played, eps]}, diff_valid[order][:, eps])[key]
        for key in SLIDE_METRICS:
            per_clip[key][c] = M.contact_mean(motion.slide[key][:played, eps], motion.contacts[key][:played, eps],
                                              diff_valid[1][:, eps])  # fmt: skip
        ok = eps & succeeded
        only = M.summarise({key: per_frame[key][:played, ok] for key in ("mpjpe_g", "mpjpe_l")}, valid[:, ok])
        per_clip["mpjpe_g_succ"][c], per_clip["mpjpe_l_succ"][c] = only["mpjpe_g"], only["mpjpe_l"]
        per_clip["success"][c] = succeeded[eps].mean()
        per_clip["survival"][c] = (~terminated[eps]).mean()
        per_clip["episode_len_ratio"][c] = np.mean(length[eps] / episode_max[eps])
    overall = {key: _mean_over_clips(v) if key in CLIPS_WITH_ANY else float(np.mean(v)) for key, v in per_clip.items()}
    return EvalResult(
        clips=list(library.names), per_clip=per_clip, overall=overall,
        episode_length=length.reshape(nclip, k), episode_max=episode_max.reshape(nclip, k), frames=played,
    )  # fmt: skip


def episode_starts(library: MotionLibrary, config: EvalConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The protocol's episodes: ``starts_per_clip`` per clip, clip-major, at evenly spaced frames (the first at t = 0)
    over the frames that leave at least one step to play.

    Returns:
        (clip, start time in s, steps the episode may play), each of shape (num_clips * starts_per_clip,).
    """
    nclip, k = library.num_clips, config.starts_per_clip
    clips = np.repeat(np.arange(nclip), k)
    playable = np.where(library.loop, np.ceil(library.duration / library.dt - 1e-9), library.num_frames - 1)
    start_frame = np.floor(np.tile(np.arange(k) / k, nclip) * playable[clips]).astype(np.int64)
    remaining = np.where(library.loop[clips], config.max_frames, library.num_frames[clips] - 1 - start_frame)
    return clips, start_frame * library.dt, np.minimum(config.max_frames, remaining)


def _with_rows(state: CharacterState, rows: np.ndarray, source: CharacterState) -> CharacterState:
    """``state`` with the characters where ``rows`` is True taken from ``source`` (a copy when any is)."""
    if not rows.any():
        return state
    out = CharacterState(**{k: v.copy() for k, v in vars(state).items()})
    for k, v in vars(source).items():
        getattr(out, k)[rows] = v[rows]
    return out


def _score(per_frame: dict[str, np.ndarray], body_err: np.ndarray, t: int, sim: CharacterState,
           ref: CharacterState, humanoid: Humanoid) -> None:  # fmt: skip
    """Writes frame ``t``'s metrics of every character into ``per_frame[key][t]`` and ``body_err[t]``."""
    root, hinge_dof = humanoid.root_index, humanoid.hinge_dof
    per_frame["mpjpe_g"][t] = M.mpjpe_global_mm(sim.body_pos, ref.body_pos)
    per_frame["mpjpe_l"][t] = M.mpjpe_local_mm(sim.body_pos, ref.body_pos, root_index=root)
    per_frame["root_pos_err"][t] = M.root_pos_error_m(sim.body_pos[:, root], ref.body_pos[:, root])
    per_frame["root_rot_err"][t] = M.root_rot_error_rad(sim.body_rot[:, root], ref.body_rot[:, root])
    per_frame["body_rot_err"][t] = M.body_rot_error_rad(sim.body_rot, ref.body_rot)
    per_frame["joint_vel_err"][t] = M.joint_vel_error(sim.qvel[:, hinge_dof], ref.qvel[:, hinge_dof])
    per_frame["root_vel_err"][t] = M.root_lin_vel_error(sim.body_linvel[:, root], ref.body_linvel[:, root])
    per_frame["root_ang_vel_err"][t] = M.root_ang_vel_error(sim.body_angvel[:, root], ref.body_angvel[:, root])
    body_err[t] = M.mean_body_pos_error_m(sim.body_pos, ref.body_pos)


class _MotionTrace:
    """The finite-difference measures of motion quality, fed one scored frame at a time.

    Keeps the last three scored frames of every episode (each character plays one episode: the evaluator never resets)
    and writes the difference ending at frame t into row t; :meth:`diff_valid` says which rows are real differences.

    A foot's height is its clearance above its clip's ground (:func:`common.sim.terrain.ground_clearance`: on a
    terrain the least gap over its collision geom's points to the ground under each; on the flat floor the height of
    its lowest point, as before terrains existed), for the simulated character and the reference alike (both on the
    clip's terrain). The slide itself stays horizontal (x, y): along a 12 deg slope a foot's slide reads 2 % short.

    Args:
        humanoid: The model (feet and their collision geoms).
        horizon: Frames per episode at most.
        n: Episodes.
        terrains: The clips' terrains.
        clips: Clip of every episode (the evaluator never resets, so it stays). Shape: (n,).
    """

    def __init__(self, humanoid: Humanoid, horizon: int, n: int, terrains: ClipTerrains, clips: np.ndarray) -> None:
        self.geometry, self.feet = BodyGeometry(humanoid), humanoid.foot_indices
        self.terrains, self.clips = terrains, np.asarray(clips, dtype=np.int64)
        self.per_frame = {key: np.zeros((horizon, n)) for key in DIFF_METRICS}
        self.slide = {key: np.zeros((horizon, n)) for key in SLIDE_METRICS}  # summed over the feet in contact
        self.contacts = {key: np.zeros((horizon, n)) for key in SLIDE_METRICS}  # feet in contact
        self.window: list[tuple[np.ndarray, ...]] = []
        self.held_targets = np.zeros(0)

    def add(self, t: int, sim: CharacterState, ref: CharacterState, targets: np.ndarray, frozen: np.ndarray) -> None:
        """Frame ``t``'s scored states and the targets that led to it (held where ``frozen``). Shapes: (N, ...)."""
        targets = np.array(targets, dtype=np.float64)
        if t == 0:
            self.held_targets = targets.copy()
        targets = np.where(frozen[:, None], self.held_targets, targets)
        self.held_targets = targets
        sim_h = ground_clearance(self.terrains, self.clips, self.geometry, sim.body_pos, sim.body_rot)[:, self.feet]
        ref_h = ground_clearance(self.terrains, self.clips, self.geometry, ref.body_pos, ref.body_rot)[:, self.feet]
        self.window = [*self.window[-2:], (sim.body_pos.copy(), ref.body_pos.copy(), targets, sim_h, ref_h)]
        if len(self.window) < 2:
            return
        sim_pos, ref_pos, target, sim_height, ref_height = (np.stack(x, axis=1) for x in zip(*self.window, strict=True))
        self.per_frame["vel_err"][t] = M.velocity_error_mm(sim_pos[:, -2:], ref_pos[:, -2:])[:, -1]
        for key, pos, height in (("foot_slide", sim_pos, sim_height), ("foot_slide_ref", ref_pos, ref_height)):
            slide, contact = M.foot_slide_mm(pos[:, -2:, self.feet], height[:, -2:])
            self.slide[key][t] = np.sum(slide[:, -1], axis=-1, where=contact[:, -1])
            self.contacts[key][t] = contact[:, -1].sum(axis=-1)
        if len(self.window) == 3:
            self.per_frame["accel_err"][t] = M.acceleration_error_mm(sim_pos, ref_pos)[:, -1]
            self.per_frame["target_jitter"][t] = M.target_jitter(target)[:, -1]

    @staticmethod
    def diff_valid(valid: np.ndarray) -> dict[int, np.ndarray]:
        """{order: rows whose difference of that order spans only valid frames}. Shapes: (T, N)."""
        first, second = np.zeros_like(valid), np.zeros_like(valid)
        first[1:] = valid[1:] & valid[:-1]
        second[2:] = first[2:] & valid[:-2]
        return {1: first, 2: second}


def _mean_over_clips(values: np.ndarray) -> float:
    """Mean of a figure over the clips that have one (success-only, foot sliding; NaN if none has)."""
    finite = values[~np.isnan(values)]
    return float(finite.mean()) if len(finite) else float("nan")


def reference_policy(result: StepResult, humanoid: Humanoid) -> np.ndarray:
    """Open-loop playback: PD targets = the reference's hinge angles at the next frame (the baseline to beat)."""
    return result.ref_next.qpos[:, humanoid.hinge_qpos]
