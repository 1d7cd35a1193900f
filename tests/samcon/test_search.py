"""SAMCON's search and cost: the kept samples are the cheapest, the chosen trajectory replays bit-exactly."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.character.kinematics import ForwardKinematics
from common.evaluation.evaluate import EvalConfig, evaluate
from common.motion.dataset import load_motions
from samcon.config import CostConfig, FeedbackConfig, SearchConfig
from samcon.cost import feedback_features, tracking_cost
from samcon.feedback import ClipPlan, FeedbackPolicy, open_loop_policy
from samcon.search import SearchAbandoned, cycle_frames, reference_frames, replay, samcon, segment_bounds
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
    # Only the root position differs (0.1^2 m^2, weight 100); relative, balance and pose terms are 0. Every body's
    # world error is 0.1 m too (the body_pos term, off by default).
    np.testing.assert_allclose(terms["root_pos"], [0.01])
    np.testing.assert_allclose(terms["body_pos"], [0.01])
    for name in ("pose", "root_rot", "end_effector", "balance", "root_vel"):
        np.testing.assert_allclose(terms[name], [0.0], atol=1e-12)
    np.testing.assert_allclose(cost, [1.0])
    np.testing.assert_allclose(tracking_cost(humanoid, CostConfig(body_pos=50.0), sim, ref)[0], [1.5])
    # One body 0.3 m off alone: the mean over the 15 bodies of its squared error.
    one = ref[np.array([0])]
    one.body_pos = ref.body_pos.copy()
    one.body_pos[:, 5, 1] += 0.3
    np.testing.assert_allclose(tracking_cost(humanoid, CostConfig(), one, ref)[1]["body_pos"], [0.09 / 15])
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


def test_a_search_around_a_centre_path_offsets_that_path(walk) -> None:
    """The reference's own next-frame angles as the centre give the plain search bit for bit; another centre path
    is what the offsets are on, and the result replays bit-exactly through the kept end states."""
    humanoid, library = walk
    search = SearchConfig(segment_frames=3, samples=8, iterations=2, keep=3, elite=4, lookahead_frames=3)
    ref = reference_frames(library, 0, 7 + 3)
    plain = samcon(humanoid, library, 0, 7, search, CostConfig(), np.random.default_rng(4))
    same = samcon(humanoid, library, 0, 7, search, CostConfig(), np.random.default_rng(4),
                  centre=ref.qpos[1:8, humanoid.hinge_qpos])  # fmt: skip
    np.testing.assert_array_equal(same.targets, plain.targets)
    np.testing.assert_array_equal(same.segment_cost, plain.segment_cost)
    # A centre bent by 0.05 rad per frame index on every hinge (7 frames): the chosen targets are it plus the
    # segment offsets, and a centre shorter than the search leaves the later frames on the reference.
    bend = ref.qpos[1:8, humanoid.hinge_qpos] + 0.05 * np.arange(7)[:, None]
    bent = samcon(humanoid, library, 0, 7, search, CostConfig(), np.random.default_rng(4), centre=bend)
    np.testing.assert_allclose(bent.targets - bend, np.repeat(bent.offsets, [3, 3, 1], axis=0), atol=1e-12)
    assert not np.array_equal(bent.targets, plain.targets)
    states = replay(humanoid, bent.start_state, bent.targets)
    np.testing.assert_array_equal(states[bent.bounds[1:] - 1], bent.end_states)
    short = samcon(humanoid, library, 0, 7, search, CostConfig(), np.random.default_rng(4), centre=bend[:3])
    np.testing.assert_allclose(short.targets[:3] - bend[:3], short.offsets[[0, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(short.targets[3:] - ref.qpos[4:8, humanoid.hinge_qpos],
                               np.repeat(short.offsets[1:], [3, 1], axis=0), atol=1e-12)  # fmt: skip


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
    with pytest.raises(ValueError, match="segment starts of the grid"):
        samcon(humanoid, library, 0, 12, search, CostConfig(), np.random.default_rng(6), start_frame=4)
    # A search may stop at a segment start before the last frame: the same grid, fewer segments.
    short = samcon(humanoid, library, 0, 12, search, CostConfig(), np.random.default_rng(6), start_frame=3,
                   end_frame=9)  # fmt: skip
    np.testing.assert_array_equal(short.bounds, [3, 6, 9])
    assert short.targets.shape == (6, humanoid.nu)
    for end in (8, 3):
        with pytest.raises(ValueError, match="segment starts of the grid"):
            samcon(humanoid, library, 0, 12, search, CostConfig(), np.random.default_rng(6), start_frame=3,
                   end_frame=end)  # fmt: skip


def test_aligned_segments_cut_every_cycle_at_the_same_phases() -> None:
    humanoid = Humanoid()
    library = load_motions(["walk", "kick"], humanoid)
    assert cycle_frames(library, 0) == 76 and cycle_frames(library, 1) == 0
    # Walk's cycle of 76 frames in round(76 / 6) = 13 segments at round(76 j / 13): 0, 5.85, 11.7, 17.5, 23.4, ...
    phases = [0, 6, 12, 18, 23, 29, 35, 41, 47, 53, 58, 64, 70]
    expected = [*phases, *(76 + p for p in phases), 152, 158, 160]
    np.testing.assert_array_equal(segment_bounds(library, 0, 160, 6, align_cycle=True), expected)
    np.testing.assert_array_equal(segment_bounds(library, 0, 20, 6), [0, 6, 12, 18, 20])
    # A one-shot clip has no cycle: every 6 frames either way.
    np.testing.assert_array_equal(segment_bounds(library, 1, 20, 6, align_cycle=True), [0, 6, 12, 18, 20])


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


def test_the_last_round_draws_narrower_around_the_same_mean(walk) -> None:
    humanoid, library = walk
    search = SearchConfig(segment_frames=3, samples=6, iterations=2, keep=2, elite=2, sigma_init=0.2)
    runs = [samcon(humanoid, library, 0, 3, s, CostConfig(), np.random.default_rng(8), regression_samples=12)
            for s in (search, replace(search, final_scale=0.5))]  # fmt: skip
    wide, narrow = (set(map(tuple, r.actions[0])) for r in runs)
    assert len(wide & narrow) == 6  # the first round's draws are the same
    # The second round's: mean + sigma z against mean + 0.5 sigma z, the same z: half the spread, in the same order.
    w, n = (np.array(sorted(rows - (wide & narrow))) for rows in (wide, narrow))
    np.testing.assert_allclose(n - n.mean(axis=0), 0.5 * (w - w.mean(axis=0)), atol=1e-12)


def test_per_state_regression_takes_the_cheapest_candidate_of_every_start_state(walk) -> None:
    humanoid, library = walk
    search = SearchConfig(segment_frames=3, samples=8, iterations=2, keep=2, elite=2, sigma_init=0.2)
    every, per_state = (samcon(humanoid, library, 0, 6, search, CostConfig(), np.random.default_rng(9),
                               regression_samples=16, regression=mode)
                        for mode in ("cheapest", "per_state"))  # fmt: skip
    np.testing.assert_array_equal(every.targets, per_state.targets)  # the regression never changes the search
    # Segment 1 starts from the 2 kept states: one sample each, the first (cheapest) of that state in the full list.
    states = np.unique(every.features[1], axis=0)
    assert len(states) == 2 and per_state.features[1].shape == (2, every.features[1].shape[1])
    for s, a in zip(per_state.features[1], per_state.actions[1], strict=True):
        first = int(np.flatnonzero((every.features[1] == s).all(axis=1))[0])
        np.testing.assert_array_equal(a, every.actions[1][first])
    assert len(per_state.features[0]) == 1  # segment 0 has one start state, the clip's


def test_perturbed_fresh_states_differ_in_root_velocity_alone(walk) -> None:
    humanoid, library = walk
    search = SearchConfig(segment_frames=3, samples=12, iterations=2, keep=2, elite=2, sigma_init=0.2)
    traj = samcon(humanoid, library, 0, 3, search, CostConfig(), np.random.default_rng(10), regression="per_state",
                  fresh_share=0.5, fresh_states=3, fresh_noise=(0.3, 0.5))  # fmt: skip
    # Segment 0: the clip's start state and 3 perturbed copies of it (the start is the reference: features 0).
    feats = traj.features[0]
    assert feats.shape == (4, 16)
    assert (np.abs(feats) < 1e-9).all(axis=1).sum() == 1
    velocity = slice(4, 10)  # root_vel_xyz and root_ang_vel_xyz, in FEATURE_NAMES' order
    np.testing.assert_allclose(np.delete(feats, velocity, axis=1), 0.0, atol=1e-9)
    assert (np.abs(feats[:, velocity]).max(axis=1) > 1e-3).sum() == 3
    # Without noise every fresh candidate starts on the reference: one fresh state, the same as the clip's start.
    plain = samcon(humanoid, library, 0, 3, search, CostConfig(), np.random.default_rng(10), regression="per_state",
                   fresh_share=0.5, fresh_states=3)  # fmt: skip
    assert len(plain.features[0]) == 2


def test_a_search_is_abandoned_once_its_cheapest_kept_path_costs_more_than_the_limit(walk) -> None:
    humanoid, library = walk
    search = SearchConfig(segment_frames=3, samples=6, iterations=1, keep=2, elite=2, sigma_init=0.2)
    full = samcon(humanoid, library, 0, 9, search, CostConfig(), np.random.default_rng(11))
    total = float(full.segment_cost.sum())
    # Above the total: nothing changes, draw for draw.
    loose = samcon(humanoid, library, 0, 9, search, CostConfig(), np.random.default_rng(11), cost_limit=total + 1e-9)
    np.testing.assert_array_equal(loose.targets, full.targets)
    # Below the cost of the first segment's cheapest sample: stopped there, its samples counted.
    with pytest.raises(SearchAbandoned, match="abandoned at segment 1") as info:
        samcon(humanoid, library, 0, 9, search, CostConfig(), np.random.default_rng(11),
               cost_limit=0.5 * float(full.kept_cost[0][0]))  # fmt: skip
    assert info.value.samples == 6 and info.value.seconds > 0
