"""The root couple as a control of the polish (studies.samcon.couple): the path and couple it returns replay to the
cost it reports, a cheap couple undoes a push and a dear one is taken away, and what it cannot combine with."""

from __future__ import annotations

import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.motion.dataset import load_motions
from samcon.config import LqrConfig, PolishConfig
from samcon.lqr import nominal_states
from samcon.polish import BodyCost
from samcon.search import reference_frames, start_state
from studies.samcon.couple import Couple, polish_couple


@pytest.fixture(scope="module")
def walk() -> tuple[Humanoid, object]:
    humanoid = Humanoid()
    return humanoid, load_motions(["walk"], humanoid)


@pytest.mark.parametrize("weight, tracked", [(1e-6, False), (1.0, False), (1e-6, True), (1.0, True)])
def test_a_couple_polished_as_a_control_replays_and_a_dear_one_is_taken_away(walk, weight: float,
                                                                             tracked: bool) -> None:  # fmt: skip
    """From walk's own targets with a yaw couple of 20 N m on the root (a push it does not have), the polish with
    the couple as three more controls: the targets and couple it returns replay (the couple held) to the cost it
    reports; cheap (1e-6 per (N m)^2), the couple is what it turns to undo the push (the body error falls, the yaw
    couple shrinks); dear (1 per (N m)^2, 400 a frame at the start), it is taken away. ``tracked``: the frames no
    window has changed yet start from the path's LQR, the couple one of its controls."""
    humanoid, library = walk
    frames = 24
    ref = reference_frames(library, 0, frames)
    ref_targets = ref.qpos[1:, humanoid.hinge_qpos]
    start = start_state(library, humanoid, 0)
    push = Couple(np.tile([0.0, 0.0, 20.0], (frames, 1)), weight)
    cfg = PolishConfig(iterations=4, window=16, stride=8, lookahead=4, whole_iterations=2)
    targets, summary = polish_couple(humanoid, start, ref_targets, ref, ref_targets, cfg, 0.25, push,
                                     lqr=LqrConfig() if tracked else None)  # fmt: skip
    values = summary["couple"]
    assert summary["kept"] and summary["cost_after"] < summary["cost_before"] and values.shape == (frames, 3)
    cost = BodyCost(humanoid, cfg, ref, ref_targets, 0.25)
    try:
        replayed = cost.path_cost(nominal_states(humanoid, start, targets, Couple(values, weight).law(humanoid.nv)),
                                  targets, 0)  # fmt: skip
        without = cost.path_cost(nominal_states(humanoid, start, targets), targets, 0)
    finally:
        cost.close()
    assert replayed.total + weight * np.sum(values**2) == pytest.approx(summary["cost_after"], rel=1e-12)
    assert without.total != replayed.total  # the couple is applied, not ignored
    if weight < 1e-3:
        assert summary["body_rms_mm_after"] < 0.2 * summary["body_rms_mm_before"]  # 94 -> 3 mm
        assert np.abs(values[:, 2]).mean() < 8.0  # most of the push undone (4 N m left on average)
    else:
        assert np.sum(values**2) < 0.01 * np.sum(push.values**2)


def test_a_couple_as_a_control_refuses_a_look_ahead_played_by_the_lqr(walk) -> None:
    """The LQR that would play a window's look-ahead has no couple among its controls."""
    humanoid, library = walk
    ref = reference_frames(library, 0, 8)
    ref_targets = ref.qpos[1:, humanoid.hinge_qpos]
    start, couple = start_state(library, humanoid, 0), Couple(np.zeros((8, 3)), 1.0)
    cfg = PolishConfig(iterations=1, window=4, stride=2, follow=True)
    with pytest.raises(ValueError, match="root couple"):
        polish_couple(humanoid, start, ref_targets, ref, ref_targets, cfg, 0.25, couple)
