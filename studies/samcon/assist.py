"""Tracking with a root force: how far a clip is out of reach *because* it needs force no floor contact can give.

:mod:`studies.samcon.feasibility` measures, from the reference alone, the part of the net external force
m (a_com - g) that no floor contact can supply (its *residual*: all of it in flight, the part outside the friction
cone in contact). A clip with a residual cannot be tracked exactly by any controller of this character, but that
alone does not say how close one can get, nor whether the force is what stops the tracker. This module answers it by
experiment: the same search and polish as ``track-samcon``, with a **root force** (the residual force control of
Yuan & Kitani 2020, here a fixed law, not learned) on the root body's origin, world frame, at the free joint's
translation dofs (MuJoCo's ``qfrc_applied``), held over each control step f -> f + 1 like the PD targets
(:class:`AssistConfig`): ``F = clip(scale F_res(f) + m (kp (p* - p) + kd (v* - v)), cap m |g|)``, p and v the root's
position and velocity at frame f, p* and v* the reference's, F_res the reference's residual. ``cap`` is the budget:
a clip that tracks within the target with a small cap and not without one needs root forces, measured; one that
misses with a generous cap too misses for another reason (a torque limit, a joint range, the search).

A **root torque** may join it (``torque_cap`` > 0, session 23; off by default): a couple on the root body from a PD
on the root's orientation (:class:`AssistConfig`). A force at the root's origin, near the centre of mass, mostly
moves the centre of mass; a couple turns the body without moving it, which is what the floor must do when a clip
turns or tips the body about its centre of mass (spins, a centre of pressure the feet cannot reach). With both, a clip
that still misses is limited by its limbs, not by what the floor gives the whole body.

Taking the help away again (session 24): ``--then-search`` searches anew around the assisted path (its targets the
candidates' centre, many states kept per segment) with a smaller cap, down to none, each stage polished. Polishing
the assisted path alone at a smaller cap (``--then-caps``) fell on run and dance_a (session 20): one path, played from
where the lost help first lets it drift, has nothing to correct the drift with.

``--then-couple W1 W2 ...`` (session 25) takes a couple away inside the polish instead: the last path's couple (as
its law gave it) becomes three more controls of the iLQR (:mod:`studies.samcon.couple`), each frame's costing W x
its squared norm, polished with each weight in turn (rising), and then the path is polished once more without it,
an unassisted open-loop path. The optimiser moves the work from the couple to the targets while it keeps the path.

The force is a function of the clip frame and the state, so an assisted path is still open loop and replays
bit-exactly with the law (:func:`studies.samcon.forces.assisted_replay`); the polish rolls out with the law and its
linearisation counts the law's dependence on the state. The residual fed forward alone (``scale`` 1, no feedback)
made the search worse on run and jog (docs/samcon.md): the reference's centre of mass falls faster than g at the
top of run's flights, and pushing the character down there did not make up for the push-off it could not give.

The residual at frame k is measure 1's h-step difference (the mean acceleration under a triangle of half-width h
steps, see :mod:`studies.samcon.feasibility`), on the reference frames the search plays
(``search.reference_frames``), with the first and last h frames taking their nearest measured neighbour's. The
assisted paths are judged here, by the shared metrics and failure rule on the replayed states (:func:`judge`, the
evaluator's full-horizon figures); they never enter a run directory: the shared evaluator applies no root force, and
an assisted path is not a tracker's result.

Command::

    python -m studies.samcon.assist --config configs/samcon/polish.yaml --motions run jog --cap 0.5 \
        --out runs/assist.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import mujoco
import numpy as np

from common.character.humanoid import BodyGeometry, Humanoid
from common.character.kinematics import ForwardKinematics
from common.character.state import CharacterState
from common.config import ConfigError, atomic_output, load_config
from common.evaluation import metrics as M
from common.evaluation.evaluate import EvalConfig
from common.maths.rotations import quat_conj, quat_mul, quat_rotate, quat_rotate_inv, quat_to_rotvec
from common.motion.dataset import resolve_clips
from common.motion.library import MotionLibrary
from common.motion.motion import MotionFormatError
from common.sim.rewards import termination
from samcon.config import SamconConfig, SearchConfig
from samcon.polish import polish
from samcon.search import Trajectory, horizon, reference_frames, replay, samcon, searched_frames, start_state
from samcon.track import cli_overrides, clip_generator, polished, segment_progress
from studies.samcon.couple import ROOT_TURN, Couple, polish_couple
from studies.samcon.feasibility import (
    CONTACT_TOLERANCE,
    accel_step,
    body_weight,
    com_and_clearance,
    external_force,
    model_friction,
    residual_vector,
    total_mass,
)
from studies.samcon.forces import assisted_replay


@dataclass(frozen=True)
class AssistConfig:
    """The root force: a world-frame force on the root body's origin (the free joint's translation dofs),
    ``F = clip(scale F_res(f) + m (kp (p* - p) + kd (v* - v)), cap m |g|)`` over step f -> f + 1, p and v the
    root's position and velocity at frame f, p* and v* the reference's, F_res the reference's residual (the mean of
    frames f's and f + 1's, :func:`residual_per_frame`).

    Attributes:
        scale: Times the reference's residual force (1: all of it; 0: none).
        kp: 1/s^2, the feedback on the root's position error (m kp: N per m).
        kd: 1/s, the feedback on its velocity error.
        cap: Largest force in body weights m |g| (0: no force at all, the same code path).
        step: h, the residual's differencing step in control steps (None: the clip's source keyframe spacing rounded
            up, at least 2, as :mod:`studies.samcon.feasibility` measures it; see
            :func:`studies.samcon.feasibility.accel_step`).
        contact_tolerance: m; a geom this close to the floor in the reference touches it.
        friction: Sliding friction coefficient (None: the model's).
        torque_cap: Largest **root torque** in body-weight metres (m |g| x 1 m; 0: none, the default, the law above
            alone, bit for bit). The torque is a couple on the root body (the free joint's rotational dofs, given in
            the root's frame as MuJoCo's are), from a PD on the root's orientation in the world frame:
            ``tau = clip(torque_kp e + torque_kd (w* - w), torque_cap m |g| 1 m)``, e the rotation vector taking
            the root's orientation to the reference's (``log(q* q^-1)``), w and w* the angular velocities. A couple
            changes the angular momentum and not the centre of mass's motion: it supplies what the floor's contacts
            cannot turn the body by (a centre of pressure outside the feet, a yaw the feet's friction cannot give),
            which a force on the root's origin near the centre of mass barely can.
        torque_kp: N m per rad of the root's orientation error.
        torque_kd: N m s per rad of its angular velocity error.
    """

    scale: float = 0.0
    kp: float = 100.0
    kd: float = 20.0
    cap: float = 0.5
    step: int | None = None
    contact_tolerance: float = CONTACT_TOLERANCE
    friction: float | None = None
    torque_cap: float = 0.0
    torque_kp: float = 1000.0
    torque_kd: float = 100.0

    def __post_init__(self) -> None:
        if min(self.scale, self.kp, self.kd, self.cap, self.contact_tolerance, self.torque_cap, self.torque_kp,
               self.torque_kd) < 0.0:  # fmt: skip
            raise ValueError(f"assist: need scale, kp, kd, cap, contact_tolerance and the torque's cap, kp and kd "
                             f">= 0, got {self}")  # fmt: skip
        if self.step is not None and self.step < 1:
            raise ValueError(f"assist.step must be >= 1, got {self.step}")
        if self.friction is not None and not self.friction >= 0.0:
            raise ValueError(f"assist.friction must be >= 0, got {self.friction}")


def residual_per_frame(humanoid: Humanoid, qpos: np.ndarray, dt: float, step: int, tolerance: float = CONTACT_TOLERANCE,
                       friction: float | None = None) -> np.ndarray:  # fmt: skip
    """The reference's residual force vector (:func:`studies.samcon.feasibility.residual_vector`) at every frame,
    the first and last h frames taking their nearest measured neighbour's.

    Args:
        qpos: Reference generalised positions on the control grid. Shape: (T, nq), T >= 2h + 1.
        dt: Grid step in s.
        step: h in grid steps.
        tolerance: Contact tolerance in m.
        friction: mu (None: the model's).

    Returns:
        Shape: (T, 3), N, world frame.
    """
    if len(qpos) < 2 * step + 1:
        raise ValueError(f"the residual needs at least {2 * step + 1} reference frames, got {len(qpos)}")
    mu = model_friction(humanoid) if friction is None else friction
    com, clearance = com_and_clearance(humanoid, qpos)
    force, contact = external_force(humanoid, com, clearance, dt, step, tolerance)
    res = residual_vector(force, contact, mu)
    return np.concatenate([np.repeat(res[:1], step, axis=0), res, np.repeat(res[-1:], step, axis=0)])


class RootAssist:
    """The law of :class:`AssistConfig` for a clip's first ``steps`` steps from its start (an external force,
    :class:`samcon.search.ExternalForce`). The reference is :func:`samcon.search.reference_frames`', the residual's h
    frames past the last as the library continues the clip.
    """

    def __init__(self, humanoid: Humanoid, library: MotionLibrary, clip: int, steps: int, cfg: AssistConfig) -> None:
        m = humanoid.model
        if m.jnt_type[0] != mujoco.mjtJoint.mjJNT_FREE or m.jnt_dofadr[0] != 0 or m.jnt_qposadr[0] != 0:
            raise ValueError(f"{humanoid.xml_path}: the root force needs the free joint first")
        if cfg.step is None:
            raise ValueError("assist.step must be resolved per clip (studies.samcon.feasibility.accel_step) before use")
        self.cfg, self.nv, self.model = cfg, m.nv, m
        self.mass, self.limit = total_mass(humanoid), cfg.cap * body_weight(humanoid)
        self.torque_limit = cfg.torque_cap * body_weight(humanoid) * 1.0  # body-weight metres -> N m
        ref = reference_frames(library, clip, max(steps + cfg.step, 2 * cfg.step))
        res = residual_per_frame(humanoid, ref.qpos, library.dt, cfg.step, cfg.contact_tolerance, cfg.friction)
        self.feedforward = cfg.scale * 0.5 * (res[:steps] + res[1 : steps + 1])
        self.root_pos, self.root_vel = ref.qpos[:steps, 0:3].copy(), ref.qvel[:steps, 0:3].copy()
        self.root_quat = ref.qpos[:steps, 3:7].copy()
        self.root_angvel = quat_rotate(self.root_quat, ref.qvel[:steps, 3:6])  # world frame

    def _unclipped(self, frame: int, qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.cfg
        force = self.feedforward[frame] + self.mass * (cfg.kp * (self.root_pos[frame] - qpos[:, 0:3])
                                                       + cfg.kd * (self.root_vel[frame] - qvel[:, 0:3]))  # fmt: skip
        return force, np.sqrt(np.sum(force * force, axis=-1, keepdims=True))

    def torque(self, frame: int, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """The root torque in the root's frame (the free joint's rotational dofs), clipped. Shape: (n, 3), N m."""
        cfg, quat = self.cfg, qpos[:, 3:7]
        error = quat_to_rotvec(quat_mul(self.root_quat[frame], quat_conj(quat)))
        world = cfg.torque_kp * error + cfg.torque_kd * (self.root_angvel[frame] - quat_rotate(quat, qvel[:, 3:6]))
        norm = np.sqrt(np.sum(world * world, axis=-1, keepdims=True))
        return quat_rotate_inv(quat, world * np.minimum(1.0, self.torque_limit / np.maximum(norm, 1e-300)))

    def __call__(self, frame: int, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        force, norm = self._unclipped(frame, qpos, qvel)
        out = np.zeros((len(qpos), self.nv))
        out[:, 0:3] = force * np.minimum(1.0, self.limit / np.maximum(norm, 1e-300))
        if self.torque_limit > 0.0:
            out[:, 3:6] = self.torque(frame, qpos, qvel)
        return out

    def jacobian(self, frame: int, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """dF/dx (n, nv, 2 nv): u = the unclipped force, du/dp = -m kp, du/dv = -m kd (the free joint's tangent
        coordinates 0:3 and nv + 0:3 are the root's world position and velocity); clipped, F = L u / |u| and
        dF/du = L / |u| (I - u u^T / |u|^2)."""
        u, norm = self._unclipped(frame, qpos, qvel)
        n, nv = len(qpos), self.nv
        dfdu = np.tile(np.eye(3), (n, 1, 1)) if self.limit > 0.0 else np.zeros((n, 3, 3))  # cap 0: F = 0 everywhere
        over = norm[:, 0] > self.limit if self.limit > 0.0 else np.zeros(n, dtype=bool)
        if over.any():
            unit = u[over] / norm[over]
            dfdu[over] = (self.limit / norm[over])[:, :, None] * (np.eye(3) - unit[:, :, None] * unit[:, None, :])
        out = np.zeros((n, nv, 2 * nv))
        out[:, 0:3, 0:3] = -self.mass * self.cfg.kp * dfdu
        out[:, 0:3, nv : nv + 3] = -self.mass * self.cfg.kd * dfdu
        if self.torque_limit > 0.0:
            out[:, 3:6, 3:6], out[:, 3:6, nv + 3 : nv + 6] = self._torque_jacobian(frame, qpos, qvel)
        return out

    def _torque_jacobian(self, frame: int, qpos: np.ndarray, qvel: np.ndarray,
                         eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """d torque / d (root rotation, root angular velocity) in MuJoCo's tangent coordinates (a rotation vector in
        the root's frame, ``mj_integratePos``; the angular velocity in the root's frame), by central differences of
        :meth:`torque` (the law is cheap; the log map and the two frame changes make the exact derivative long).
        Shapes: (n, 3, 3) each."""
        n = len(qpos)
        rot, vel = np.zeros((n, 3, 3)), np.zeros((n, 3, 3))
        for j in range(3):
            for sign in (1.0, -1.0):
                moved = qpos.copy()
                step = np.zeros(self.nv)
                step[3 + j] = sign * eps
                for i in range(n):
                    mujoco.mj_integratePos(self.model, moved[i], step, 1.0)
                faster = qvel.copy()
                faster[:, 3 + j] += sign * eps
                rot[:, :, j] += sign * self.torque(frame, moved, qvel) / (2.0 * eps)
                vel[:, :, j] += sign * self.torque(frame, qpos, faster) / (2.0 * eps)
        return rot, vel


def judge(humanoid: Humanoid, states: np.ndarray, ref: CharacterState, ev: EvalConfig) -> dict[str, Any]:
    """The evaluator's open-loop figures for a path from a clip's start, from the same metric and termination
    functions: MPJPE-g and -l (mm) over every frame (the full-horizon protocol) and the first step (1-based) at which
    its failure rules (``ev.termination``) fire, None if never.

    Args:
        states: Full states after every step (:func:`samcon.search.replay`). Shape: (F, nstate).
        ref: The reference at frames 1..F. Leading shape (F,).
    """
    m = humanoid.model
    fk = ForwardKinematics(humanoid, threads=0)
    try:
        sim = fk(states[:, 1 : 1 + m.nq].copy(), states[:, 1 + m.nq : 1 + m.nq + m.nv].copy())
    finally:
        fk.close()
    geometry = BodyGeometry(humanoid)
    failed, _ = termination(ev.termination, humanoid, sim, ref, np.arange(1, len(states) + 1),
                            geometry.lowest_points(sim.body_pos, sim.body_rot),
                            geometry.lowest_points(ref.body_pos, ref.body_rot))  # fmt: skip
    return {
        "mpjpe_g": float(M.mpjpe_global_mm(sim.body_pos, ref.body_pos).mean()),
        "mpjpe_l": float(M.mpjpe_local_mm(sim.body_pos, ref.body_pos, root_index=humanoid.root_index).mean()),
        "fell_at": int(np.argmax(failed)) + 1 if failed.any() else None,
    }


def force_summary(forces: np.ndarray, weight: float, dofs: slice = slice(0, 3)) -> dict[str, float]:
    """|root force| over a path's steps (F, nv), in body weights: mean, 95th percentile, max, share above 0.1
    (``dofs`` 3:6: the root torque, in body-weight metres)."""
    norm = np.linalg.norm(forces[:, dofs], axis=-1) / weight
    return {"mean": float(norm.mean()), "p95": float(np.percentile(norm, 95)), "max": float(norm.max()),
            "share_over_0.1": float(np.mean(norm > 0.1))}  # fmt: skip


def _forces(forces: np.ndarray, weight: float, torque: bool, start: np.ndarray, states: np.ndarray) -> dict[str, Any]:
    """The root force's summary (``force_body_weights``) and, with a torque, the torque's
    (``torque_body_weight_metres``, m |g| x 1 m, with ``vertical_mean``: the mean |world z component|, the part
    that turns the body about the vertical). ``start`` (nstate,) and ``states`` (F, nstate): the path's states
    before its first step and after every step (the torque of step f is in the root's frame of the state before it).
    """
    out: dict[str, Any] = {"force_body_weights": force_summary(forces, weight)}
    if torque:
        quat = np.concatenate([start[None], states[:-1]])[:, 4:8]  # state = (time, qpos, ...): qpos[3:7]
        vertical = np.abs(quat_rotate(quat, forces[:, 3:6])[:, 2]) / weight
        out["torque_body_weight_metres"] = force_summary(forces, weight, slice(3, 6)) | {
            "vertical_mean": float(vertical.mean())}
    return out


def track_assisted(cfg: SamconConfig, acfg: AssistConfig, humanoid: Humanoid, library: MotionLibrary, clip: int,
                   log: Any, then_caps: Sequence[float] = (), then_search: Sequence[tuple[float, float]] = (),
                   then_sigma: float = 0.1, start_path: np.ndarray | None = None,
                   then_couple: Sequence[float] = (), again: int = 0,
                   save: Callable[[dict[str, np.ndarray]], None] = lambda paths: None,
                   ) -> tuple[dict[str, Any], dict[str, np.ndarray]]:  # fmt: skip
    """One clip: the search of ``cfg`` (and its polish when on) with the root force of ``acfg``, judged open loop
    from the clip's start with the force replayed. The draws are ``track-samcon``'s (its seed and the clip's name).

    ``then_caps`` (with the polish on): polish the path again with each of these caps in turn, each from the last
    one's targets (a continuation that takes the helping force away; with a last cap of 0 the result is an
    unassisted open-loop path), each judged with its own law (``row["then"]``).

    ``then_search`` (force cap, torque cap) pairs: after that, search again with each pair's law in turn, around the
    last path (its targets are the candidates' centre, :func:`samcon.search.samcon`'s ``centre``; ``sigma_init``
    ``then_sigma``), and polish the result with the same law when the config has a polish (``row["then_search"]``).
    Unlike ``then_caps`` the search keeps many states per segment, so it can correct the drift that taking the help
    away causes where it begins. With a last pair (0, 0) the result is an unassisted open-loop path.

    ``start_path`` (F, nu): instead of the search (and polish, and ``then_caps``), this path (e.g. a stage saved by
    ``--paths``), judged with ``acfg``'s law (``row["given"]``), is where ``then_search`` starts.

    ``then_couple`` weights (per (N m)^2 per frame): last, the couple the last path's law gives (a law without
    force: its caps' force cap 0) is polished as a control with each weight in turn (``row["then_couple"]``,
    judged with the couple held), then the path without it (``row["unassisted"]``); see the module docstring.
    ``again``: then polish the last, unassisted path that many more times (``row["unassisted"]`` the last, each
    round's figures in ``row["unassisted_rounds"]``), stopping at a round the polish dropped (the next would repeat
    it).

    ``save`` is called with the paths so far after every stage (``--paths`` writes them then, so that a run stopped
    midway keeps its finished stages).

    Returns:
        The row of figures, and the paths: ``start_state`` and the targets of every stage (``searched``,
        ``polished``, ``then_search_<i>``, or ``given``; (F, nu)).
    """
    name, frames = library.names[clip], horizon(library, clip, cfg.train.max_frames)

    rng = clip_generator(cfg.train.seed, name)
    common = dict(threads=cfg.train.threads, max_speed=cfg.gym.max_speed, rsi_lift=cfg.train.eval.rsi_lift,
                  progress=segment_progress(name, log))  # fmt: skip
    ref = reference_frames(library, clip, frames)
    row: dict[str, Any] = {"frames": frames, "step": acfg.step}
    weight, torque = body_weight(humanoid), acfg.torque_cap > 0.0
    if start_path is not None:
        if start_path.shape != (frames, humanoid.nu):
            raise ValueError(f"{name}: the given path is {start_path.shape}, the clip needs ({frames}, {humanoid.nu})")
        first = start_state(library, humanoid, clip, cfg.train.eval.rsi_lift)
        law = RootAssist(humanoid, library, clip, frames, acfg)
        states, forces = assisted_replay(humanoid, first, start_path, law, 0, cfg.gym.max_speed)
        row["given"] = judge(humanoid, states, ref[1:], cfg.train.eval)
        row |= _forces(forces, weight, torque, first, states)
        paths = {"start_state": first, "given": np.asarray(start_path, dtype=float)}
        return _search_around(cfg, acfg, humanoid, library, clip, log, row, paths, paths["given"], 0, 0.0,
                              then_search, then_sigma, rng, common, then_couple, again, save)  # fmt: skip
    traj, states, forces = _search(cfg, cfg.search, acfg, humanoid, library, clip, rng, common)
    paths = {"start_state": traj.start_state, "searched": traj.targets}
    row["searched"] = judge(humanoid, states, ref[1:], cfg.train.eval)
    row |= _forces(forces, weight, torque, traj.start_state, states)
    for j, cap in enumerate([acfg.cap, *then_caps] if cfg.polish.iterations else []):
        law = RootAssist(humanoid, library, clip, frames, replace(acfg, cap=cap))
        traj = polished(traj, cfg, humanoid, library, clip, log, force=law)
        states, forces = assisted_replay(humanoid, traj.start_state, traj.targets, law, 0, cfg.gym.max_speed)
        judged = judge(humanoid, states, ref[1:], cfg.train.eval) | {"kept": bool(traj.polish["kept"])}
        if j == 0:  # the assisted result: its force replaces the search's
            row["polished"] = judged
            row |= _forces(forces, weight, torque, traj.start_state, states)
            paths["polished"] = traj.targets
            save(paths)
            continue
        row.setdefault("then", []).append(judged | {"cap": cap} | _forces(forces, weight, torque, traj.start_state,
                                                                          states))  # fmt: skip
        fell = "" if judged["fell_at"] is None else f", fell at step {judged['fell_at']}"
        print(f"{name}: polished again with cap {cap:g}: MPJPE-g {judged['mpjpe_g']:.1f} mm{fell}", file=log,
              flush=True)  # fmt: skip
    return _search_around(cfg, acfg, humanoid, library, clip, log, row, paths, traj.targets, traj.samples,
                          traj.seconds, then_search, then_sigma, rng, common, then_couple, again, save)  # fmt: skip


def _search(cfg: SamconConfig, search: SearchConfig, acfg: AssistConfig, humanoid: Humanoid, library: MotionLibrary,
            clip: int, rng: np.random.Generator, common: dict[str, Any],
            centre: np.ndarray | None = None) -> tuple[Trajectory, np.ndarray, np.ndarray]:  # fmt: skip
    """The search of ``search`` from the clip's start under ``acfg``'s law (around ``centre`` if given), and its path
    replayed with the law: the trajectory, the states (F, nstate) and the force of every step (F, nv)."""
    frames = horizon(library, clip, cfg.train.max_frames)
    law = RootAssist(humanoid, library, clip, searched_frames(library, clip, frames, search.lookahead_frames), acfg)
    traj = samcon(humanoid, library, clip, frames, search, cfg.cost, rng, force=law, centre=centre, **common)
    states, forces = assisted_replay(humanoid, traj.start_state, traj.targets, law, 0, cfg.gym.max_speed)
    return traj, states, forces


def _search_around(cfg: SamconConfig, acfg: AssistConfig, humanoid: Humanoid, library: MotionLibrary, clip: int,
                   log: Any, row: dict[str, Any], paths: dict[str, np.ndarray], centre: np.ndarray, samples: int,
                   seconds: float, then_search: Sequence[tuple[float, float]], then_sigma: float,
                   rng: np.random.Generator, common: dict[str, Any],
                   then_couple: Sequence[float] = (), again: int = 0,
                   save: Callable[[dict[str, np.ndarray]], None] = lambda paths: None,
                   ) -> tuple[dict[str, Any], dict[str, np.ndarray]]:  # fmt: skip
    """:func:`track_assisted`'s ``then_search``, ``then_couple`` and ``again`` stages from the path ``centre`` (under
    ``acfg``'s law), adding to its row and paths."""
    name, frames = library.names[clip], horizon(library, clip, cfg.train.max_frames)
    ref, weight = reference_frames(library, clip, frames), body_weight(humanoid)
    stage = acfg
    for i, (force_cap, torque_cap) in enumerate(then_search):
        stage = replace(acfg, cap=force_cap, torque_cap=torque_cap)
        print(f"{name}: searching around the last path with force cap {force_cap:g}, torque cap {torque_cap:g}",
              file=log, flush=True)  # fmt: skip
        traj, states, forces = _search(cfg, replace(cfg.search, sigma_init=then_sigma), stage, humanoid, library,
                                       clip, rng, common, centre)  # fmt: skip
        samples, seconds = samples + traj.samples, seconds + traj.seconds
        result: dict[str, Any] = {"force_cap": force_cap, "torque_cap": torque_cap,
                                  "searched": judge(humanoid, states, ref[1:], cfg.train.eval)}  # fmt: skip
        if cfg.polish.iterations:
            law = RootAssist(humanoid, library, clip, frames, stage)
            before = traj.seconds
            traj = polished(traj, cfg, humanoid, library, clip, log, force=law)
            seconds += traj.seconds - before
            states, forces = assisted_replay(humanoid, traj.start_state, traj.targets, law, 0, cfg.gym.max_speed)
            result["polished"] = judge(humanoid, states, ref[1:], cfg.train.eval) | {"kept": bool(traj.polish["kept"])}
        result |= _forces(forces, weight, torque_cap > 0.0, traj.start_state, states)
        row.setdefault("then_search", []).append(result)
        paths[f"then_search_{i}"] = centre = traj.targets
        save(paths)
        last = result.get("polished", result["searched"])
        fell = "" if last["fell_at"] is None else f", fell at step {last['fell_at']}"
        print(f"{name}: searched around the last path with force cap {force_cap:g}, torque cap {torque_cap:g}: "
              f"MPJPE-g {result['searched']['mpjpe_g']:.1f} mm searched, {last['mpjpe_g']:.1f} mm last{fell}",
              file=log, flush=True)  # fmt: skip
    if then_couple or again:
        seconds += _couple_away(cfg, stage, humanoid, library, clip, log, row, paths, centre, then_couple, again,
                                save)  # fmt: skip
    row |= {"samples": samples, "minutes": seconds / 60.0,
            "minutes_per_motion_second": seconds / 60.0 / (frames * library.dt)}  # fmt: skip
    return row, paths


def _couple_away(cfg: SamconConfig, acfg: AssistConfig, humanoid: Humanoid, library: MotionLibrary, clip: int,
                 log: Any, row: dict[str, Any], paths: dict[str, np.ndarray], targets: np.ndarray,
                 weights: Sequence[float], again: int = 0,
                 save: Callable[[dict[str, np.ndarray]], None] = lambda paths: None) -> float:  # fmt: skip
    """:func:`track_assisted`'s ``then_couple`` stages from ``targets`` under ``acfg``'s law, adding to its row and
    paths (``then_couple_<i>`` and its ``then_couple_<i>_couple`` (F, 3) in N m, ``unassisted``), then with
    ``weights`` the path polished without the couple, and ``again`` more polishes of it. Returns the polishes'
    seconds."""
    name, frames = library.names[clip], horizon(library, clip, cfg.train.max_frames)
    ref, weight = reference_frames(library, clip, frames), body_weight(humanoid)
    ref_targets = ref.qpos[1:, humanoid.hinge_qpos]
    first = start_state(library, humanoid, clip, cfg.train.eval.rsi_lift)
    law = RootAssist(humanoid, library, clip, frames, acfg)
    _, forces = assisted_replay(humanoid, first, targets, law, 0, cfg.gym.max_speed)
    if np.abs(forces[:, :3]).max() > 0.0:
        raise ValueError(f"{name}: --then-couple takes a couple away, but the last path's law also gives a root force "
                         f"(force cap {acfg.cap:g}); end --then-search with a force cap of 0")  # fmt: skip
    values, seconds = forces[:, ROOT_TURN], 0.0
    pcfg = replace(cfg.polish, follow=False)  # a look-ahead played by an LQR cannot carry the couple
    common = dict(lqr=cfg.lqr, name=name, log=log)
    for i, w in enumerate(weights):
        targets, summary = polish_couple(humanoid, first, targets, ref, ref_targets, pcfg, cfg.cost.fall_head_error,
                                         Couple(values, w), **common)  # fmt: skip
        values, seconds = summary.pop("couple"), seconds + summary["seconds"]
        states, _ = assisted_replay(humanoid, first, targets, Couple(values, w).law(humanoid.nv), 0,
                                    cfg.gym.max_speed)  # fmt: skip
        norm = np.linalg.norm(values, axis=1) / weight
        judged = judge(humanoid, states, ref[1:], cfg.train.eval) | {
            "weight": w, "kept": bool(summary["kept"]),
            "torque_body_weight_metres": {"mean": float(norm.mean()), "p95": float(np.percentile(norm, 95)),
                                          "max": float(norm.max())}}  # fmt: skip
        row.setdefault("then_couple", []).append(judged)
        paths[f"then_couple_{i}"], paths[f"then_couple_{i}_couple"] = targets, values
        save(paths)
        print(f"{name}: polished with the couple as a control at weight {w:g}: MPJPE-g {judged['mpjpe_g']:.1f} mm, "
              f"couple mean {norm.mean():.3f} body-weight metres", file=log, flush=True)  # fmt: skip
    for j in range((1 if weights else 0) + again):
        targets, summary = polish(humanoid, first, targets, ref, ref_targets, cfg.polish, cfg.cost.fall_head_error,
                                  **common)  # fmt: skip
        seconds += summary["seconds"]
        states = replay(humanoid, first, targets, cfg.gym.max_speed)
        row["unassisted"] = judge(humanoid, states, ref[1:], cfg.train.eval) | {"kept": bool(summary["kept"])}
        row.setdefault("unassisted_rounds", []).append(row["unassisted"])
        paths["unassisted"] = targets
        save(paths)
        print(f"{name}: without help, polished (round {j + 1}): MPJPE-g {row['unassisted']['mpjpe_g']:.1f} mm",
              file=log, flush=True)  # fmt: skip
        if not summary["kept"]:  # the polish is deterministic: from the same path a next round does the same
            break
    return seconds


def _cap_pair(spec: str) -> tuple[float, float]:
    """``FORCE_CAP:TORQUE_CAP`` (``--then-search``) -> the two caps, both >= 0."""
    try:
        force, torque = (float(v) for v in spec.split(":"))
    except ValueError:
        raise ConfigError(f"--then-search: {spec!r} is not FORCE_CAP:TORQUE_CAP (two numbers, e.g. 0:0.05)") from None
    if not (force >= 0.0 and torque >= 0.0):
        raise ConfigError(f"--then-search: {spec!r}: the caps must be >= 0")
    return force, torque


def _given_paths(spec: str, motions: Sequence[str]) -> dict[str, np.ndarray]:
    """``FILE.npz:STAGE`` (``--start-path``) -> {clip: that clip's targets of the stage} for every clip named."""
    file, _, stage = spec.rpartition(":")
    if not file or not stage:
        raise ConfigError(f"--start-path: {spec!r} is not FILE.npz:STAGE")
    try:
        with np.load(file) as saved:
            held = list(saved.files)
            got = {name: saved[f"{name}/{stage}"] for name in motions if f"{name}/{stage}" in held}
    except (OSError, ValueError) as e:
        raise ConfigError(f"{file}: cannot be read as a --paths file ({e})") from None
    missing = [f"{name}/{stage}" for name in motions if name not in got]
    if missing:
        raise ConfigError(f"{file}: no {', '.join(missing)} (it holds {', '.join(held)})")
    return got


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m studies.samcon.assist", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--config", default="configs/samcon/polish.yaml",
                        help="track-samcon config whose search, cost, polish and seed are used "
                             "(default: configs/samcon/polish.yaml, the search and the polish)")  # fmt: skip
    parser.add_argument("--motions", nargs="+", default=None, help="clips, overriding train.motions")
    parser.add_argument("--seed", type=int, default=None, help="sampling seed (train.seed)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override a config value, e.g. --set search.samples=400 (repeatable)")
    defaults = AssistConfig()
    parser.add_argument("--scale", type=float, default=defaults.scale,
                        help="feed-forward share of the reference's residual force (default: %(default)s)")
    parser.add_argument("--kp", type=float, default=defaults.kp, metavar="PER_S2",
                        help="root position feedback, 1/s^2 times the mass (default: %(default)s)")
    parser.add_argument("--kd", type=float, default=defaults.kd, metavar="PER_S",
                        help="root velocity feedback, 1/s times the mass (default: %(default)s)")
    parser.add_argument("--cap", type=float, default=defaults.cap, metavar="BODY_WEIGHTS",
                        help="largest root force in body weights; 0: none, the unassisted search through the same "
                             "code (default: %(default)s)")  # fmt: skip
    parser.add_argument("--torque-cap", type=float, default=defaults.torque_cap, metavar="BODY_WEIGHT_METRES",
                        help="largest root torque (a couple on the root, from a PD on its orientation) in m |g| x 1 m; "
                             "0: none (default: %(default)s)")  # fmt: skip
    parser.add_argument("--torque-kp", type=float, default=defaults.torque_kp, metavar="NM_PER_RAD",
                        help="root orientation feedback of the torque (default: %(default)s)")
    parser.add_argument("--torque-kd", type=float, default=defaults.torque_kd, metavar="NMS_PER_RAD",
                        help="root angular velocity feedback of the torque (default: %(default)s)")
    parser.add_argument("--then-caps", type=float, nargs="+", default=[], metavar="BODY_WEIGHTS",
                        help="after the assisted polish, polish again with each of these caps in turn (e.g. 0.25 0.1 "
                             "0: a continuation that takes the force away; needs a config with a polish; the root "
                             "torque, if any, stays as it is)")  # fmt: skip
    parser.add_argument("--then-search", nargs="+", default=[], metavar="FORCE_CAP:TORQUE_CAP",
                        help="after that, search again around the last path (its targets the candidates' centre) with "
                             "each of these force and torque caps in turn, each polished when the config has a "
                             "polish (e.g. 0:0.05 0:0: a continuation that takes a root torque away; with 0:0 last, "
                             "the result is an unassisted open-loop path)")  # fmt: skip
    parser.add_argument("--then-sigma", type=float, default=0.1, metavar="RAD",
                        help="sigma_init of the searches of --then-search (default: %(default)s)")
    parser.add_argument("--then-couple", type=float, nargs="+", default=[], metavar="WEIGHT",
                        help="last, polish the path with its root couple as a control costing WEIGHT x |couple|^2 "
                             "per frame ((N m)^-2, in the polish's cost units) for each weight in turn (rising, e.g. "
                             "1e-5 1e-4 1e-3), then once more without it: an unassisted open-loop path; needs a "
                             "polish and a law without force (--cap 0, or a last --then-search pair 0:C)")  # fmt: skip
    parser.add_argument("--polish-again", type=int, default=0, metavar="N",
                        help="last, polish the final unassisted path N more times (after --then-couple, or when the "
                             "last path has no help: a last --then-search pair 0:0, or --start-path with --cap 0 "
                             "--torque-cap 0) (default: 0)")  # fmt: skip
    parser.add_argument("--start-path", default=None, metavar="FILE.npz:STAGE",
                        help="skip the search: start --then-search from each clip's path STAGE of a --paths file "
                             "(e.g. runs/a.npz:then_search_0), judged first with --cap and --torque-cap")  # fmt: skip
    parser.add_argument("--paths", default=None, metavar="FILE.npz",
                        help="also write every clip's start state and each stage's PD targets there (atomically, "
                             "after every stage; arrays <clip>/start_state, <clip>/searched, <clip>/polished, "
                             "<clip>/then_search_<i>)")  # fmt: skip
    parser.add_argument("--step", type=int, default=None, metavar="H",
                        help="differencing step of the residual in control steps (default: per clip, its source "
                             "keyframe spacing rounded up, at least 2, as studies.samcon.feasibility measures "
                             "it)")  # fmt: skip
    parser.add_argument("--contact-tolerance", type=float, default=CONTACT_TOLERANCE, metavar="METRES",
                        help=f"reference contact tolerance (default: {CONTACT_TOLERANCE} m)")
    parser.add_argument("--friction", type=float, default=None, metavar="MU",
                        help="friction coefficient of the cone (default: the model's)")
    parser.add_argument("--out", default=None, metavar="FILE.json",
                        help="write the per-clip figures there (atomically), after every clip")
    return parser


def main(argv: Sequence[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    try:
        cfg = load_config(SamconConfig, args.config, cli_overrides(args))
        acfg = AssistConfig(scale=args.scale, kp=args.kp, kd=args.kd, cap=args.cap, step=args.step,
                            contact_tolerance=args.contact_tolerance, friction=args.friction,
                            torque_cap=args.torque_cap, torque_kp=args.torque_kp, torque_kd=args.torque_kd)  # fmt: skip
        if cfg.search.sigma_choices:
            raise ConfigError(f"{args.config}: search.sigma_choices is not supported here; set search.sigma_init")
        if args.then_caps and (not cfg.polish.iterations or min(args.then_caps) < 0):
            raise ConfigError(f"--then-caps needs caps >= 0 and a config with a polish ({args.config}: "
                              f"polish.iterations {cfg.polish.iterations})")  # fmt: skip
        then_search = [_cap_pair(spec) for spec in args.then_search]
        if args.start_path and (args.then_caps or not (then_search or args.then_couple or args.polish_again)):
            raise ConfigError("--start-path needs --then-search, --then-couple or --polish-again and takes no "
                              "--then-caps")  # fmt: skip
        last = then_search[-1] if then_search else (args.cap, args.torque_cap)
        if args.polish_again < 0 or (args.polish_again and not cfg.polish.iterations):
            raise ConfigError(f"--polish-again needs N >= 0 and a config with a polish, got {args.polish_again}")
        if args.polish_again and not args.then_couple and max(last) > 0.0:
            raise ConfigError("--polish-again polishes an unassisted path: end with --then-couple, a --then-search "
                              "pair 0:0, or give --cap 0 --torque-cap 0")  # fmt: skip
        if args.then_couple and (not cfg.polish.iterations or min(args.then_couple) <= 0.0):
            raise ConfigError(f"--then-couple needs weights > 0 and a config with a polish ({args.config}: "
                              f"polish.iterations {cfg.polish.iterations})")  # fmt: skip
        if args.then_couple and (then_search[-1][0] if then_search else args.cap) > 0.0:
            raise ConfigError("--then-couple takes a root couple away, not a force: the last path's force cap (--cap, "
                              "or the last --then-search pair's first number) must be 0")  # fmt: skip
        if not args.then_sigma > 0.0:
            raise ConfigError(f"--then-sigma must be > 0, got {args.then_sigma}")
        if cfg.polish.iterations and cfg.polish.search:
            raise ConfigError(f"{args.config}: polish.search is not supported here (its searches have no root force)")
        humanoid = Humanoid(cfg.gym.physics)
        # resolve_clips + from_clips (load_motions without its dataset branch): h needs the source keyframe times.
        clips = resolve_clips(list(cfg.train.motions))
        library = MotionLibrary.from_clips(clips, humanoid)
        given = _given_paths(args.start_path, library.names) if args.start_path else None
        for c, name in enumerate(library.names if given is not None else []):
            need = (horizon(library, c, cfg.train.max_frames), humanoid.nu)
            if given[name].shape != need:
                raise ConfigError(f"{args.start_path}: {name}'s path is {given[name].shape}, the clip needs {need}")
    except (ConfigError, MotionFormatError, FileNotFoundError, ValueError) as e:
        sys.exit(f"error: {e}")
    out: dict[str, Any] = {"config": args.config, "overrides": args.overrides, "assist": vars(acfg), "clips": {},
                           "then_search": then_search, "then_sigma": args.then_sigma,
                           "then_couple": args.then_couple, "polish_again": args.polish_again,
                           "start_path": args.start_path}  # fmt: skip
    paths: dict[str, np.ndarray] = {}
    t0 = time.perf_counter()

    def write_paths(got: dict[str, np.ndarray]) -> None:
        if args.paths is not None:
            with atomic_output(args.paths) as tmp, open(tmp, "wb") as f:
                np.savez(f, **got)

    for c, name in enumerate(library.names):
        step = acfg.step or accel_step(1.0 / clips[c].source_fps, library.dt)
        row, clip_paths = track_assisted(
            cfg, replace(acfg, step=step), humanoid, library, c, sys.stdout, args.then_caps, then_search,
            args.then_sigma, None if given is None else given[name], args.then_couple, args.polish_again,
            lambda so_far, name=name, done=paths: write_paths(done | {f"{name}/{k}": v for k, v in so_far.items()}),
        )  # fmt: skip
        out["clips"][name] = row
        paths |= {f"{name}/{key}": value for key, value in clip_paths.items()}
        stages = [(key, row[key]) for key in ("given", "searched", "polished") if key in row]
        stages += [(f"at cap {t['cap']:g}", t) for t in row.get("then", [])]
        stages += [(f"around it at caps {t['force_cap']:g}:{t['torque_cap']:g}", t.get("polished", t["searched"]))
                   for t in row.get("then_search", [])]  # fmt: skip
        stages += [(f"with the couple at weight {t['weight']:g}", t) for t in row.get("then_couple", [])]
        stages += [(f"without help, polish {j + 1}", t) for j, t in enumerate(row.get("unassisted_rounds", []))]
        figures = ", ".join(f"{j['mpjpe_g']:.1f} mm {label}" + ("" if j["fell_at"] is None else f" (fell at step "
                            f"{j['fell_at']})") for label, j in stages)  # fmt: skip
        torque = row.get("torque_body_weight_metres")
        figures += "" if torque is None else f"; root torque mean {torque['mean']:.3f} body-weight metres"
        print(f"{name}: MPJPE-g {figures}; root force mean {row['force_body_weights']['mean']:.3f} body weights; "
              f"{row['minutes_per_motion_second']:.2f} min per s of motion", flush=True)  # fmt: skip
        if args.out is not None:
            out["seconds"] = time.perf_counter() - t0
            with atomic_output(args.out) as tmp:
                tmp.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
        write_paths(paths)
    if args.out is not None:
        print(f"written: {args.out}")


if __name__ == "__main__":
    main()
