"""An exponential moving average of a network's weights (Polyak averaging), for evaluation.

After each optimiser step of the live network, every averaged parameter moves a fraction ``1 - decay`` of the way
to the live one: ``avg <- decay * avg + (1 - decay) * live``. Buffers (e.g. a normaliser's statistics) are copied,
not averaged. The average is never trained and never acts in the training gym; it only smooths the weights that
are evaluated and exported, which the last optimiser steps otherwise jolt from one evaluation to the next.
"""

from __future__ import annotations

import copy
from typing import Any

import torch


class WeightAverage:
    """The averaged copy of ``module``.

    Args:
        module: The live network; the average starts as an exact copy of it.
        decay: Share of the old average kept per update, in [0, 1) (0: the average is the live network).

    Attributes:
        module: The averaged network (eval mode, no gradients).
        updates: Updates applied so far.
    """

    def __init__(self, module: torch.nn.Module, decay: float) -> None:
        if not 0.0 <= decay < 1.0:
            raise ValueError(f"decay must be in [0, 1), got {decay}")
        self.decay = decay
        self.module = copy.deepcopy(module).eval()
        for p in self.module.parameters():
            p.requires_grad_(False)
        self.updates = 0

    @torch.no_grad()
    def update(self, live: torch.nn.Module) -> None:
        """Moves the average towards ``live`` (call after each optimiser step of ``live``)."""
        for avg, new in zip(self.module.parameters(), live.parameters(), strict=True):
            avg.lerp_(new.detach(), 1.0 - self.decay)
        for avg, new in zip(self.module.buffers(), live.buffers(), strict=True):
            avg.copy_(new)
        self.updates += 1

    def state_dict(self) -> dict[str, Any]:
        return {"module": self.module.state_dict(), "updates": self.updates}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.module.load_state_dict(state["module"])
        self.updates = int(state["updates"])
