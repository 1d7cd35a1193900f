"""Fitting a clip to a terrain (``mimic-motions fit-terrain``): its stance feet put on the terrain by lifting or
lowering the root per frame, the clip written with the terrain.

A clip recorded on flat ground keeps its feet on the floor in stance. On a terrain, each stance foot must rest on the
ground under it instead: the root is raised per frame by the terrain's height under the stance foot, and the whole
pose moves with it (a root-only fit: the legs are not bent to the terrain, so both feet can rest on it only where the
ground under them is level).

Per control-rate frame (the library's MuJoCo kinematics, as the ground fix measures the feet):

1. **Stance**: a foot slower than :data:`~.cleanup.STANCE_SPEED` (the ground fix's rule; ``stance_speed`` sets
   another) and within :data:`STANCE_HEIGHT` of the clip's usual stance height (a slow foot high in the air, at a
   jump's top, is not standing on anything). A jog or run recorded at 30 fps plants its foot at 0.1-1 m/s (it rolls
   from heel to toe between two frames), so that the ground fix's 0.2 m/s sees 0-2 frames of a contact and the fit
   interpolates the root through the rest: ``--stance-speed 1`` finds the whole contact.
2. **The ground under a foot**: how much the foot's clearance drops from the flat floor to the terrain,
   g = clearance above the floor - clearance above the terrain (each the least over the foot box's corners, the
   terrain taken under each corner): raising the root by g puts the foot as high above the terrain as it was above the
   floor. A foot flat on a 10 cm box: g = 0.10; a foot over a step's edge: its corner over the higher tread counts.
   (A clip that already carries a terrain is moved from that one to the new one: its clearance above its own terrain
   takes the floor's place.)
3. **The target**: where one foot stands, its g. Where both do, a weighted mean with each foot's weight its distance
   in frames to the nearer end of its stance (a stance running off the clip's ends has no end there): in a walk's
   double support the leaving foot's weight falls to 1 as the landing foot's grows from 1, a handover linear in
   time; standing still, both weigh alike. Frames with no foot in stance (flight, a fast turn) take the target by
   linear interpolation in time between their neighbours (held at the clip's ends). A clip with no stance frame at
   all takes the lower foot's g.
4. **Smoothing**: the target changes in steps (at each handover) and bends at the ends of each ramp. The offset is
   :func:`~.cleanup.smooth_lift` of the target, the ground fix's own filter: the lowest curve above the target whose
   slope is at most :data:`FIT_SPEED` (a cone envelope), then a running maximum and a Hann window over
   +-:data:`FIT_SMOOTHING`. Why this filter: it is never below the target, so the fit pushes no stance foot into the
   terrain (a symmetric low-pass filter would cut every step's corner and sink the landing foot into the tread);
   a step is climbed at a bounded vertical speed instead of in one frame (no jump between steps); the Hann window
   gives the offset a continuous velocity; and it is exactly 0 where the target is 0, so a flat terrain leaves the
   clip as it was. What it costs: near a handover the leaving (stairs up) or landing (stairs down) foot floats above
   its tread for as long as the climb at FIT_SPEED takes beyond the double support.
5. **The ground fix on the terrain**: the keyframes take the offset by linear interpolation in time, then
   :func:`~.cleanup.fix_ground` measured against the terrain: the whole clip shifted by its median stance clearance,
   and lifted (smoothly, at :data:`~.cleanup.LIFT_SPEED`) where a stance foot is still more than
   :data:`~.cleanup.GROUND_TOLERANCE` in it. On a terrain flat at height 0 the offset is 0 and this step is
   ``fix_ground`` on the flat floor bit for bit: the flat special case of the fit is the ground fix.

Velocities are not stored in a clip: every reader derives them from the positions when it resamples the clip to the
control rate (central differences, :func:`~common.motion.library.resample_clip`), so the fitted clip's velocities are
those of its new positions wherever it is read or written (a motion dataset ``.h5`` stores them so computed).

A clip must stay over its terrain: every support point of every body (foot and hand box corners, capsule ends) at
every control frame within the grid, or the fit is refused. A wrap clip's offset must come back to where it started
(within :data:`LOOP_CLOSURE`) for its loop to stay closed; otherwise (stairs) it is written one-shot, and its later
cycles would walk off the terrain anyway (the terrain does not move with the cycles).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from common.character.humanoid import BodyGeometry, Humanoid
from common.motion.library import MotionLibrary
from common.motion.motion import Clip
from common.motion.motion_import import cleanup
from common.motion.terrain import Terrain

FIT_SPEED = 1.0  # m/s: the most the fit changes the root's vertical speed; see the module docstring
FIT_SMOOTHING = 0.05  # s: half-width of the window that rounds the offset's corners
STANCE_HEIGHT = 0.05  # m: a slow foot higher than this above the clip's usual stance height is not in stance
LOOP_CLOSURE = 0.001  # m: a wrap clip stays wrap when its offset ends within this of where it began


@dataclass(frozen=True)
class TerrainFit:
    """What :func:`fit_terrain` did.

    Attributes:
        offset: The terrain's offset added to the root's height, per keyframe (m), before the ground fix.
            Shape: (M,).
        stance: The stance frames found, per control frame and foot (right, left as the humanoid's feet). Shape:
            (T, 2), bool.
        ground: The ground fix on the terrain that followed (its shift and local lift).
        before: (worst stance foot, worst foot at any frame): the lowest clearance above the terrain of the clip as
            given, m (negative: in the terrain); stance a foot slower than ``stance_speed``.
        after: The same of the fitted clip.
        loop_opened: A wrap clip written one-shot because its offset does not close the loop.
        stance_speed: The stance rule's speed (m/s).
    """

    offset: np.ndarray
    stance: np.ndarray
    ground: cleanup.GroundFix
    before: tuple[float, float]
    after: tuple[float, float]
    loop_opened: bool
    stance_speed: float = cleanup.STANCE_SPEED

    def report(self) -> list[str]:
        cm = 100.0
        frames = len(self.stance)
        either = int(self.stance.any(axis=1).sum())
        lines = [
            f"terrain fit: root offset {self.offset.min() * cm:+.1f} to {self.offset.max() * cm:+.1f} cm over "
            f"{len(self.offset)} keyframes; stance frames (foot slower than {self.stance_speed:g} m/s and within "
            f"{STANCE_HEIGHT * cm:g} cm of its stance height): right {int(self.stance[:, 0].sum())}, left "
            f"{int(self.stance[:, 1].sum())}, either {either} of {frames}",
            self.ground.report().replace("ground fixed", "then ground fixed on the terrain"),
            f"lowest stance foot above the terrain: {self.before[0] * cm:+.1f} cm as given, {self.after[0] * cm:+.1f} "
            f"cm fitted; lowest foot at any frame: {self.before[1] * cm:+.1f} cm as given, {self.after[1] * cm:+.1f} "
            "cm fitted (a swing foot may still cut a step's edge: the fit moves the root, not the legs)",
        ]  # fmt: skip
        if self.loop_opened:
            lines.append(f"written one-shot (loop none): the offset ends {(self.offset[-1] - self.offset[0]) * cm:+.1f}"
                         " cm from where it began, so a wrap loop would not close")  # fmt: skip
        return lines


def fit_terrain(clip: Clip, humanoid: Humanoid, terrain: Terrain,
                stance_speed: float = cleanup.STANCE_SPEED) -> tuple[Clip, TerrainFit]:  # fmt: skip
    """Fits ``clip`` to ``terrain`` (see the module docstring) and attaches the terrain to it.

    Args:
        clip: The clip, on the flat floor or on another terrain.
        humanoid: The character.
        terrain: The ground to fit it to.
        stance_speed: A foot slower than this (m/s) may be in stance (step 1); the ground fix that follows keeps its
            own :data:`~.cleanup.STANCE_SPEED`.

    Returns:
        (the fitted clip, carrying ``terrain``; what was done).

    Raises:
        ValueError: the clip leaves the terrain's grid (one line naming the body, where and when).
    """
    flat_clip = replace(clip, loop=False, terrain=None)
    frames = MotionLibrary.from_clips([flat_clip], humanoid).frames
    geometry = BodyGeometry(humanoid)
    check_extent(clip, humanoid, geometry, frames.body_pos, frames.body_rot, terrain)
    feet = humanoid.foot_indices
    # the floor, mostly
    own = geometry.clearance(frames.body_pos, frames.body_rot, cleanup.ground_of(clip.terrain))[:, feet]
    on = geometry.clearance(frames.body_pos, frames.body_rot, terrain.height_at)[:, feet]
    slow = np.linalg.norm(frames.body_linvel[:, feet], axis=-1) < stance_speed
    usual = float(np.median(own[slow])) if slow.any() else float(own.min())
    stance = slow & (own <= usual + STANCE_HEIGHT)
    target = stance_target(own - on, stance, own)
    dt = humanoid.physics.control_dt
    offset = cleanup.smooth_lift(target, FIT_SPEED * dt, max(1, int(round(FIT_SMOOTHING / dt))))
    at_keys = np.interp(clip.times, np.arange(len(offset)) * dt, offset)
    lifted = replace(clip, root_pos=clip.root_pos + at_keys[:, None] * np.array([0.0, 0.0, 1.0]), terrain=terrain)
    fixed, ground = cleanup.fix_ground(lifted, humanoid)
    loop_opened = clip.loop and abs(offset[-1] - offset[0]) > LOOP_CLOSURE
    if loop_opened:
        fixed = replace(fixed, loop=False)
    after = cleanup.foot_contact(fixed, humanoid)
    after_worst = _worst(after.height, after.speed < stance_speed)
    fit = TerrainFit(at_keys, stance, ground, _worst(on, slow), after_worst, loop_opened, stance_speed)
    return fixed, fit


def _worst(height: np.ndarray, stance: np.ndarray) -> tuple[float, float]:
    """(lowest stance foot, lowest foot at any frame), m; the first is +inf with no stance frame."""
    return float(np.where(stance, height, np.inf).min()), float(height.min())


def stance_target(ground: np.ndarray, stance: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """The target offset per frame: the ground under the stance feet, handed over linearly in double support and
    interpolated in time where no foot stands (step 3 of the module docstring).

    Args:
        ground: The terrain's height under each foot, g. Shape: (T, 2).
        stance: Stance frames. Shape: (T, 2), bool.
        flat: Each foot's clearance above the flat floor (which foot is lower where none stands). Shape: (T, 2).

    Returns:
        Shape: (T,).
    """
    n = len(ground)
    if not stance.any():
        stance = np.zeros_like(stance)
        stance[np.arange(n), flat.argmin(axis=1)] = True
    weight = np.zeros(ground.shape)
    for foot in range(ground.shape[1]):
        s = stance[:, foot].astype(np.int8)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], s, [0]])))
        for start, stop in zip(edges[::2], edges[1::2], strict=True):  # stance over frames start .. stop - 1
            k = np.arange(start, stop)
            since = k - start + 1.0 if start > 0 else np.full(len(k), np.inf)
            until = stop - k + 0.0 if stop < n else np.full(len(k), np.inf)
            weight[start:stop, foot] = np.minimum(since, until)
    weight[np.isinf(weight)] = n + 1.0  # a stance over the whole clip
    some = stance.any(axis=1)
    mean = (weight[some] * ground[some]).sum(axis=1) / weight[some].sum(axis=1)
    return np.interp(np.arange(n), np.flatnonzero(some), mean)


def check_extent(clip: Clip, humanoid: Humanoid, geometry: BodyGeometry, body_pos: np.ndarray, body_rot: np.ndarray,
                 terrain: Terrain) -> None:  # fmt: skip
    """Refuses a clip one of whose bodies leaves the terrain's grid at some control frame.

    Raises:
        ValueError: ``"<clip>: leaves the terrain: its <body> reaches (x, y) at t s, beyond the terrain's x a..b,
            y c..d m"``.
    """
    px, py, _ = geometry.support_points(body_pos, body_rot)  # (T, B, 8) each
    lo = terrain.origin
    hi = terrain.origin + terrain.size
    out = (px < lo[0]) | (px > hi[0]) | (py < lo[1]) | (py > hi[1])
    if not out.any():
        return
    # The farthest point beyond the grid, to name.
    beyond = np.maximum.reduce([lo[0] - px, px - hi[0], lo[1] - py, py - hi[1]])
    t, b, p = np.unravel_index(np.argmax(beyond), beyond.shape)
    raise ValueError(
        f"{clip.source}: the clip leaves its terrain: its {humanoid.body_names[b]} reaches (x, y) = "
        f"({px[t, b, p]:.2f}, {py[t, b, p]:.2f}) m at {t * humanoid.physics.control_dt:.2f} s, beyond the terrain's "
        f"x {lo[0]:.2f} to {hi[0]:.2f} m, y {lo[1]:.2f} to {hi[1]:.2f} m; move the terrain or make it larger"
    )
