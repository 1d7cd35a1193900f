"""Pushes on the pelvis for the robustness protocol: a seeded impulse schedule and its exact velocity change.

A push is an impulse p (N s) applied at the pelvis's frame origin, horizontal, in a random direction. It changes
the generalised velocities at once by dqvel = M(q)^-1 J(q)^T p (J: the 3 x nv translational Jacobian of that point,
M: the joint-space inertia matrix), the impulsive limit of a short force; the character's total linear momentum
then changes by exactly p when nothing touches it.

Nothing here depends on the ground: M and J are the pose's, so a character on its clip's terrain gets the velocity
change it would get on the flat floor in that pose (the gym computes it in the character's own model, without the
heightfield, ``tests/common/test_judge_terrain.py``), and the schedule's impulses are horizontal whatever the ground's
slope.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np


@dataclass(frozen=True)
class PushConfig:
    """The push schedule of the robustness protocol.

    Attributes:
        impulse: Size of every push (N s). 30 N s on the 45 kg humanoid changes its centre-of-mass velocity by
            about 0.67 m/s, a firm shove (DeepMimic's perturbation tests pushed for 0.1-0.2 s with 100-600 N).
        first_frame: Control step of an episode at which the first push lands.
        interval: Control steps between pushes (120 = 2 s at 60 Hz).
        seed: Seed of the directions (one generator for the whole evaluation, drawn in episode order).
    """

    impulse: float = 30.0
    first_frame: int = 60
    interval: int = 120
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.impulse >= 0:
            raise ValueError(f"pushes.impulse must be >= 0 (N s), got {self.impulse}")
        if self.first_frame < 0 or self.interval < 1:
            raise ValueError("pushes.first_frame must be >= 0 and pushes.interval >= 1")


def push_schedule(config: PushConfig, num_episodes: int, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """Which frames push, and the impulse of every episode at each of them.

    Args:
        config: The schedule.
        num_episodes: Episodes evaluated together, E.
        horizon: Control steps of the longest episode.

    Returns:
        frames: Control steps at which a push lands, ascending. Shape: (P,).
        impulses: World-frame impulse per push and episode, horizontal. Shape: (P, E, 3).
    """
    frames = np.arange(config.first_frame, horizon, config.interval, dtype=np.int64)
    angle = np.random.default_rng(config.seed).uniform(0.0, 2.0 * np.pi, size=(len(frames), num_episodes))
    impulses = config.impulse * np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], axis=-1)
    return frames, impulses


def impulse_velocity_change(model: mujoco.MjModel, data: mujoco.MjData, qpos: np.ndarray, qvel: np.ndarray,
                            body: int, impulse: np.ndarray) -> np.ndarray:  # fmt: skip
    """dqvel = M^-1 J^T p for an impulse ``p`` at the frame origin of ``body`` (MuJoCo body id).

    Args:
        model: The model.
        data: Scratch data (overwritten).
        qpos: Generalised positions of one character. Shape: (nq,).
        qvel: Its generalised velocities. Shape: (nv,).
        body: MuJoCo body id (1 = the pelvis of the humanoid).
        impulse: World-frame impulse (N s). Shape: (3,).

    Returns:
        The change of qvel. Shape: (nv,).
    """
    data.qpos[:], data.qvel[:] = qpos, qvel
    mujoco.mj_forward(model, data)
    jacp = np.zeros((3, model.nv))
    mujoco.mj_jac(model, data, jacp, None, data.xpos[body], body)
    dqvel = np.zeros(model.nv)
    mujoco.mj_solveM(model, data, dqvel.reshape(1, -1), (jacp.T @ np.asarray(impulse, dtype=np.float64))[None])
    return dqvel
