"""SuperTrack on terrain (issue 59, the ``terrain`` config): the heightmap W and the policy read, the simulated contacts
W learns to predict and the reference's contact labels the policy reads. All three are raw (not normalised), as PPO's
``parc`` observation leaves them (:func:`common.sim.observation.is_raw_feature`).

- **Heightmap**: the root's height above its clip's ground at a square grid of points around it, turned with its
  heading (:func:`common.sim.torch_terrain.heightmap`, PPO's ``heightmap`` in torch), sampled where the input state
  puts the root: at S_i in the gym, at the predicted P_i in W's rollouts, so that its gradient reaches the prediction.
  On the flat floor it is the root's height at every point.
- **Contacts** (PPO's rule, :func:`common.sim.terrain.contact_labels`: a body whose collision geom comes within
  ``contact_height`` of the ground), computed on the gym side and stored with each frame: ``sim_contacts`` of S_i
  (what W's contact logits for P_i are trained against) and ``kin_contacts`` of the reference at t_i + k dt for every
  k of ``contact_frames`` (what the policy read when it acted, read again when it trains on the frame).

A window's terrain is its clip's: the buffer stores each frame's clip, and a window never crosses an episode, so
never a clip.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from common.character.humanoid import BodyGeometry, Humanoid
from common.motion.library import MotionLibrary
from common.sim.gym import StepResult
from common.sim.terrain import ClipTerrains, contact_labels, heightmap_offsets
from common.sim.torch_terrain import TerrainField, heightmap
from supertrack.config import TerrainConfig
from supertrack.state import BodyState


def heightmap_size(config: TerrainConfig) -> int:
    """Width P of the heightmap W and the policy read (0: none)."""
    e = config.heightmap_extent
    return 0 if e is None else len(heightmap_offsets(e, config.heightmap_spacing))


def policy_terrain_size(config: TerrainConfig, num_bodies: int) -> int:
    """Width of the policy's terrain inputs: the heightmap, then K x N reference contact labels (0: none)."""
    return heightmap_size(config) + len(config.contact_frames) * num_bodies


def terrain_fields(config: TerrainConfig, num_bodies: int) -> dict[str, tuple[tuple[int, ...], str]]:
    """The per-frame fields the gym's actor adds on terrain (none with the config's defaults)."""
    out: dict[str, tuple[tuple[int, ...], str]] = {}
    if config.contact_weight > 0:
        out["sim_contacts"] = ((num_bodies,), "bool")
    if config.contact_frames:
        out["kin_contacts"] = ((len(config.contact_frames), num_bodies), "bool")
    return out


class TerrainInputs(nn.Module):
    """The terrain inputs of one library's clips (its clip indices are the gym's ``clip``).

    A module so that ``.to(device)`` moves the terrains' tensors; it holds no weights and is never saved (a policy
    evaluated on other motions reads their terrains).

    Args:
        config: The ``terrain`` section.
        humanoid: The model (the bodies' collision geoms).
        library: The clips.
    """

    def __init__(self, config: TerrainConfig, humanoid: Humanoid, library: MotionLibrary) -> None:
        super().__init__()
        self.config, self.library = config, library
        self.terrains = ClipTerrains.of(library)
        self.geometry = BodyGeometry(humanoid)
        self.num_bodies = humanoid.num_bodies
        self.field = TerrainField(self.terrains)
        e = config.heightmap_extent
        offsets = np.zeros((0, 2)) if e is None else heightmap_offsets(e, config.heightmap_spacing)
        self.register_buffer("offsets", torch.as_tensor(offsets, dtype=torch.float32), persistent=False)

    @property
    def heightmap_size(self) -> int:
        """Width P of the heightmap (0: none)."""
        return int(self.offsets.shape[0])

    @property
    def policy_size(self) -> int:
        """Width of the policy's terrain inputs (:func:`policy_terrain_size`)."""
        return policy_terrain_size(self.config, self.num_bodies)

    def heightmap(self, state: BodyState, clip: Tensor) -> Tensor | None:
        """The heightmap around each state's root (m), differentiable in the root's position and heading; None when
        the config has none.

        Args:
            state: Leading shape (B,).
            clip: Clip of each state. Shape: (B,).

        Returns:
            Shape: (B, P).
        """
        if not self.heightmap_size:
            return None
        return heightmap(self.field, clip, state.pos[..., 0, :], state.rot[..., 0, :], self.offsets)

    def policy_inputs(self, heightmap: Tensor | None, kin_contacts: Tensor | None) -> Tensor | None:
        """The policy's terrain inputs: [heightmap, contact labels] (B, policy_size), or None when it reads none.

        Args:
            heightmap: :meth:`heightmap` of the policy's input state. Shape: (B, P).
            kin_contacts: The reference's contact labels (``kin_contacts``). Shape: (B, K, N), any dtype.
        """
        parts = [] if heightmap is None else [heightmap]
        if self.config.contact_frames:
            parts.append(kin_contacts.flatten(-2).to(torch.float32))
        return torch.cat(parts, dim=-1) if parts else None

    def reference_contacts(self, res: StepResult) -> np.ndarray | None:
        """The reference's contact labels at t + k dt for every k of ``contact_frames`` (None when there are none).

        Returns:
            Shape: (N characters, K, bodies), bool.
        """
        frames = self.config.contact_frames
        if not frames:
            return None
        labels = []
        for k in frames:
            ref = res.ref_next if k == 1 else self.library.query(res.clip, res.time + k * self.library.dt)
            labels.append(contact_labels(self.terrains, res.clip, self.geometry, ref.body_pos, ref.body_rot,
                                         self.config.contact_height))  # fmt: skip
        return np.stack(labels, axis=1) > 0.5

    def simulated_contacts(self, res: StepResult) -> np.ndarray:
        """Which bodies of ``res.sim`` touch their clip's ground (PPO's rule). Shape: (N characters, bodies), bool."""
        labels = contact_labels(self.terrains, res.clip, self.geometry, res.sim.body_pos, res.sim.body_rot,
                                self.config.contact_height)  # fmt: skip
        return labels > 0.5
