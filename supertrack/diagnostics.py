"""Open-loop accuracy of the world model against the real simulator, per prediction horizon.

W is rolled out from recorded states with the recorded PD targets (as in its training) and compared with the frames
the simulator produced. Held-back characters' frames measure generalisation; the training buffer's the fit.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from common.maths import torch_rotations as R
from common.sim.buffer import CyclicBuffer
from supertrack.models import WorldModel
from supertrack.rollout import world_model_rollout
from supertrack.state import BodyState
from supertrack.terrain import TerrainInputs


@torch.no_grad()
def open_loop_errors(world_model: WorldModel, buffer: CyclicBuffer, horizons: Sequence[int], batch: int,
                     rng: np.random.Generator, prefix: str = "world_model/",
                     terrain: TerrainInputs | None = None) -> dict[str, float]:  # fmt: skip
    """Mean per-body errors of W's open-loop prediction h frames ahead, for every horizon h.

    Args:
        world_model: W.
        buffer: Frames with fields ``sim`` (N, 13) and ``target_rot`` (J, 4).
        horizons: Frames ahead, e.g. (1, 8, 32).
        batch: Windows measured.
        rng: Draws the windows.
        prefix: Key prefix.
        terrain: The terrain inputs, when W reads a heightmap (sampled on each window's ``clip``).

    Returns:
        ``{prefix}pos_err_h{h}`` (m), ``vel_err_h{h}`` (m/s), ``rot_err_h{h}`` (rad, geodesic), ``angvel_err_h{h}``
        (rad/s); empty when the buffer holds no window of ``max(horizons) + 1`` frames yet.
    """
    length = max(horizons) + 1
    if length > buffer.rows or not buffer.valid_window_starts(length).any():
        return {}
    device = next(world_model.parameters()).device
    windows = buffer.sample_windows(batch, length, rng)
    sim = BodyState.unpack(torch.as_tensor(windows["sim"], device=device))
    clip = None if terrain is None else torch.as_tensor(windows["clip"][:, 0], device=device)
    predicted = world_model_rollout(world_model, sim, torch.as_tensor(windows["target_rot"], device=device),
                                    terrain=terrain, clip=clip)  # fmt: skip
    out: dict[str, float] = {}
    for h in horizons:
        p, s = predicted.time(h - 1), sim.time(h)
        out[f"{prefix}pos_err_h{h}"] = float((p.pos - s.pos).norm(dim=-1).mean())
        out[f"{prefix}vel_err_h{h}"] = float((p.vel - s.vel).norm(dim=-1).mean())
        out[f"{prefix}rot_err_h{h}"] = float(R.quat_geodesic_angle(p.rot, s.rot).mean())
        out[f"{prefix}angvel_err_h{h}"] = float((p.angvel - s.angvel).norm(dim=-1).mean())
    return out
