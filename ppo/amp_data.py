"""What the AMP discriminator sees: motion features of a character state, expert transitions from the motion library,
and a replay buffer of the policy's transitions.

One feature function (:class:`AMPFeatures`) serves both sides: the policy's transitions are the gym's simulated states
(written per frame by :class:`ppo.actor.GymActor`), the expert's are the library's reference states
(:class:`ExpertSampler`); a transition is the pair [s, s'] of one control step (dt apart). The features are motion
only (rsl_rl's guidance; no task inputs, no reference, no phase), and do not change under a turn about the vertical
or a shift along the ground, so that a motion looks the same wherever it is played:
- ``root_height``: the root's height above the ground (1);
- ``root_rot``: two-axis encoding of H^-1 q_root, the root's tilt (6), H the root's heading (yaw) rotation;
- ``root_vel``, ``root_angvel``: H^-1 v_root, H^-1 w_root, world velocities in the heading frame (3 + 3);
- ``joint_rot``: two-axis encoding of every joint's local rotation (12 joints x 6). Rotations, not the hinge angles
  of qpos: a wrap clip's angles gain whole turns per cycle (:meth:`common.motion.library.MotionLibrary._cycle_wind`),
  so the same pose would show other angles in another cycle;
- ``joint_vel``: the hinge velocities of qvel (28);
- ``end_effectors`` (optional): hands and feet in the root's frame, R_root^-1 (x_e - x_root) (4 x 3).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from common.character.humanoid import Humanoid, hinges_to_joint_rotations
from common.character.state import CharacterState
from common.maths.rotations import quat_conj, quat_from_yaw, quat_mul, quat_rotate, quat_to_two_axis, quat_yaw
from common.motion.library import MotionLibrary


class AMPFeatures:
    """The discriminator's features of a character state (see the module docstring).

    Args:
        humanoid: The model (joints, hinges, end effectors).
        end_effectors: Add the hands' and feet's positions in the root frame.
    """

    def __init__(self, humanoid: Humanoid, end_effectors: bool = True) -> None:
        self.humanoid = humanoid
        self.root = humanoid.root_index
        self.hinge_dof = humanoid.hinge_dof
        self.effectors = humanoid.end_effector_indices if end_effectors else None
        widths = {"root_height": 1, "root_rot": 6, "root_vel": 3, "root_angvel": 3,
                  "joint_rot": 6 * len(humanoid.joint_groups), "joint_vel": len(self.hinge_dof)}  # fmt: skip
        if self.effectors is not None:
            widths["end_effectors"] = 3 * len(self.effectors)
        self.layout: dict[str, slice] = {}
        start = 0
        for name, width in widths.items():
            self.layout[name] = slice(start, start + width)
            start += width
        self.size = start

    def named(self, state: CharacterState) -> dict[str, np.ndarray]:
        """Named features of N characters, {name: (N, k)}, in the flat order."""
        n = state.qpos.shape[0]
        root_pos, root_rot = state.body_pos[:, self.root], state.body_rot[:, self.root]
        heading_inv = quat_conj(quat_from_yaw(quat_yaw(root_rot)))
        out = {
            "root_height": root_pos[:, 2:3],
            "root_rot": quat_to_two_axis(quat_mul(heading_inv, root_rot)),
            "root_vel": quat_rotate(heading_inv, state.body_linvel[:, self.root]),
            "root_angvel": quat_rotate(heading_inv, state.body_angvel[:, self.root]),
            "joint_rot": quat_to_two_axis(hinges_to_joint_rotations(self.humanoid, state.qpos)).reshape(n, -1),
            "joint_vel": state.qvel[:, self.hinge_dof],
        }
        if self.effectors is not None:
            local = state.body_pos[:, self.effectors] - root_pos[:, None]
            out["end_effectors"] = quat_rotate(quat_conj(root_rot)[:, None], local).reshape(n, -1)
        return out

    def __call__(self, state: CharacterState) -> np.ndarray:
        """Flat features of N characters. Shape: (N, D), float32."""
        return np.concatenate(list(self.named(state).values()), axis=-1).astype(np.float32)


class ExpertSampler:
    """Expert transitions [s, s'] from the motion library's reference kinematics.

    Args:
        library: The clips.
        features: The feature function (the policy's).
    """

    def __init__(self, library: MotionLibrary, features: AMPFeatures) -> None:
        self.library, self.features = library, features

    def at(self, clips: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Features of the reference at (clip, t) and at (clip, t + dt). Shapes: (M,), (M,) -> (M, D), (M, D)."""
        lib = self.library
        return self.features(lib.query(clips, times)), self.features(lib.query(clips, times + lib.dt))

    def sample(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """n transitions at random clips (uniform) and grid times that leave a step to play (as RSI draws them)."""
        return self.at(*self.library.sample_starts(n, rng))


class TransitionReplay:
    """A cyclic buffer of the policy's transitions, rows [s, s'] (float32), with MimicKit's turnover: until it is
    full it takes every transition of a rollout, then ``samples`` of them (drawn without replacement), overwriting
    the oldest rows.

    Args:
        capacity: Rows held.
        width: Row width (2 D).
    """

    def __init__(self, capacity: int, width: int) -> None:
        self.data = np.zeros((capacity, width), dtype=np.float32)
        self.head = 0  # next row to write
        self.size = 0

    @property
    def capacity(self) -> int:
        return self.data.shape[0]

    @property
    def full(self) -> bool:
        return self.size == self.capacity

    def add(self, rows: np.ndarray, samples: int, rng: np.random.Generator) -> None:
        """Adds a rollout's transitions (M, width): all of them until the buffer is full, then ``samples`` drawn."""
        if self.full and samples < len(rows):
            rows = rows[np.sort(rng.choice(len(rows), size=samples, replace=False))]
        rows = rows[-self.capacity :]
        idx = (self.head + np.arange(len(rows))) % self.capacity
        self.data[idx] = rows
        self.head = int((self.head + len(rows)) % self.capacity)
        self.size = min(self.capacity, self.size + len(rows))

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """n rows drawn uniformly (with replacement) from those held. Shape: (n, width)."""
        if self.size == 0:
            raise RuntimeError("the replay buffer is empty")
        return self.data[rng.integers(0, self.size, size=n)]

    def state_dict(self) -> dict[str, Any]:
        return {"data": self.data[: self.size].copy(), "head": self.head, "capacity": self.capacity}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        data = np.asarray(state["data"], dtype=np.float32)
        if int(state["capacity"]) != self.capacity or data.shape[1:] != self.data.shape[1:]:
            raise ValueError(f"replay buffer state holds {state['capacity']} rows of {data.shape[1:]}, this one "
                             f"{self.capacity} of {self.data.shape[1:]}")  # fmt: skip
        self.data[:] = 0.0
        self.data[: len(data)] = data
        self.head, self.size = int(state["head"]), len(data)
