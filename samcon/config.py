"""The config of ``track-samcon``: frozen dataclasses loaded with :func:`common.config.load_config`.

The section names ``train`` and ``gym`` follow the learners' configs so that the report reads a SAMCON run's
motions, evaluation protocol and physics the same way (:mod:`report.runs`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

from common.character.humanoid import PhysicsConfig
from common.evaluation.evaluate import EvalConfig


@dataclass(frozen=True)
class TrackConfig:
    """What to track and how the result is judged.

    Attributes:
        motions: Motion specs (see :func:`common.motion.dataset.resolve_clips`).
        seed: Seed of the sampling.
        max_frames: Control steps tracked from each clip's start: loop clips this many, one-shot clips to their last
            frame if sooner (the shared evaluator's horizon).
        threads: MuJoCo rollout threads.
        eval: The protocol the linear feedback policy is judged under (the open-loop trajectory is judged from the
            clip's start only, with one episode per clip).
    """

    motions: list[str] = field(default_factory=lambda: ["walk"])
    seed: int = 0
    max_frames: int = 512
    threads: int = 1
    eval: EvalConfig = field(default_factory=EvalConfig)

    def __post_init__(self) -> None:
        if self.max_frames < 1:
            raise ValueError(f"train.max_frames must be >= 1, got {self.max_frames}")


@dataclass(frozen=True)
class SimSection:
    """The simulation (named ``gym`` like the learners' section).

    Attributes:
        physics: Rates and solver settings; the same as the learners' for the comparison to mean anything.
        max_speed: A generalised velocity above this (m/s, rad/s) counts as a blown-up simulation.
    """

    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    max_speed: float = 1000.0


@dataclass(frozen=True)
class SearchConfig:
    """The sampling search (SAMCON with the 2015 per-segment distribution update).

    Attributes:
        segment_frames: Control steps per segment (6 at 60 Hz = 0.1 s, Liu et al. 2010).
        samples: Candidates simulated per iteration of a segment.
        iterations: Sampling rounds per segment; after each, the offset distribution moves to its elite.
        keep: States kept at the end of a segment (the starts of the next one).
        elite: Best candidates of a round that set the next round's distribution.
        sigma_init: Initial standard deviation of the PD-target offsets (rad).
        sigma_min: Floor of that deviation (rad), so that a segment never stops exploring.
        sigma_rate: Learning rate of the deviation towards the elite's (CMA's c_sigma role); 1 copies it.
        mean_carry: Share of the previous segment's final mean that starts the next one (offsets that hold a
            joint against gravity persist from segment to segment).
        backtrack_segments: When even the cheapest kept sample of a segment has fallen (the evaluator's head rule),
            the search goes back this many segments and searches them again, each with ``iterations`` more rounds
            than the last time it was searched (Liu et al. 2010 restart a failed segment from an earlier one too):
            the greedy one-segment choice cannot see a fall coming, while a wider search a few segments earlier
            often avoids it. 0: never.
        max_backtracks: Backtracks per clip at most; past them a fall is kept and the search goes on.
        max_rounds: Rounds of one segment at most, however often it is searched again.
        backtrack_sigma: ``sigma_init`` (rad) of the segments searched again after a backtrack, if wider than their
            own; None: unchanged. A narrow ``sigma_init`` tracks the pose closer (walk: 45 against 89 mm MPJPE-g at
            0.1 against 0.3) but cannot find a take-off (jump fell at 0.1), so the width grows only where it fell.
        lookahead_frames: Frames each candidate plays on past its segment, holding its offset, whose mean cost
            (times ``lookahead_weight``) joins its own: the greedy choice then sees a little of what a state leads
            to. 0: off (the plain SAMCON cost).
        lookahead_weight: Weight of that look-ahead cost.
        align_cycle: For a loop clip, cut each cycle into ``round(cycle / segment_frames)`` segments of whole frames
            (5 or 6 on walk's 76-frame cycle), the same in every cycle, instead of ``segment_frames`` from frame 0
            on, which falls out of step with the cycle: then segment ``k`` of every cycle starts at the same phase,
            and the feedback policy can be indexed by phase (``feedback.index: phase``). One-shot clips: unchanged.
        final_scale: The last round of a segment (of two or more) draws with this times the deviation reached: after
            the wide rounds have found where the offsets lie, samples close to the elite's mean, which carry less of
            the draws' noise into the pose, compete with them for the kept states. 1: off.
        sigma_choices: Search each clip once with each of these ``sigma_init`` (rad) and keep the trajectory of the
            lowest total cost (a fall costs ``cost.fall_penalty`` per frame, so a path that stands wins): a narrow
            width tracks slow clips closer (walk 45 against 89 mm at 0.1 against 0.3) and loses the dynamic ones
            (run, jump), which the wide one tracks; the search picks per clip. Minutes and samples are those of all
            the searches. Each search after the first stops once its cheapest kept path already costs more than
            the best so far, so the robust width goes first. Empty: ``sigma_init`` alone.
    """

    segment_frames: int = 6
    samples: int = 300
    iterations: int = 2
    keep: int = 40
    elite: int = 20
    sigma_init: float = 0.15
    sigma_min: float = 0.01
    sigma_rate: float = 0.5
    mean_carry: float = 0.5
    backtrack_segments: int = 3
    max_backtracks: int = 20
    max_rounds: int = 16
    backtrack_sigma: float | None = None
    lookahead_frames: int = 0
    lookahead_weight: float = 1.0
    align_cycle: bool = False
    final_scale: float = 1.0
    sigma_choices: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if min(self.lookahead_frames, self.lookahead_weight) < 0:
            raise ValueError("search: need lookahead_frames >= 0 and lookahead_weight >= 0")
        if min(self.backtrack_segments, self.max_backtracks) < 0 or self.max_rounds < self.iterations:
            raise ValueError("search: need backtrack_segments >= 0, max_backtracks >= 0, max_rounds >= iterations")
        if min(self.segment_frames, self.samples, self.iterations, self.keep, self.elite) < 1:
            raise ValueError("search: segment_frames, samples, iterations, keep and elite must be >= 1")
        if self.keep > self.samples * self.iterations or self.elite > self.samples:
            raise ValueError("search: keep must be <= samples * iterations and elite <= samples")
        if any(not s > 0 for s in self.sigma_choices):
            raise ValueError(f"search.sigma_choices must all be > 0, got {list(self.sigma_choices)}")
        if not 0 < self.final_scale <= 1:
            raise ValueError(f"search.final_scale must lie in (0, 1], got {self.final_scale}")
        if self.backtrack_sigma is not None and not self.backtrack_sigma > 0:
            raise ValueError(f"search.backtrack_sigma must be > 0 or null, got {self.backtrack_sigma}")
        if not (self.sigma_init > 0 and self.sigma_min >= 0 and 0 < self.sigma_rate <= 1 and 0 <= self.mean_carry <= 1):
            raise ValueError("search: need sigma_init > 0, sigma_min >= 0, 0 < sigma_rate <= 1, 0 <= mean_carry <= 1")


@dataclass(frozen=True)
class CostConfig:
    """Weights of the tracking cost, averaged over a segment's frames (see :func:`samcon.cost.tracking_cost`).

    Each weight is 1 / sigma^2 for an error sigma judged tolerable, so that every term is about 1 at that error.

    Attributes:
        pose: Mean squared hinge angle error (rad^2).
        root_pos: Squared root position error (m^2): MPJPE-g is mostly root drift, open loop has no other check.
        root_rot: Squared root orientation angle (rad^2).
        end_effector: Mean squared root-relative hand and foot position error (m^2).
        balance: Squared horizontal error of the centre of mass relative to the feet (m^2): Liu et al.'s balance.
        root_vel: Squared root velocity error ((m/s)^2): the state the next segment starts from.
        body_pos: Mean over all bodies of the squared world position error (m^2): the judge's own measure (MPJPE-g
            is its root), which the terms above only approximate. 0: off.
        fall_head_error: Head height error (m) that counts as a fall (the evaluator's rule).
        fall_penalty: Cost added per frame fallen, large enough that a fallen sample is never kept while one stands.
    """

    pose: float = 10.0
    root_pos: float = 100.0
    root_rot: float = 25.0
    end_effector: float = 100.0
    balance: float = 100.0
    root_vel: float = 1.0
    body_pos: float = 0.0
    fall_head_error: float = 0.25
    fall_penalty: float = 1000.0


@dataclass(frozen=True)
class FeedbackConfig:
    """The per-segment linear feedback policies (Liu et al. 2016).

    Attributes:
        samples: Lowest-cost candidates of each segment regressed on (``regression: cheapest``).
        regression: Which candidates the regression takes: ``cheapest``, the ``samples`` lowest-cost ones of the
            segment (the lectures'), which mixes up which start states were cheap with which offset suits a state;
            ``per_state``, the lowest-cost candidate of every distinct start state (each kept state, and the
            reference for ``fresh_share``), the best offset found for that state.
        ridge: Ridge term relative to the mean feature variance (see :func:`samcon.feedback.fit_linear`).
        anchor: ``mean``: b = mean(a) - M mean(s) (the lectures' regression through the samples' means); ``path``:
            b = a* - M s* through the chosen trajectory's offset a* and start features s*, so that on its own states
            the policy replays the open-loop trajectory. The elite of one search are mostly noise around many
            different offsets, so their mean offset need not track at all (walk, measured: see docs/samcon.md).
            ``nearest``: the path anchor through every searched path (the one from the clip's start and the
            ``starts`` ones): at a segment's start the policy takes the path whose start features are nearest
            (each feature scaled by its spread over the regression samples) and applies ``a*_p + M (s - s*_p)``.
            An evaluation episode starts on the reference, where a search from that phase started, not where the
            search from frame 0 has drifted to; with ``starts: 0`` it is ``path``.
        fresh_share: Share of the candidates started on the reference state at their segment's start, as an
            evaluation episode starts, so that the regression also sees the states the policy is started from (they
            never become kept states). 0: the plain search.
        fresh_states: With a velocity noise below, distinct fresh start states per segment (drawn once per segment).
        fresh_linvel_noise: Standard deviation (m/s) added to the root's linear velocity of each fresh state: the
            regression then sees deviations like a push or a stumble and the offsets that recover from them.
        fresh_angvel_noise: The same for the root's angular velocity (rad/s).
        starts: Extra searches for the regression, each from the reference state at another segment-aligned frame of
            the clip's first cycle (drawn with the run's seed), tracking to the same last frame: an evaluation
            episode starts on the reference at some phase, a state the search from frame 0 has drifted away from
            by then, and a regression on that search's samples alone has seen nothing like it. Their samples join
            the regression of the segments they cover; their time is reported apart from the oracle's. More starts than
            the first cycle has segment starts: every one is taken in turn (each again with new draws).
        start_segments: Segments each of those searches tracks (0: to the same last frame as the search from the
            clip's start). Short searches from many phases keep their samples and paths near the reference, where an
            evaluation episode starts, at a fraction of the minutes.
        index: ``time``: a policy per segment of the tracked range (loop clips past it go back whole cycles);
            ``phase`` (loop clips, needs ``search.align_cycle``): a policy per segment of the cycle, fitted on the
            samples of that segment in every cycle of every search and, with ``anchor: nearest``, anchored on all
            their paths there (a 512-frame search of walk passes each phase 6 or 7 times). One-shot clips: ``time``.
        refine_iterations: Re-runs of SAMCON sampling around the current policies, each followed by a refit.
        refine_sigma: Offset deviation (rad) of those re-runs.
        visit_iterations: Rounds of searches from the states the policy itself reaches before it falls (the
            data-aggregation idea of DAgger, Ross et al. 2011, and of Liu et al. 2016's guided learning, where the
            policy's own rollouts decide where new samples come from): each round runs the current policy from
            ``visit_episodes`` starts at segment starts of the clip's first cycle (loop clips) or tracked range under
            the evaluator's failure rule; for every episode that fails, a search of ``start_segments`` segments (at
            least 1) starts from its simulated state at the last segment start ``visit_lead`` frames or more before
            the failure; the searches join the regression and, with ``anchor: nearest``, the anchors; then a refit.
            Their time is counted with the feedback's, apart from the oracle's. 0: none.
        visit_episodes: Episodes per round (start frames drawn with the run's seed, stratified over the range).
        visit_frames: Steps per episode.
        visit_lead: Frames before a failure the search starts at least (where the deviation begins, not the fall).
    """

    samples: int = 60
    regression: Literal["cheapest", "per_state"] = "cheapest"
    ridge: float = 0.1
    anchor: Literal["mean", "path", "nearest"] = "path"
    fresh_share: float = 0.0
    fresh_states: int = 1
    fresh_linvel_noise: float = 0.0
    fresh_angvel_noise: float = 0.0
    starts: int = 0
    start_segments: int = 0
    index: Literal["time", "phase"] = "time"
    refine_iterations: int = 0
    refine_sigma: float = 0.05
    visit_iterations: int = 0
    visit_episodes: int = 16
    visit_frames: int = 300
    visit_lead: int = 24

    def __post_init__(self) -> None:
        if self.visit_iterations < 0 or self.visit_episodes < 1 or self.visit_frames < 1 or self.visit_lead < 0:
            raise ValueError("feedback: need visit_iterations >= 0, visit_episodes >= 1, visit_frames >= 1 and "
                             "visit_lead >= 0")  # fmt: skip
        if self.starts < 0 or self.start_segments < 0:
            raise ValueError(f"feedback: need starts >= 0 and start_segments >= 0, got {self.starts}, "
                             f"{self.start_segments}")
        if self.samples < 2 or self.ridge < 0 or self.refine_iterations < 0 or self.refine_sigma <= 0:
            raise ValueError("feedback: need samples >= 2, ridge >= 0, refine_iterations >= 0, refine_sigma > 0")
        if self.fresh_states < 1 or min(self.fresh_linvel_noise, self.fresh_angvel_noise) < 0:
            raise ValueError("feedback: need fresh_states >= 1 and fresh velocity noises >= 0")
        if not 0 <= self.fresh_share <= 0.5:
            raise ValueError(f"feedback.fresh_share must lie in [0, 0.5], got {self.fresh_share}")


_FEATURES = ("root_tilt_x", "root_tilt_y", "root_vel_x", "root_vel_y", "root_ang_vel_x", "root_ang_vel_y")
_ACTUATORS = ("right_hip_x", "right_hip_y", "left_hip_x", "left_hip_y", "right_ankle_x", "right_ankle_y",
              "left_ankle_x", "left_ankle_y", "chest_x", "chest_y")  # fmt: skip


@dataclass(frozen=True)
class OptimiseConfig:
    """Closed-loop optimisation of reduced feedback gains with CMA-ES (:mod:`samcon.optimise`; the gains of Liu et al.
    2012 and the reduced-order policies of Ding et al. 2015 are tuned this way): on top of the regressed policy, each
    segment adds ``R_g (s - s*)`` with s the deviation from the reference (:data:`samcon.cost.FEATURE_NAMES`), s*
    that of the nearest anchor path (``feedback.anchor: nearest``; else 0) and R_g nonzero only from ``features`` to
    ``actuators``; CMA-ES searches those entries by running the policy from random starts of the clip in the gym,
    scored by the frames it stays up and its body position error.

    Attributes:
        generations: CMA-ES generations per clip (0: off).
        population: Candidates per generation.
        starts: Episodes per candidate, from reference states at random frames of the clip (one in each of
            ``starts`` equal stretches), drawn anew every generation with the run's seed, the same for every
            candidate of a generation; not the evaluator's fixed starts.
        frames: Steps per episode (one-shot clips: at most to their last frame).
        sigma: CMA-ES's initial step, in rad of offset per unit of a scaled feature.
        features: Feedback features the gains read, each scaled by its spread under the regressed policy (as a
            standard deviation from the median absolute deviation, at least ``min_spread``).
        actuators: Actuators the gains act on.
        groups: Gain matrices per clip, over consecutive segments of the plan split evenly (1: one for all).
        mirror: The second half of the groups is the left-right mirror image of the first (a walk's second step
            mirrors its first), halving the parameters; needs an even ``groups`` and both sides of every listed
            feature and actuator.
        error_scale: m of mean body position error that costs as much as a fallen frame (errors above it cost 1).
        max_correction: The largest correction per actuator (rad); beyond it the correction is clipped.
        min_spread: The smallest spread a feature is scaled by (its units: m, rad, m/s, rad/s).
        offsets: Actuators whose open-loop offset the search also moves, one value per segment of the plan (with
            ``feedback.index: phase`` the cycle's segments; Ding et al. 2015 optimise the feed-forward with the
            gains): the nominal the gains correct around is then itself shaped by the closed loop. Not mirrored.
        offset_sigma: rad, the initial step of those offsets (the gains' is ``sigma``).
    """

    generations: int = 0
    population: int = 16
    starts: int = 8
    frames: int = 300
    sigma: float = 0.2
    features: list[str] = field(default_factory=lambda: list(_FEATURES))
    actuators: list[str] = field(default_factory=lambda: list(_ACTUATORS))
    groups: int = 1
    mirror: bool = False
    error_scale: float = 0.5
    max_correction: float = 0.5
    min_spread: float = 0.01
    offsets: list[str] = field(default_factory=list)
    offset_sigma: float = 0.05

    def __post_init__(self) -> None:
        if self.generations < 0 or self.population < 2 or self.starts < 1 or self.frames < 1 or self.groups < 1:
            raise ValueError("optimise: need generations >= 0, population >= 2, starts >= 1, frames >= 1, groups >= 1")
        if min(self.sigma, self.error_scale, self.max_correction, self.min_spread, self.offset_sigma) <= 0:
            raise ValueError("optimise: need sigma, error_scale, max_correction, min_spread and offset_sigma > 0")
        if not self.features or not self.actuators:
            raise ValueError("optimise: features and actuators must not be empty")
        if self.mirror and self.groups % 2:
            raise ValueError(f"optimise.mirror needs an even optimise.groups, got {self.groups}")


@dataclass(frozen=True)
class LqrConfig:
    """Time-varying LQR around the searched path (:mod:`samcon.lqr`, session 18): the feedback policy judged under
    the evaluator's protocol becomes ``u*_t + clip(K_t dx)`` from the full state's deviation ``dx``, in place of the
    regressed per-segment policy (which is still fitted, stored and judged beside it, and used for clips without
    paths).

    Attributes:
        enabled: Use it (session 18: walk 12 of 16 evaluator starts held against the regressed policy's 1, crawl 16
            against 8).
        eps: Step of MuJoCo's centred finite differences (``mjd_transitionFD``). Measured on walk, 19 starts:
            1e-6 0.63 survival, 1e-4 0.16, 1e-3 0.42: wider steps straddle contact changes.
        root_pos, root_height, root_rot, hinge, root_vel, root_ang_vel, hinge_vel: The diagonal of the state cost Q
            per tangent coordinate (m, rad, m/s, rad/s; 0: free): horizontal root position, its height, root
            rotation, hinge angles and their velocities.
        control: R = control * I (per rad of target correction).
        limit: The largest correction per actuator (rad); beyond it it is clipped.
        visit_rounds: Rounds of recovery paths (LQR-trees): episodes of the policy from random frames of the first
            cycle; from each that falls, a SAMCON search from its state ``visit_lead`` frames or more before the fall
            over ``visit_segments`` segments joins the paths with its own LQR (0: the main path alone).
        visit_episodes: Episodes per round (``visit_frames`` steps each at most).
        visit_frames: Steps per visit episode.
        visit_lead: Frames before the fall the search starts at (at a segment start).
        visit_segments: Segments each recovery search covers.
    """

    enabled: bool = True
    eps: float = 1e-6
    root_pos: float = 0.0
    root_height: float = 0.0
    root_rot: float = 25.0
    hinge: float = 10.0
    root_vel: float = 1.0
    root_ang_vel: float = 0.1
    hinge_vel: float = 0.01
    control: float = 10.0
    limit: float = 0.5
    visit_rounds: int = 0
    visit_episodes: int = 24
    visit_frames: int = 512
    visit_lead: int = 36
    visit_segments: int = 8

    def __post_init__(self) -> None:
        weights = (self.root_pos, self.root_height, self.root_rot, self.hinge, self.root_vel, self.root_ang_vel,
                   self.hinge_vel)  # fmt: skip
        if min(weights) < 0:
            raise ValueError("lqr: the state weights must be >= 0")
        if not (self.eps > 0 and self.control > 0 and self.limit > 0):
            raise ValueError("lqr: need eps, control and limit > 0")
        if self.visit_rounds < 0 or min(self.visit_episodes, self.visit_frames, self.visit_segments) < 1:
            raise ValueError("lqr: need visit_rounds >= 0 and visit_episodes, visit_frames, visit_segments >= 1")
        if self.visit_lead < 0:
            raise ValueError(f"lqr.visit_lead must be >= 0, got {self.visit_lead}")


@dataclass(frozen=True)
class PolishConfig:
    """iLQR on the searched open-loop path (:mod:`samcon.polish`, session 19), before the feedback is fitted.

    Attributes:
        iterations: iLQR iterations per window (0: off). Each linearises the window (about 10 s of one core per 512
            frames) and rolls out every step size at least once.
        window: Frames per window (0: the whole path at once). Windows start ``stride`` frames apart (0: the
            window), each from the path's state at its first frame as the windows before left it.
        stride: See ``window``.
        lookahead: With windows, frames after each window whose cost (and falls) count in its own, their targets
            held as they are.
        search: With windows, the frames after the previous window's look-ahead start from a SAMCON search (the
            run's search settings) from where that look-ahead left the character, not from the searched path
            tracked by its LQR (measured on jog: the search from frame 120 fell after 170 s; off in every config
            but debug.yaml). Its samples count in the clip's.
        follow: With windows and the LQR start (``lqr``), each window's look-ahead frames are played by the LQR of the
            path the pass starts from, from wherever the window leaves the character (``u*_t + clip(K_t (x_t -
            x*_t))``, in every rollout; the window's iLQR sees the closed loop ``A + B K`` there), not by targets held
            as they were: a window is then judged by how well the LQR carries on from its end, which is how the next
            window's new frames start. One value for every pass, or one per pass (``[false, true]``: the second pass
            follows the first one's path).
        follow_lookahead: The look-ahead of the passes that follow (None: ``lookahead``).
        passes: Sweeps of windows over the path, each from the best path so far (a pass that ends dearer or falls
            where the best did not is dropped); 0: none.
        whole_iterations: Then iLQR iterations over the whole path at once, from the best so far (each step lowers
            the whole path's cost, so it keeps what the windows gained and rescues nothing they lost).
        body: Weight of the mean squared body position error (m^2; 100: 0.1 m costs 1 per frame).
        velocity: Weight of the squared hinge velocity error ((rad/s)^2).
        root_velocity: Weight of the squared error of the root's velocities (MuJoCo's free joint: linear in the
            world frame, angular in the root frame; (m/s)^2 and (rad/s)^2).
        control: Weight of the squared offset of the targets from the reference's next-frame angles (rad^2).
        eps: Finite-difference step of the linearisation.
        alphas: Step sizes tried in every forward pass (one batch).
        mu_init, mu_min, mu_max, mu_factor: The regularisation of Q_uu: starts at mu_init, divided by mu_factor
            after a step that lowered the cost (not below mu_min), multiplied after one that did not; the polish
            stops when it would exceed mu_max.
        tolerance: Stop when an iteration lowers the cost by less than this share.
        verbose: Log every forward pass (regularisation, expected change, each step size's cost).
    """

    iterations: int = 0
    window: int = 0
    stride: int = 0
    lookahead: int = 0
    passes: int = 1
    whole_iterations: int = 0
    search: bool = False
    follow: bool | tuple[bool, ...] = False
    follow_lookahead: int | None = None
    body: float = 100.0
    velocity: float = 0.001
    root_velocity: float = 0.0
    control: float = 0.01
    eps: float = 1e-6
    alphas: tuple[float, ...] = (1.0, 0.5, 0.25, 0.1, 0.03)
    mu_init: float = 1.0
    mu_min: float = 1e-3
    mu_max: float = 1e4
    mu_factor: float = 4.0
    tolerance: float = 0.002
    verbose: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "alphas", tuple(float(a) for a in self.alphas))
        if self.iterations < 0:
            raise ValueError(f"polish.iterations must be >= 0, got {self.iterations}")
        if self.passes < 0 or self.whole_iterations < 0:
            raise ValueError(f"polish: need passes, whole_iterations >= 0, got {self.passes}, {self.whole_iterations}")
        if self.lookahead < 0:
            raise ValueError(f"polish.lookahead must be >= 0, got {self.lookahead}")
        if not isinstance(self.follow, bool) and len(self.follow) != self.passes:
            raise ValueError(f"polish.follow: one value per pass ({self.passes}), got {list(self.follow)}")
        if self.follow_lookahead is not None and self.follow_lookahead < 0:
            raise ValueError(f"polish.follow_lookahead must be >= 0 or null, got {self.follow_lookahead}")
        if self.search and any(self.follows(p) for p in range(self.passes)):
            raise ValueError("polish.search plays new frames from searches, polish.follow by the searched path's LQR: "
                             "use one or the other")
        if self.window < 0 or self.stride < 0 or (self.window and self.stride > self.window):
            raise ValueError(f"polish: need window >= 0 and 0 <= stride <= window, got {self.window}, {self.stride}")
        if min(self.body, self.velocity, self.root_velocity, self.control) < 0 or self.body == 0:
            raise ValueError("polish: need body > 0 and velocity, control >= 0")
        if not (self.eps > 0 and self.alphas and min(self.alphas) > 0):
            raise ValueError("polish: need eps > 0 and at least one step size, all > 0")
        if not (0 < self.mu_min <= self.mu_init <= self.mu_max and self.mu_factor > 1 and self.tolerance >= 0):
            raise ValueError("polish: need 0 < mu_min <= mu_init <= mu_max, mu_factor > 1, tolerance >= 0")

    def follows(self, p: int) -> bool:
        """Whether pass ``p`` (from 0) plays its windows' look-aheads by the LQR."""
        return self.follow if isinstance(self.follow, bool) else self.follow[p]

    def for_pass(self, p: int) -> PolishConfig:
        """The settings of pass ``p``: ``follow`` a bool, and ``follow_lookahead`` as its look-ahead if it follows."""
        follows = self.follows(p)
        ahead = self.follow_lookahead if follows and self.follow_lookahead is not None else self.lookahead
        return replace(self, follow=follows, lookahead=ahead)


@dataclass(frozen=True)
class SamconConfig:
    """Everything ``track-samcon`` reads."""

    train: TrackConfig = field(default_factory=TrackConfig)
    gym: SimSection = field(default_factory=SimSection)
    search: SearchConfig = field(default_factory=SearchConfig)
    cost: CostConfig = field(default_factory=CostConfig)
    feedback: FeedbackConfig = field(default_factory=FeedbackConfig)
    optimise: OptimiseConfig = field(default_factory=OptimiseConfig)
    lqr: LqrConfig = field(default_factory=LqrConfig)
    polish: PolishConfig = field(default_factory=PolishConfig)

    def __post_init__(self) -> None:
        if self.feedback.index == "phase" and not self.search.align_cycle:
            raise ValueError("feedback.index: phase needs search.align_cycle: true (segments at the same phase in "
                             "every cycle)")
