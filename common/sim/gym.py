"""The DeepMimic-style tracking gym: N simulated humanoids under PD control, each following a reference clip.

One control step (``step``): PD targets for every hinge -> ``substeps`` physics steps (MuJoCo, threads) -> body
states -> the reference at the new time -> rewards and termination -> characters whose episode ended are reset
with reference state initialisation (RSI). Time is kept per character as (clip, start time, frames since reset).
The physics runs on a worker thread (``mujoco.rollout`` releases the GIL) while the calling thread prepares what the
step needs of the reference, which does not depend on the physics; the numbers are those of doing it in order.

Frame alignment: ``StepResult.sim`` and ``StepResult.ref`` are the simulated and reference states at the same
time t; ``ref_next`` is the reference at t + dt, the pose the next PD targets should reach.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial

import mujoco
import numpy as np

from common.character.humanoid import BodyGeometry, Humanoid, PhysicsConfig
from common.character.kinematics import ForwardKinematics
from common.character.state import CharacterState
from common.motion.library import MotionLibrary
from common.sim.physics import BatchedSim
from common.sim.pushes import impulse_velocity_change
from common.sim.rewards import RewardConfig, TerminationConfig, TrackingReward, termination
from common.sim.terrain import ClipTerrains, ground_clearance


@dataclass(frozen=True)
class GymConfig:
    """The gym.

    Attributes:
        num_envs: Characters simulated in parallel.
        threads: MuJoCo rollout threads (use the machine's cores).
        seed: Seed of the gym's random generator (RSI draws).
        rsi_lift: At RSI, raise a character whose reference pose pushes a body into the ground until its lowest
            point is at ground level (some clips have the feet 3-13 cm below it; starting inside the ground
            launches the character).
        max_speed: A generalised velocity above this (m/s, rad/s) counts as a blown-up simulation.
        physics: Rates and solver settings.
        termination: Episode end rules.
        reward: Reward terms.
    """

    num_envs: int = 64
    threads: int = 2
    seed: int = 0
    rsi_lift: bool = False
    max_speed: float = 1000.0
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    termination: TerminationConfig = field(default_factory=TerminationConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)

    def __post_init__(self) -> None:
        if self.num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {self.num_envs}")


@dataclass
class StepResult:
    """What the gym reports after a reset or a step. Leading shape (N,) everywhere.

    Attributes:
        sim: Simulated state at time t (after a reset for characters whose episode just ended).
        ref: Reference state at time t.
        ref_next: Reference state at t + dt.
        reward: Reward of the step. Shape: (N,).
        reward_terms: Unweighted exp(-k e) per term, {name: (N,)}.
        terminated: The episode failed at this step. Shape: (N,).
        truncated: The episode hit a time limit or the clip's end at this step. Shape: (N,).
        final_sim: The state the step reached, before any reset (equals ``sim`` where not done).
        final_ref: Reference at the time of ``final_sim``.
        final_ref_next: Reference one step after ``final_ref`` (to build the observation of ``final_sim``, e.g. for
            bootstrapping the value of a truncated episode).
        final_phase: Clip phase of ``final_sim``. Shape: (N,).
        final_clip: Clip of ``final_sim`` (before any reset). Shape: (N,).
        final_time: Clip time of ``final_sim`` in seconds. Shape: (N,).
        phase: Clip phase of ``sim`` in [0, 1). Shape: (N,).
        clip: Clip index of the current episode. Shape: (N,).
        time: Clip time of ``sim`` in seconds. Shape: (N,).
        episode_id: Unique id of the current episode. Shape: (N,).
        episode_frame: Steps since the current episode's reset. Shape: (N,).
        info: Counts: ``diverged`` (blown-up simulations reset), ``term/<rule>``.
        diverged: The simulation blew up at this step; ``final_sim`` is then the reference pose it was put back on,
            not a state the character reached (it also counts as terminated). Shape: (N,).
    """

    sim: CharacterState
    ref: CharacterState
    ref_next: CharacterState
    reward: np.ndarray
    reward_terms: dict[str, np.ndarray]
    terminated: np.ndarray
    truncated: np.ndarray
    final_sim: CharacterState
    final_ref: CharacterState
    final_ref_next: CharacterState
    final_phase: np.ndarray
    final_clip: np.ndarray
    final_time: np.ndarray
    phase: np.ndarray
    clip: np.ndarray
    time: np.ndarray
    episode_id: np.ndarray
    episode_frame: np.ndarray
    info: dict[str, float]
    diverged: np.ndarray

    @property
    def done(self) -> np.ndarray:
        return self.terminated | self.truncated


def _copy(state: CharacterState) -> CharacterState:
    return CharacterState(**{k: v.copy() for k, v in vars(state).items()})


def _assign(dst: CharacterState, ids: np.ndarray, src: CharacterState) -> None:
    for name in ("qpos", "qvel", "body_pos", "body_rot", "body_linvel", "body_angvel"):
        getattr(dst, name)[ids] = getattr(src, name)


class TrackingGym:
    """N characters tracking clips of a motion library.

    Args:
        config: Gym settings.
        library: The reference clips (built for the same control rate).
        humanoid: The model; built from ``config.physics`` when not given.
        clip_weights: Sampling weight per clip for RSI (uniform when None); can be changed with
            :meth:`set_clip_weights`.
    """

    def __init__(self, config: GymConfig, library: MotionLibrary, humanoid: Humanoid | None = None,
                 clip_weights: np.ndarray | None = None) -> None:  # fmt: skip
        self.config = config
        self.humanoid = humanoid or Humanoid(config.physics)
        if abs(library.dt - self.humanoid.physics.control_dt) > 1e-12:
            raise ValueError(
                f"motion library sampled at {1 / library.dt:g} Hz but the gym controls at"
                f" {self.humanoid.physics.control_hz:g} Hz"
            )
        self.library = library
        self.num_envs = config.num_envs
        self.dt = self.humanoid.physics.control_dt
        self.rng = np.random.default_rng(config.seed)
        # Clips on terrain: each character is stepped in its clip's terrain model (common/sim/terrain.py).
        self.terrains = ClipTerrains.of(library)
        flat, self._clip_models = self.terrains.models(self.humanoid) if self.terrains.any else (None, None)
        self.sim = BatchedSim(self.humanoid, config.num_envs, config.threads, config.max_speed, model=flat)
        self.fk = ForwardKinematics(self.humanoid, config.threads)
        self.geometry = BodyGeometry(self.humanoid)
        self.reward_fn = TrackingReward(self.humanoid, config.reward)
        self.hinge_qpos = self.humanoid.hinge_qpos
        self.clip_weights = None if clip_weights is None else np.asarray(clip_weights, dtype=np.float64)
        n = config.num_envs
        self.clip = np.zeros(n, dtype=np.int64)
        self.start_time = np.zeros(n)
        self.frame = np.zeros(n, dtype=np.int64)
        self.episode_id = np.full(n, -1, dtype=np.int64)
        self._next_episode = 0
        self._state: CharacterState | None = None
        self._ref: CharacterState | None = None
        self._ref_next: CharacterState | None = None
        self._scratch: mujoco.MjData | None = None  # for pushes
        self._physics: ThreadPoolExecutor | None = None  # runs the physics while step() prepares the reference

    def close(self) -> None:
        if self._physics is not None:
            self._physics.shutdown()
            self._physics = None
        self.sim.close()
        self.fk.close()

    @property
    def nu(self) -> int:
        return self.humanoid.nu

    @property
    def time(self) -> np.ndarray:
        return self.start_time + self.frame * self.dt

    def set_clip_weights(self, weights: np.ndarray | None) -> None:
        self.clip_weights = None if weights is None else np.asarray(weights, dtype=np.float64)

    def phase(self) -> np.ndarray:
        """Clip phase in [0, 1) of every character: position in the loop (wrap) or in the clip (one-shot)."""
        dur = self.library.duration[self.clip]
        t = self.time
        return np.where(self.library.loop[self.clip], np.mod(t, dur) / dur, np.clip(t / dur, 0.0, 1.0))

    def reference_targets(self) -> np.ndarray:
        """PD targets that follow the reference: the hinge angles of ``ref_next``. Shape: (N, nu)."""
        self._require_reset()
        return self._ref_next.qpos[:, self.hinge_qpos].copy()

    def reset(self, ids: np.ndarray | None = None, clips: np.ndarray | None = None,
              times: np.ndarray | None = None) -> StepResult:  # fmt: skip
        """Reference state initialisation of characters ``ids`` (all by default).

        Args:
            ids: Characters to reset. Shape: (M,).
            clips: Clip per character (drawn with the clip weights when None). Shape: (M,).
            times: Start time per character in seconds (a random grid frame when None). Shape: (M,).

        Returns:
            The current state of all N characters (not a step: reward 0, no done flags).
        """
        ids = np.arange(self.num_envs) if ids is None else np.asarray(ids, dtype=np.int64)
        if self._state is None and len(ids) != self.num_envs:
            raise RuntimeError("the first reset must reset every character")
        self._reset_ids(ids, clips, times)
        n = self.num_envs
        zeros = np.zeros(n, dtype=bool)
        return self._result(np.zeros(n), {}, zeros, zeros.copy(), self._state, self._ref, self._ref_next,
                            self.phase(), {})  # fmt: skip

    def _reset_ids(self, ids: np.ndarray, clips: np.ndarray | None, times: np.ndarray | None) -> None:
        if len(ids) == 0:
            return
        if clips is None or times is None:
            drawn_clips, drawn_times = self.library.sample_starts(len(ids), self.rng, self.clip_weights)
            clips = drawn_clips if clips is None else np.asarray(clips, dtype=np.int64)
            times = drawn_times if times is None else np.asarray(times, dtype=np.float64)
        self.clip[ids] = clips
        self.start_time[ids] = times
        self.frame[ids] = 0
        self.episode_id[ids] = self._next_episode + np.arange(len(ids))
        self._next_episode += len(ids)
        ref = self.library.query(clips, times)
        qpos = ref.qpos.copy()
        if self.config.rsi_lift:
            clearance = self.geometry.lowest_points(ref.body_pos, ref.body_rot)
            if self.terrains.any:  # the ground under each body's origin
                clearance = clearance - self.terrains.height(clips, ref.body_pos[..., 0], ref.body_pos[..., 1])
            qpos[:, 2] += np.maximum(0.0, -clearance.min(axis=-1))
        self.sim.set_state(ids, qpos, ref.qvel)
        if self._clip_models is not None:
            self.sim.set_models(ids, [self._clip_models[c] for c in clips])
        state = self.fk(self.sim.qpos[ids].copy(), self.sim.qvel[ids].copy())
        ref_next = self.library.query(clips, times + self.dt)
        if self._state is None:
            self._state, self._ref, self._ref_next = state, ref, ref_next
        else:
            _assign(self._state, ids, state)
            _assign(self._ref, ids, ref)
            _assign(self._ref_next, ids, ref_next)

    def step(self, pd_targets: np.ndarray, autoreset: bool = True) -> StepResult:
        """One control step of every character.

        Args:
            pd_targets: Target angle of every actuated hinge, in actuator order. Shape: (N, nu).
            autoreset: Reset characters whose episode ended (RSI). The evaluator passes False and ignores them.

        Raises:
            ValueError: on a wrong shape or non-finite targets.
        """
        self._require_reset()
        pd_targets = np.asarray(pd_targets, dtype=np.float64)
        if pd_targets.shape != (self.num_envs, self.nu):
            raise ValueError(f"pd_targets: expected shape ({self.num_envs}, {self.nu}), got {pd_targets.shape}")
        if not np.isfinite(pd_targets).all():
            bad = np.argwhere(~np.isfinite(pd_targets))[0]
            raise ValueError(f"pd_targets: non-finite value at character {bad[0]}, actuator {bad[1]}")
        # What the step needs of the reference is known before the physics runs: the reference at t (``ref_next``
        # of the last step), what the reward derives from it, and the reference at t + dt. Prepared on this thread
        # while the physics runs on the worker, it costs about half of its 1-2 ms at N = 256 on 2 cores (the two
        # physics threads are slowed by what it takes from them) instead of all of it after the physics.
        ref = self._ref_next
        frame = self.frame + 1
        next_time = self.start_time + frame * self.dt + self.dt  # the same arithmetic as self.time + self.dt after
        if self._physics is None:
            self._physics = ThreadPoolExecutor(max_workers=1, thread_name_prefix="gym-physics")
        pending = self._physics.submit(self.sim.step, pd_targets)
        try:
            ref_prepared = self.reward_fn.prepare(ref)
            ref_next = self.library.query(self.clip, next_time)
            # Resets overwrite rows of the current reference states in place; the final_* fields keep these copies.
            ref_copy, ref_next_copy = _copy(ref), _copy(ref_next)
            cfg = self.config.termination
            ref_lowest = None
            if cfg.contact_clearance is not None and cfg.fall_contact != "off":
                ref_lowest = ground_clearance(self.terrains, self.clip, self.geometry, ref.body_pos, ref.body_rot)
        finally:
            diverged = pending.result()
        if diverged.any():
            # Keep blown-up numbers out of every array: such a character is put on its reference pose (a clean state,
            # unlike its last one, from which it would blow up again), reported as terminated with reward 0.
            bad = np.flatnonzero(diverged)
            self.sim.set_state(bad, ref.qpos[bad], ref.qvel[bad])
        self.frame += 1  # in place, as before: equal to frame
        state = self.fk(self.sim.qpos.copy(), self.sim.qvel.copy())
        reward, terms = self.reward_fn(state, ref_prepared)
        # Only the fall-contact rule looks at the lowest points (0.6 ms at N = 256): computed when it is on. On
        # terrain every height the rules compare is above the ground of the character's clip (common/sim/rewards.py).
        lowest = None
        if cfg.fall_contact != "off":
            lowest = ground_clearance(self.terrains, self.clip, self.geometry, state.body_pos, state.body_rot)
        terminated, rules = termination(cfg, self.humanoid, state, ref, self.frame, lowest, ref_lowest, self._ground())
        terminated |= diverged
        reward[diverged] = 0.0
        truncated = np.zeros(self.num_envs, dtype=bool)
        if cfg.max_episode_frames is not None:
            truncated |= self.frame >= cfg.max_episode_frames
        if cfg.clip_end:
            truncated |= self.time + self.dt > self.library.end_time[self.clip] + 1e-9
        truncated &= ~terminated
        info = {"diverged": float(diverged.sum()), **{f"term/{k}": float(v.sum()) for k, v in rules.items()}}
        final_sim, final_ref, final_ref_next = state, ref, ref_next_copy
        self._state, self._ref, self._ref_next = _copy(state), ref_copy, ref_next
        final_phase, final_clip, final_time = self.phase(), self.clip.copy(), self.time
        done = np.flatnonzero(terminated | truncated)
        if autoreset and len(done):
            self._reset_ids(done, None, None)
        return self._result(reward, terms, terminated, truncated, final_sim, final_ref, final_ref_next, final_phase,
                            info, final_clip, final_time, diverged)  # fmt: skip

    def _result(
        self,
        reward: np.ndarray,
        terms: dict[str, np.ndarray],
        terminated: np.ndarray,
        truncated: np.ndarray,
        final_sim: CharacterState,
        final_ref: CharacterState,
        final_ref_next: CharacterState,
        final_phase: np.ndarray,
        info: dict[str, float],
        final_clip: np.ndarray | None = None,
        final_time: np.ndarray | None = None,
        diverged: np.ndarray | None = None,
    ) -> StepResult:
        clip, time = self.clip.copy(), self.time
        final_clip = clip if final_clip is None else final_clip
        final_time = time if final_time is None else final_time
        return StepResult(
            sim=self._state, ref=self._ref, ref_next=self._ref_next, reward=reward, reward_terms=terms,
            terminated=terminated, truncated=truncated, final_sim=final_sim, final_ref=final_ref,
            final_ref_next=final_ref_next, final_phase=final_phase, phase=self.phase(), clip=clip, time=time,
            final_clip=final_clip, final_time=final_time,
            episode_id=self.episode_id.copy(),
            episode_frame=self.frame.copy(), info=info,
            diverged=np.zeros(self.num_envs, dtype=bool) if diverged is None else diverged,
        )  # fmt: skip

    def state_dict(self) -> dict:
        """Everything needed to continue exactly: physics states, episode bookkeeping, RNG, clip weights."""
        self._require_reset()
        return {
            "sim_state": self.sim.state.copy(), "clip": self.clip.copy(), "start_time": self.start_time.copy(),
            "frame": self.frame.copy(), "episode_id": self.episode_id.copy(), "next_episode": self._next_episode,
            "rng": self.rng.bit_generator.state, "clip_weights": self.clip_weights,
        }  # fmt: skip

    def load_state_dict(self, state: dict) -> StepResult:
        """Restores :meth:`state_dict` and returns the current state of all characters."""
        if state["sim_state"].shape != self.sim.state.shape:
            raise ValueError(f"gym state for {state['sim_state'].shape[0]} characters, this gym has {self.num_envs}")
        self.sim.state[:] = state["sim_state"]
        self.clip[:], self.start_time[:] = state["clip"], state["start_time"]
        if self._clip_models is not None:
            self.sim.set_models(np.arange(self.num_envs), [self._clip_models[c] for c in self.clip])
        self.frame[:], self.episode_id[:] = state["frame"], state["episode_id"]
        self._next_episode = int(state["next_episode"])
        self.rng.bit_generator.state = state["rng"]
        self.set_clip_weights(state["clip_weights"])
        self._state = self.fk(self.sim.qpos.copy(), self.sim.qvel.copy())
        # The same floating-point expression as in step() (previous time + dt), so that a resumed run is bit-exact.
        prev = self.start_time + (self.frame - 1) * self.dt
        self._ref = self.library.query(self.clip, np.where(self.frame > 0, prev + self.dt, self.start_time))
        self._ref_next = self.library.query(self.clip, self.time + self.dt)
        zeros = np.zeros(self.num_envs, dtype=bool)
        return self._result(np.zeros(self.num_envs), {}, zeros, zeros.copy(), self._state, self._ref, self._ref_next,
                            self.phase(), {})  # fmt: skip

    def _ground(self) -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
        """The ground's height under world points (x, y) of shape (N, K) of every character, on its clip's terrain
        (for the termination rules); None for a library without terrain: the flat floor, the rules' flat arithmetic."""
        return partial(self.terrains.height, self.clip.copy()) if self.terrains.any else None

    def push(self, ids: np.ndarray, impulses: np.ndarray) -> None:
        """Applies an impulse at the pelvis of characters ``ids`` (robustness tests), between two control steps.

        Their velocities jump by :func:`common.sim.pushes.impulse_velocity_change`; the current state (``sim`` of the
        last :class:`StepResult`) is updated in place, so the policy sees the push before its next action.

        Args:
            ids: Characters to push. Shape: (K,).
            impulses: World-frame impulses (N s). Shape: (K, 3).
        """
        self._require_reset()
        ids = np.asarray(ids, dtype=np.int64)
        if len(ids) == 0:
            return
        if self._scratch is None:
            self._scratch = mujoco.MjData(self.humanoid.model)
        body = self.humanoid.root_index + 1  # MuJoCo's body 0 is the world
        for i, p in zip(ids, np.asarray(impulses, dtype=np.float64), strict=True):
            self.sim.qvel[i] += impulse_velocity_change(self.humanoid.model, self._scratch, self.sim.qpos[i],
                                                        self.sim.qvel[i], body, p)  # fmt: skip
        _assign(self._state, ids, self.fk(self.sim.qpos[ids].copy(), self.sim.qvel[ids].copy()))

    def _require_reset(self) -> None:
        if self._state is None:
            raise RuntimeError("call reset() before step()")
