"""Per-segment linear feedback policies regressed from SAMCON samples, and the evaluator policies of a SAMCON run.

Liu et al. (2016) and the tracking-control lectures: for segment k, the offset held over the segment is
``a = M_k s + b_k`` with ``s`` the feedback features (:func:`samcon.cost.feedback_features`) at the segment's start,
fitted by least squares to the lowest-cost SAMCON samples of that segment: ``M = [(S^T S)^-1 S^T A]^T`` on
centred S and A, ``b = mean(a) - M mean(s)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import Policy
from common.motion.library import MotionLibrary
from common.sim.gym import StepResult
from samcon.cost import feedback_features

if TYPE_CHECKING:
    from samcon.lqr import LqrPath


def fit_linear(features: np.ndarray, actions: np.ndarray, ridge: float) -> tuple[np.ndarray, np.ndarray]:
    """Least squares ``a ~ M s + b`` with a ridge term.

    The ridge is ``ridge * trace(S^T S) / D`` on the centred features (relative, so one value suits any feature
    scale): a segment's samples start from only ``keep`` distinct states, so S^T S is rank-deficient (or nearly so)
    and the plain normal equations would fit gains to noise; the ridge shrinks them towards 0, i.e. towards the
    open-loop offset b. When every sample starts from one state (the clip's first segment), M = 0.

    Args:
        features: Shape: (n, D).
        actions: Shape: (n, A).
        ridge: Relative ridge (0: ordinary least squares; needs n > D then).

    Returns:
        M: Shape: (A, D). b: Shape: (A,).
    """
    s_mean, a_mean = features.mean(axis=0), actions.mean(axis=0)
    s, a = features - s_mean, actions - a_mean
    gram = s.T @ s
    # The floor keeps the system solvable when the samples share one start state (the first segment): M = 0 then.
    lam = max(ridge * np.trace(gram) / max(1, len(gram)), 1e-12)
    gain = np.linalg.solve(gram + lam * np.eye(len(gram)), s.T @ a).T
    return gain, a_mean - gain @ s_mean


@dataclass
class ClipPlan:
    """What a SAMCON run holds for one clip. S segments, F frames, P searched paths.

    Attributes:
        targets: Open-loop PD targets from the clip's start. Shape: (F, nu).
        bounds: First frame of each segment and F. Shape: (S + 1,).
        gain: Feedback gains M_k. Shape: (S, nu, D).
        bias: Feedback offsets b_k. Shape: (S, nu).
        anchor_features: With ``feedback.anchor: nearest``, the start features s*_p of every searched path p
            (the search from the clip's start and the ``feedback.starts`` ones) at every segment it covers, NaN
            where it does not. Shape: (S, P, D). None: the policy is ``M_k s + b_k``.
        anchor_offsets: Those paths' chosen offsets a*_p. Shape: (S, P, nu).
        feature_scale: Per feature, the spread the distance to an anchor is measured in. Shape: (D,).
        ref_gain: Gains optimised in closed loop (:mod:`samcon.optimise`), added to the offset of every segment:
            ``R_g (s - s*_p)`` with anchors (zero on a searched path's own states), else ``R_g s``, g the segment's
            group (G groups split the segments evenly). Shape: (G, nu, D). None: none.
        ref_limit: The largest correction per actuator (rad); beyond it it is clipped.
        ref_offset: Open-loop offsets optimised in closed loop (``optimise.offsets``), added to segment k's offset
            (not clipped). Shape: (S, nu). None: none.
        lqr: With ``lqr.enabled``, the time-varying LQR paths (:mod:`samcon.lqr`), the one from the clip's start
            first: the evaluator's policy of the clip is then theirs. None: the policies above.
        lqr_limit: Their largest correction per actuator (rad).
    """

    targets: np.ndarray
    bounds: np.ndarray
    gain: np.ndarray
    bias: np.ndarray
    anchor_features: np.ndarray | None = None
    anchor_offsets: np.ndarray | None = None
    feature_scale: np.ndarray | None = None
    ref_gain: np.ndarray | None = None
    ref_limit: float = np.inf
    ref_offset: np.ndarray | None = None
    lqr: list[LqrPath] | None = None
    lqr_limit: float = np.inf

    def group(self, k: int, groups: int) -> int:
        """The group of segment ``k`` when the plan's segments are split evenly into ``groups``."""
        return k * groups // (len(self.bounds) - 1)

    def regressed(self, k: int, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The regressed part of segment ``k``'s offset for features ``s`` (D,): ``M_k s + b_k``, or with anchors
        ``a*_p + M_k (s - s*_p)`` through the path p whose start features are nearest to ``s`` (scaled by
        ``feature_scale``): on any searched path's own states the policy replays that path. Also the deviation the
        closed-loop gains read: ``s - s*_p`` from that path's state with anchors, else ``s`` (from the reference).
        Shapes: (nu,), (D,)."""
        if self.anchor_features is None:
            return self.gain[k] @ s + self.bias[k], s
        have = ~np.isnan(self.anchor_features[k, :, 0])
        diff = s - self.anchor_features[k, have]
        p = int(np.argmin(np.square(diff / self.feature_scale).sum(axis=1)))
        return self.anchor_offsets[k, have][p] + self.gain[k] @ diff[p], diff[p]

    def offset(self, k: int, s: np.ndarray) -> np.ndarray:
        """The offset of segment ``k`` for features ``s`` (D,): :meth:`regressed` plus, with ``ref_gain``, the
        closed-loop gains' ``R_g`` times the deviation it gives (clipped to ``ref_limit``), plus ``ref_offset[k]``.
        Shape: (nu,)."""
        out, diff = self.regressed(k, s)
        if self.ref_offset is not None:
            out = out + self.ref_offset[k]
        if self.ref_gain is not None:
            out = out + np.clip(self.ref_gain[self.group(k, len(self.ref_gain))] @ diff, -self.ref_limit,
                                self.ref_limit)  # fmt: skip
        return out


def _frame_index(result: StepResult, dt: float) -> np.ndarray:
    return np.rint(result.time / dt).astype(np.int64)


def open_loop_policy(plans: dict[str, ClipPlan], library: MotionLibrary, humanoid: Humanoid) -> Policy:
    """The open-loop trajectories as an evaluator policy, meant for episodes that start at t = 0: the stored target
    of the current frame; past a trajectory's end, or for a clip it lacks, the reference's next-frame angles."""

    def policy(result: StepResult) -> np.ndarray:
        out = result.ref_next.qpos[:, humanoid.hinge_qpos].copy()
        frame = _frame_index(result, library.dt)
        for i, (c, f) in enumerate(zip(result.clip, frame, strict=True)):
            plan = plans.get(library.names[c])
            if plan is not None and f < len(plan.targets):
                out[i] = plan.targets[f]
        return out

    return policy


def segment_of(plan: ClipPlan, frame: int, loop_frames: int | None) -> int:
    """The segment whose frames match ``frame``: a loop clip past the tracked range goes back whole cycles
    (``loop_frames`` frames each) until it falls inside it; a one-shot clip holds its last segment."""
    tracked = int(plan.bounds[-1])
    if loop_frames and frame >= tracked:
        frame -= int(np.ceil((frame - tracked + 1) / loop_frames)) * loop_frames
    frame = min(max(frame, 0), tracked - 1)
    return int(np.searchsorted(plan.bounds, frame, side="right") - 1)


class FeedbackPolicy:
    """The time-indexed linear feedback policies as an evaluator policy, from any start.

    The correction ``M_k s + b_k`` is computed at the first frame of each segment an episode enters (or at its
    start) and held until the segment ends, as in SAMCON, on the reference's next-frame hinge angles. A clip the run
    did not track gets the reference's angles (no correction).
    """

    def __init__(self, plans: dict[str, ClipPlan], library: MotionLibrary, humanoid: Humanoid) -> None:
        self.plans, self.library, self.humanoid = plans, library, humanoid
        self._episode: np.ndarray | None = None
        self._segment: np.ndarray | None = None
        self._held: np.ndarray | None = None

    def __call__(self, result: StepResult) -> np.ndarray:
        n, nu = len(result.clip), self.humanoid.nu
        if self._episode is None or len(self._episode) != n:
            self._episode, self._segment, self._held = np.full(n, -1), np.full(n, -1), np.zeros((n, nu))
        frame = _frame_index(result, self.library.dt)
        seg = np.full(n, -1)
        for i, (c, f) in enumerate(zip(result.clip, frame, strict=True)):
            plan = self.plans.get(self.library.names[c])
            if plan is not None:
                loop = int(round(self.library.duration[c] / self.library.dt)) if self.library.loop[c] else None
                seg[i] = segment_of(plan, int(f), loop)
        renew = (result.episode_id != self._episode) | (seg != self._segment)
        if renew.any():
            ids = np.flatnonzero(renew)
            s = feedback_features(self.humanoid, result.sim[ids], result.ref[ids])
            for j, i in enumerate(ids):
                plan = self.plans.get(self.library.names[result.clip[i]])
                self._held[i] = 0.0 if plan is None else self._offset(i, plan, int(seg[i]), s[j])
        self._episode, self._segment = result.episode_id.copy(), seg
        return result.ref_next.qpos[:, self.humanoid.hinge_qpos] + self._held

    def _offset(self, i: int, plan: ClipPlan, k: int, s: np.ndarray) -> np.ndarray:
        """The offset character ``i`` holds over segment ``k`` of ``plan`` from features ``s`` (D,)."""
        return plan.offset(k, s)
