"""SAMCON's search and cost: the kept samples are the cheapest, the chosen trajectory replays bit-exactly."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.character.kinematics import ForwardKinematics
from common.motion.dataset import load_motions
from common.train.evaluate import EvalConfig, evaluate
from samcon.config import CostConfig, FeedbackConfig, SearchConfig
from samcon.cost import feedback_features, tracking_cost
from samcon.feedback import ClipPlan, FeedbackPolicy, open_loop_policy
from samcon.search import reference_frames, replay, samcon
from samcon.track import fit_policies


@pytest.fixture(scope="module")
def walk() -> tuple[Humanoid, object]:
    humanoid = Humanoid()
    return humanoid, load_motions(["walk"], humanoid)


def test_cost_of_a_shifted_character_is_its_root_term(walk) -> None:
    humanoid, library = walk
    ref = library.query(np.array([0]), np.array([0.3]))
    sim = ref[np.array([0])]
    sim.body_pos = ref.body_pos + np.array([0.1, 0.0, 0.0])  # every body 10 cm along x
    cost, terms = tracking_cost(humanoid, CostConfig(), sim, ref)
    # Only the root position differs (0.1^2 m^2, weight 100); relative, balance and pose terms are 0.
    np.testing.assert_allclose(terms["root_pos"], [0.01])
    for name in ("pose", "root_rot", "end_effector", "balance", "root_vel"):
        np.testing.assert_allclose(terms[name], [0.0], atol=1e-12)
    np.testing.assert_allclose(cost, [1.0])
    np.testing.assert_allclose(feedback_features(humanoid, sim, ref), 0.0, atol=1e-12)
    sim.body_pos[:, humanoid.head_index, 2] -= 0.3  # the head 30 cm low: a fall by the evaluator's rule
    cost, terms = tracking_cost(humanoid, CostConfig(), sim, ref)
    assert terms["fallen"].all() and cost[0] > 1000.0


def _per_frame_costs(humanoid: Humanoid, library, start: np.ndarray, offsets: np.ndarray, frames: int,
                     cost_cfg: CostConfig) -> np.ndarray:  # fmt: skip
    """Each offset played alone from ``start`` on the reference's next-frame angles, scored frame by frame,
    independently of the search's batch. Shape: (len(offsets), frames)."""
    ref = reference_frames(library, 0, frames)
    fk = ForwardKinematics(humanoid)
    out = []
    for offset in offsets:
        states = replay(humanoid, start, ref.qpos[1 : frames + 1, humanoid.hinge_qpos] + offset)
        now = fk(states[:, 1 : 1 + humanoid.nq], states[:, 1 + humanoid.nq : 1 + humanoid.nq + humanoid.nv])
        out.append(tracking_cost(humanoid, cost_cfg, now, ref[np.arange(1, frames + 1)])[0])
    fk.close()
    return np.array(out)


def test_kept_are_the_cheapest_and_the_trajectory_replays_bit_exactly(walk) -> None:
    humanoid, library = walk
    search = SearchConfig(segment_frames=4, samples=6, iterations=1, keep=3, elite=2, sigma_init=0.2)
    cost_cfg = CostConfig()
    traj = samcon(humanoid, library, 0, 4, search, cost_cfg, np.random.default_rng(3))
    # The same draws, each candidate simulated alone and scored frame by frame, independently of the batch.
    offsets = 0.2 * np.random.default_rng(3).standard_normal((6, humanoid.nu))
    costs = _per_frame_costs(humanoid, library, traj.start_state, offsets, 4, cost_cfg).mean(axis=1)
    np.testing.assert_allclose(traj.kept_cost[0], np.sort(costs)[:3], rtol=1e-12)
    best = int(np.argmin(costs))
    np.testing.assert_array_equal(traj.offsets[0], offsets[best])
    assert traj.segment_cost[0] == traj.kept_cost[0][0]
    assert traj.samples == 6


def test_two_segments_trace_back_and_replay_bit_exactly(walk) -> None:
    humanoid, library = walk
    search = SearchConfig(segment_frames=3, samples=8, iterations=2, keep=3, elite=4)
    traj = samcon(humanoid, library, 0, 7, search, CostConfig(), np.random.default_rng(0))
    np.testing.assert_array_equal(traj.bounds, [0, 3, 6, 7])
    assert traj.targets.shape == (7, humanoid.nu) and traj.samples == 8 * 2 * 3
    states = replay(humanoid, traj.start_state, traj.targets)
    np.testing.assert_array_equal(states[traj.bounds[1:] - 1], traj.end_states)
    # The targets are the reference's next-frame angles plus the segment's offset.
    ref = reference_frames(library, 0, 7)
    np.testing.assert_allclose(traj.targets[3:6] - ref.qpos[4:7, humanoid.hinge_qpos], traj.offsets[[1, 1, 1]],
                               atol=1e-12)  # fmt: skip


def test_path_anchored_feedback_replays_the_open_loop_trajectory(walk) -> None:
    humanoid, library = walk
    search = SearchConfig(segment_frames=3, samples=8, iterations=2, keep=3, elite=4)
    traj = samcon(humanoid, library, 0, 9, search, CostConfig(), np.random.default_rng(1), regression_samples=6)
    gain, bias = fit_policies(traj, FeedbackConfig(samples=6, anchor="path"))
    assert np.abs(gain).max() > 0  # real feedback from the second segment on, not a disguised open loop
    plans = {"walk": ClipPlan(traj.targets, traj.bounds, gain, bias)}
    protocol = EvalConfig(starts_per_clip=1, max_frames=9, threads=1)
    open_loop = evaluate(open_loop_policy(plans, library, humanoid), library, humanoid, protocol)
    feedback = evaluate(FeedbackPolicy(plans, library, humanoid), library, humanoid, protocol)
    # On the trajectory's own states s*, M s + b = a*: the same targets up to rounding, the same error.
    assert feedback.overall["mpjpe_g"] == pytest.approx(open_loop.overall["mpjpe_g"], rel=1e-6)
    # The open-loop policy under the evaluator is the search's own trajectory, bit for bit, hence its error.
    states = replay(humanoid, traj.start_state, traj.targets)
    fk = ForwardKinematics(humanoid)
    sim = fk(states[:, 1 : 1 + humanoid.nq], states[:, 1 + humanoid.nq : 1 + humanoid.nq + humanoid.nv])
    fk.close()
    ref = reference_frames(library, 0, 9)
    expected = np.mean(1000 * np.linalg.norm(sim.body_pos - ref.body_pos[1:], axis=-1).mean(axis=-1))
    assert open_loop.overall["mpjpe_g"] == pytest.approx(expected, rel=1e-12)


def test_fresh_candidates_feed_the_regression_but_are_never_kept(walk) -> None:
    humanoid, library = walk
    search = SearchConfig(segment_frames=3, samples=8, iterations=1, keep=3, elite=2)
    traj = samcon(humanoid, library, 0, 6, search, CostConfig(), np.random.default_rng(2), regression_samples=8,
                  fresh_share=0.5)  # fmt: skip
    # Continuity: the chosen path is simulated from the start state only, never from a reference state.
    states = replay(humanoid, traj.start_state, traj.targets)
    np.testing.assert_array_equal(states[traj.bounds[1:] - 1], traj.end_states)
    # In the second segment, half the regression rows start on the reference (features ~0), half on kept states.
    fresh = np.abs(traj.features[1]).max(axis=1) < 1e-9
    assert fresh.sum() == 4 and (~fresh).sum() == 4


def test_a_fallen_segment_is_searched_again_with_more_rounds(walk) -> None:
    humanoid, library = walk
    search = SearchConfig(segment_frames=3, samples=6, iterations=1, keep=2, elite=2, backtrack_segments=1,
                          max_backtracks=2, max_rounds=3)  # fmt: skip
    # A head rule of 0 m: every sample "falls" at every frame, so every segment asks for a backtrack.
    always = CostConfig(fall_head_error=0.0)
    lines = []
    traj = samcon(humanoid, library, 0, 6, search, always, np.random.default_rng(4),
                  progress=lambda k, s, c, t, back: lines.append((k, back)))  # fmt: skip
    # Segment 1 (k = 0) falls twice and has no segment before it: searched with 1, 2, then 3 rounds (kept, the
    # backtracks used up); segment 2 keeps its fall with 1 round.
    assert traj.backtracks == 2
    assert lines == [(0, 0), (0, 0), (0, None), (1, None)]
    assert traj.samples == 6 * (1 + 2 + 3) + 6 * 1
    assert len(traj.kept_cost[0]) == 2 and traj.segment_terms["fallen"].min() > 0
    states = replay(humanoid, traj.start_state, traj.targets)
    np.testing.assert_array_equal(states[traj.bounds[1:] - 1], traj.end_states)
    # Where nothing falls, backtracking changes nothing: the same draws, the same trajectory.
    never = CostConfig(fall_head_error=10.0)
    on = samcon(humanoid, library, 0, 6, search, never, np.random.default_rng(5))
    off = samcon(humanoid, library, 0, 6, replace(search, backtrack_segments=0), never, np.random.default_rng(5))
    assert on.backtracks == off.backtracks == 0
    np.testing.assert_array_equal(on.targets, off.targets)


def test_a_backtrack_widens_the_sampling_of_the_segments_searched_again(walk) -> None:
    humanoid, library = walk
    # One round per search, so that the last search of segment 1 draws mean 0 + sigma * z: the same z either way.
    search = SearchConfig(segment_frames=3, samples=6, iterations=1, keep=2, elite=2, backtrack_segments=1,
                          max_backtracks=2, max_rounds=1, sigma_init=0.15)  # fmt: skip
    always = CostConfig(fall_head_error=0.0)
    runs = [samcon(humanoid, library, 0, 6, s, always, np.random.default_rng(4), regression_samples=6)
            for s in (search, replace(search, backtrack_sigma=0.5))]  # fmt: skip
    narrow, wide = (np.array(sorted(map(tuple, r.actions[0]))) for r in runs)
    assert runs[0].backtracks == runs[1].backtracks == 2
    np.testing.assert_allclose(wide, np.array(sorted(map(tuple, narrow * (0.5 / 0.15)))), rtol=1e-12)
    # A width below sigma_init never narrows it.
    low = samcon(humanoid, library, 0, 6, replace(search, backtrack_sigma=0.01), always, np.random.default_rng(4),
                 regression_samples=6)  # fmt: skip
    np.testing.assert_array_equal(low.targets, runs[0].targets)


def test_a_search_from_a_later_frame_starts_on_that_reference_state_and_replays(walk) -> None:
    humanoid, library = walk
    search = SearchConfig(segment_frames=3, samples=6, iterations=1, keep=2, elite=2)
    later = samcon(humanoid, library, 0, 12, search, CostConfig(), np.random.default_rng(6), start_frame=6)
    np.testing.assert_array_equal(later.bounds, [6, 9, 12])
    assert later.frames == 6 and later.targets.shape == (6, humanoid.nu) and len(later.features) == 2
    # The start is the gym's reset to frame 6's time: the reference pose of frame 6.
    ref = reference_frames(library, 0, 12)
    np.testing.assert_allclose(later.start_state[1 : 1 + humanoid.nq], ref.qpos[6], atol=1e-12)
    np.testing.assert_allclose(later.targets[:3] - ref.qpos[7:10, humanoid.hinge_qpos], later.offsets[[0, 0, 0]],
                               atol=1e-12)  # fmt: skip
    states = replay(humanoid, later.start_state, later.targets)
    np.testing.assert_array_equal(states[later.bounds[1:] - later.bounds[0] - 1], later.end_states)
    # Its first segment's samples all start on the reference itself: feedback features 0.
    np.testing.assert_allclose(later.features[0], 0.0, atol=1e-9)
    with pytest.raises(ValueError, match="multiple of segment_frames"):
        samcon(humanoid, library, 0, 12, search, CostConfig(), np.random.default_rng(6), start_frame=4)


def test_the_look_ahead_cost_is_the_held_offset_played_on(walk) -> None:
    humanoid, library = walk
    search = SearchConfig(segment_frames=3, samples=4, iterations=1, keep=4, elite=2, sigma_init=0.2,
                          lookahead_frames=3, lookahead_weight=0.5)  # fmt: skip
    cost_cfg = CostConfig()
    traj = samcon(humanoid, library, 0, 3, search, cost_cfg, np.random.default_rng(7))
    offsets = 0.2 * np.random.default_rng(7).standard_normal((4, humanoid.nu))
    # Each candidate alone: 3 frames of the segment, then 3 more with the same offset.
    per_frame = _per_frame_costs(humanoid, library, traj.start_state, offsets, 6, cost_cfg)
    costs = per_frame[:, :3].mean(axis=1) + 0.5 * per_frame[:, 3:].mean(axis=1)
    np.testing.assert_allclose(traj.kept_cost[0], np.sort(costs), rtol=1e-12)
    # The kept state is the segment's end, not the look-ahead's.
    np.testing.assert_array_equal(replay(humanoid, traj.start_state, traj.targets)[-1], traj.end_states[0])
