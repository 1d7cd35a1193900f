"""The weight average against hand-computed values."""

from __future__ import annotations

import pytest
import torch

from common.train.averaging import WeightAverage


class _Net(torch.nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.w = torch.nn.Parameter(torch.tensor([1.0, -2.0]))
        self.register_buffer("stat", torch.tensor([5.0]))


def test_each_update_moves_the_average_a_fraction_one_minus_decay_towards_the_live_weights() -> None:
    live = _Net()
    avg = WeightAverage(live, decay=0.75)
    with torch.no_grad():
        live.w.copy_(torch.tensor([3.0, 2.0]))
        live.stat.fill_(7.0)
    avg.update(live)
    # 0.75 * [1, -2] + 0.25 * [3, 2] = [1.5, -1.0]; the buffer is copied, not averaged.
    torch.testing.assert_close(avg.module.w, torch.tensor([1.5, -1.0]))
    torch.testing.assert_close(avg.module.stat, torch.tensor([7.0]))
    avg.update(live)
    # 0.75 * [1.5, -1] + 0.25 * [3, 2] = [1.875, -0.25]
    torch.testing.assert_close(avg.module.w, torch.tensor([1.875, -0.25]))
    assert avg.updates == 2
    assert not avg.module.w.requires_grad and not avg.module.training
    torch.testing.assert_close(live.w, torch.tensor([3.0, 2.0]))  # the live network is not touched


def test_decay_zero_follows_the_live_weights_and_state_round_trips() -> None:
    live = _Net()
    avg = WeightAverage(live, decay=0.0)
    with torch.no_grad():
        live.w.mul_(4.0)
    avg.update(live)
    torch.testing.assert_close(avg.module.w, torch.tensor([4.0, -8.0]))
    other = WeightAverage(_Net(), decay=0.0)
    other.load_state_dict(avg.state_dict())
    torch.testing.assert_close(other.module.w, torch.tensor([4.0, -8.0]))
    assert other.updates == 1


@pytest.mark.parametrize("decay", [-0.1, 1.0, 1.5])
def test_a_decay_outside_zero_one_is_refused(decay: float) -> None:
    with pytest.raises(ValueError, match=r"decay must be in \[0, 1\)"):
        WeightAverage(_Net(), decay)
