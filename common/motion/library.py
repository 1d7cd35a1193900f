"""The kinematic reference: many clips resampled to the control rate, queried by (clip, time) for N characters.

For every frame the library holds the model's qpos/qvel and every body's world position, rotation, linear and
angular velocity, computed with MuJoCo's own kinematics (``mj_kinematics``/``mj_comVel`` through
``mj_forward`` and ``mj_objectVelocity``), so that the reference and the simulator agree by construction.

Looping (``wrap``) clips continue past their end: cycle c is the first cycle moved by the rigid ground-plane
transform Delta^c, where Delta takes the root's ground position and heading at the first keyframe to those at the
last keyframe. Because mocap loops never close exactly, the joint rotations and root tilt are bent towards the
first keyframe over the cycle (the mismatch e at the end is applied as s/D * e at time s), so that pose and
velocities stay continuous across the loop point instead of jumping once per cycle. Bending the legs moves the
feet up or down: the root height is set per keyframe so that the character's lowest point stays
where the clip had it (the seam's own clearance mismatch is taken out over the cycle's last half second). Without
that correction the jump clip's 15-20 deg hip and knee mismatch put its feet 7.9 cm into the floor after the landing,
where the clip as recorded has them at most 1.8 cm below it. The bend closes the loop in pose, not in velocity. Asked
for (``seam_bridge``; off by default), the keyframes within that many seconds of the seam are then replaced by one
cubic curve across it (:func:`_bridge_seam`), so that velocities run on too: zombie_walk's and dance_spin's seams
ask for 1.8 and 1.3 body weights of force no floor contact gives, bridged none. It is off by default because it made
SAMCON's search on zombie_walk and cartwheel worse on every draw measured (docs/motions.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from common.character.humanoid import BodyGeometry, Humanoid
from common.character.state import FRAME_FIELDS, CharacterState
from common.maths.rotations import (
    angular_velocity,
    quat_conj,
    quat_fix_hemisphere,
    quat_from_rotvec,
    quat_from_yaw,
    quat_mul,
    quat_normalize,
    quat_rotate,
    quat_rotate_inv,
    quat_slerp,
    quat_split_heading,
    quat_to_euler_xyz_continuous,
    quat_to_rotvec,
    quat_yaw,
)
from common.motion.errors import MotionFormatError
from common.motion.motion import Clip
from common.motion.terrain import Terrain

SEAM_BLEND = 0.5  # s: a wrap clip's end takes its first frame's clearance above the floor over this long
SEAM_BRIDGE = 0.1  # s: with the seam bridge (opt-in), the keyframes this close to a wrap clip's loop seam are bridged
FLIGHT_CLEARANCE = 0.03  # m: a keyframe whose lowest point is higher above the floor than this is in flight


@dataclass(frozen=True)
class ClipFrames:
    """One clip on the control-rate grid t_k = k * dt (what the HDF5 dataset stores per clip).

    A wrap clip is time-scaled so that its cycle lasts a whole number of steps n; its grid holds frames 0..n, frame n
    being frame 0 of the next cycle. A one-shot clip's grid ends at the last grid time <= its duration. ``terrain``
    is the ground the clip is on (None: the flat floor); it does not move with a wrap clip's cycles.
    """

    name: str
    source: str
    loop: bool
    duration: float
    cycle_yaw: float
    cycle_shift: np.ndarray
    frames: CharacterState
    terrain: Terrain | None = None


def _bend_loop(clip: Clip, humanoid: Humanoid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closes a wrap clip's loop: returns root_pos, root_rot, joint_rot bent towards the first keyframe.

    The joint rotations and root tilt are bent by s/D of the seam mismatch at time s. The bend changes how far the
    feet (or hands, or back) reach down, so the root height is shifted per keyframe by
    c(s) = (h(s) - h_bent(s)) - w(s) (h(D) - h(0)), h being the lowest point of the character's collision geoms: the
    bent clip keeps the recorded clip's clearance above the floor, except for the seam's own clearance mismatch
    h(D) - h(0), which is taken out over the last :data:`SEAM_BLEND` seconds (w a smoothstep from 0 to 1 there):
    over the whole cycle it would lift or sink every frame for what is often a glitch of the last few (crawl's last
    keyframes are 8.8 cm in the floor). c at the ends closes the loop. At keyframes in flight (recorded h above
    :data:`FLIGHT_CLEARANCE`) c is interpolated linearly in time between its values at the neighbouring keyframes
    that touch the floor (or the ends), which leaves the flight's vertical acceleration as recorded.
    """
    s = (clip.times / clip.duration)[:, None]
    root_pos = clip.root_pos.copy()  # its height is set by the clearance correction below
    heading, tilt = quat_split_heading(clip.root_rot)
    tilt_err = quat_to_rotvec(quat_mul(tilt[0], quat_conj(tilt[-1])))
    tilt = quat_mul(quat_from_rotvec(s * tilt_err), tilt)
    root_rot = quat_fix_hemisphere(quat_mul(heading, tilt), axis=0)
    joint_err = quat_to_rotvec(quat_mul(clip.joint_rot[0], quat_conj(clip.joint_rot[-1])))
    joint_rot = quat_fix_hemisphere(quat_mul(quat_from_rotvec(s[:, :, None] * joint_err[None]), clip.joint_rot), axis=0)
    recorded = _lowest_point(humanoid, clip.root_pos, clip.root_rot, clip.joint_rot)
    bent = _lowest_point(humanoid, root_pos, root_rot, joint_rot)
    blend = min(SEAM_BLEND, clip.duration)
    u = np.clip((clip.times - (clip.duration - blend)) / blend, 0.0, 1.0)
    w = u * u * (3.0 - 2.0 * u)
    shift = (recorded - bent) - w * (recorded[-1] - recorded[0])
    # In flight the clearance is a foot in the air, not a contact to keep: there the shift runs linearly in time
    # between the keyframes that touch (and the ends, which close the loop), so that the root's flight stays the
    # recorded parabola (a shift linear in time adds no acceleration). Shifting it to each flight keyframe's clearance
    # moved run's root by up to 13 cm in the air, an acceleration no floor contact can give.
    touch = recorded <= FLIGHT_CLEARANCE
    touch[[0, -1]] = True
    root_pos[:, 2] += np.interp(clip.times, clip.times[touch], shift[touch])
    return root_pos, root_rot, joint_rot


def _bridge_seam(
    clip: Clip,
    humanoid: Humanoid,
    root_pos: np.ndarray,
    root_rot: np.ndarray,
    joint_rot: np.ndarray,
    width: float = SEAM_BRIDGE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Makes a closed wrap clip's loop seam continuous in velocity: returns root_pos, root_rot, joint_rot bridged.

    The bend closes the loop in pose, not in velocity: where the recorded end moves differently from the recorded
    start (or its last keyframes are glitches: zombie_walk's root rises 1.5 cm in its last 1/60 s), the reference's
    velocities jump at every seam, up to 1.5 m/s at the root within one frame, a force no contact gives. The k
    keyframes either side of the seam (k = ``width`` times the clip's rate, at least 2) are replaced by one cubic
    Hermite curve per coordinate, run across the seam in the unrolled clip (the next cycle moved by the cycle
    transform Delta) from the keyframe k before the seam to the keyframe k after it, with their central-difference
    velocities. Rotations (root and joints) are bridged as rotation vectors about the seam's pose: the window turns by
    far less than pi. The seam keyframes stay related by Delta, so the loop stays closed; keyframes outside the window
    are left as they are. A foot that lands inside the window would overshoot the floor on the cubic: there the root
    is lifted to keep the bridged pose's lowest point no lower than the window's ends' (or the floor).

    Args:
        clip: The wrap clip (its times and cycle transform).
        humanoid: The model (its collision geoms).
        root_pos, root_rot, joint_rot: Its closed keyframes (:func:`_bend_loop`). Shapes: (M, 3), (M, 4), (M, J, 4).
        width: Seconds either side of the seam; 0 leaves the keyframes as they are.
    """
    m = len(clip.times)
    k = min(max(2, int(round(width * clip.source_fps))), (m - 3) // 2) if width > 0.0 else 0
    if k < 1:
        return root_pos, root_rot, joint_rot
    yaw, shift = cycle_transform(clip)
    q_yaw = quat_from_yaw(np.array(yaw))
    # The unrolled window: keyframes m-k-2 .. m-1 of this cycle, then 1 .. k+1 of the next (moved by Delta).
    end, nxt = np.arange(m - k - 2, m), np.arange(1, k + 2)
    times = np.concatenate([clip.times[end], clip.duration + clip.times[nxt]])
    pos = np.concatenate([root_pos[end], quat_rotate(q_yaw, root_pos[nxt]) + shift])
    rot = np.concatenate([root_rot[end], quat_mul(q_yaw, root_rot[nxt])])
    jrot = np.concatenate([joint_rot[end], joint_rot[nxt]])
    seam = k + 1  # keyframe m-1 of this cycle, keyframe 0 of the next
    # Tangent coordinates: the root position, then rotation vectors about the seam's pose (left perturbations).
    coords = np.concatenate(
        [pos, quat_to_rotvec(quat_mul(rot, quat_conj(rot[seam]))),
         quat_to_rotvec(quat_mul(jrot, quat_conj(jrot[seam]))).reshape(len(times), -1)], axis=1,
    )  # fmt: skip
    a, b = 1, 2 * k + 1
    span = times[b] - times[a]
    va = (coords[a + 1] - coords[a - 1]) / (times[a + 1] - times[a - 1])
    vb = (coords[b + 1] - coords[b - 1]) / (times[b + 1] - times[b - 1])
    u = ((times[a + 1 : b] - times[a]) / span)[:, None]
    bridge = ((2 * u**3 - 3 * u**2 + 1) * coords[a] + (u**3 - 2 * u**2 + u) * span * va
              + (-2 * u**3 + 3 * u**2) * coords[b] + (u**3 - u**2) * span * vb)  # fmt: skip
    inner = np.arange(a + 1, b)
    new_pos = bridge[:, 0:3]
    new_rot = quat_mul(quat_from_rotvec(bridge[:, 3:6]), rot[seam])
    new_jrot = quat_mul(quat_from_rotvec(bridge[:, 6:].reshape(len(inner), -1, 3)), jrot[seam][None])
    # A foot that comes down inside the window overshoots the floor on the cubic (dance_a's by 1.6 cm): the root is
    # lifted so that no bridged keyframe reaches lower than the window's ends do (or the floor, if they are above it).
    floor = min(0.0, *_lowest_point(humanoid, pos[[a, b]], rot[[a, b]], jrot[[a, b]]))
    new_pos[:, 2] += np.maximum(0.0, floor - _lowest_point(humanoid, new_pos, new_rot, new_jrot))
    root_pos, root_rot, joint_rot = root_pos.copy(), root_rot.copy(), joint_rot.copy()
    mine, theirs = inner <= seam, inner >= seam  # the seam is both this cycle's last keyframe and the next's first
    root_pos[end[inner[mine]]] = new_pos[mine]
    root_rot[end[inner[mine]]] = new_rot[mine]
    joint_rot[end[inner[mine]]] = new_jrot[mine]
    first = inner[theirs] - seam  # keyframes 0 .. k-1 of the first cycle, moved back by Delta^-1
    q_back = quat_conj(q_yaw)
    root_pos[first] = quat_rotate(q_back, new_pos[theirs] - shift)
    root_rot[first] = quat_mul(q_back, new_rot[theirs])
    joint_rot[first] = new_jrot[theirs]
    return root_pos, quat_fix_hemisphere(root_rot, axis=0), quat_fix_hemisphere(joint_rot, axis=0)


def _lowest_point(humanoid: Humanoid, root_pos: np.ndarray, root_rot: np.ndarray, joint_rot: np.ndarray) -> np.ndarray:
    """Height of the lowest collision-geom point of each keyframe's pose (MuJoCo's kinematics). Shape: (K,)."""
    qpos = _qpos(humanoid, root_pos, root_rot, joint_rot)
    state = body_states(humanoid, qpos, np.zeros((len(qpos), humanoid.nv)))
    return BodyGeometry(humanoid).lowest_points(state.body_pos, state.body_rot).min(axis=-1)


def _qpos(humanoid: Humanoid, root_pos: np.ndarray, root_rot: np.ndarray, joint_rot: np.ndarray) -> np.ndarray:
    """Generalised coordinates of keyframes: the free root, then each joint's Euler angles or hinge angle."""
    qpos = np.zeros((len(root_pos), humanoid.nq))
    qpos[:, 0:3] = root_pos
    qpos[:, 3:7] = root_rot
    for j, group in enumerate(humanoid.joint_groups):
        if group.kind == "spherical":
            qpos[:, list(group.qpos)] = quat_to_euler_xyz_continuous(joint_rot[:, j])
        else:
            # A single-axis rotation about +y: angle = 2 atan2(q_y, q_w).
            qpos[:, group.qpos[0]] = 2.0 * np.arctan2(joint_rot[:, j, 2], joint_rot[:, j, 0])
    return qpos


def cycle_transform(clip: Clip) -> tuple[float, np.ndarray]:
    """Delta of a wrap clip: yaw psi and shift t with x' = R_z(psi) x + t, taking keyframe 0 to the last keyframe."""
    yaw = float(quat_yaw(clip.root_rot[-1]) - quat_yaw(clip.root_rot[0]))
    yaw = (yaw + np.pi) % (2 * np.pi) - np.pi
    p0 = np.array([*clip.root_pos[0, :2], 0.0])
    shift = clip.root_pos[-1] - quat_rotate(quat_from_yaw(np.array(yaw)), p0)
    shift[2] = 0.0
    return yaw, shift


def cycle_power(yaw: np.ndarray, shift: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Delta^c for integer c (negative c gives the inverse), vectorised.

    As a complex map of the ground plane: z -> e^{i c psi} z + t (1 - e^{i c psi}) / (1 - e^{i psi}).

    Args:
        yaw: Cycle yaw psi. Shape: (N,).
        shift: Cycle shift t (z component ignored). Shape: (N, 3).
        c: Cycle counts. Shape: (N,).

    Returns:
        (yaw * c, shift_c) with shift_c of shape (N, 3) and zero z.
    """
    t = shift[..., 0] + 1j * shift[..., 1]
    rot_c = np.exp(1j * yaw * c)
    denom = 1.0 - np.exp(1j * yaw)
    small = np.abs(denom) < 1e-9
    geom = np.where(small, c, (1.0 - rot_c) / np.where(small, 1.0, denom))
    tc = t * geom
    return yaw * c, np.stack([tc.real, tc.imag, np.zeros_like(tc.real)], axis=-1)


def _sample_keyframes(
    clip: Clip, times: np.ndarray, root_pos: np.ndarray, root_rot: np.ndarray, joint_rot: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Interpolates keyframes at arbitrary times (wrap clips continue with Delta; one-shot clips clamp)."""
    if clip.loop:
        cycles = np.floor(times / clip.duration)
        local = times - cycles * clip.duration
    else:
        cycles = np.zeros_like(times)
        local = np.clip(times, 0.0, clip.duration)
    j = np.clip(np.searchsorted(clip.times, local, side="right") - 1, 0, len(clip.times) - 2)
    w = np.clip((local - clip.times[j]) / (clip.times[j + 1] - clip.times[j]), 0.0, 1.0)
    pos = root_pos[j] + w[:, None] * (root_pos[j + 1] - root_pos[j])
    rot = quat_slerp(root_rot[j], root_rot[j + 1], w)
    jrot = quat_slerp(joint_rot[j], joint_rot[j + 1], w[:, None])
    if clip.loop:
        yaw, shift = cycle_transform(clip)
        yaw_c, shift_c = cycle_power(np.full_like(cycles, yaw), np.broadcast_to(shift, (len(cycles), 3)), cycles)
        q_c = quat_from_yaw(yaw_c)
        pos = quat_rotate(q_c, pos) + shift_c
        rot = quat_mul(q_c, rot)
    return pos, rot, jrot


def resample_clip(clip: Clip, humanoid: Humanoid, seam_bridge: float = 0.0) -> ClipFrames:
    """Resamples a clip to the control rate and computes every per-frame quantity.

    Velocities are central differences over the grid (one-sided at the ends of a one-shot clip); the frames one
    step outside the grid come from the neighbouring cycles of a wrap clip. ``seam_bridge``: seconds either side of
    a wrap clip's loop seam bridged by :func:`_bridge_seam` (0: off, the bent clip as it is; :data:`SEAM_BRIDGE`
    is the width measured in session 22).
    """
    if not seam_bridge >= 0.0:
        raise ValueError(f"{clip.source}: seam_bridge must be >= 0 s (0: off), got {seam_bridge}")
    dt = humanoid.physics.control_dt
    if clip.loop:
        root_pos, root_rot, joint_rot = _bridge_seam(clip, humanoid, *_bend_loop(clip, humanoid), seam_bridge)
        # A cycle of a whole number of frames keeps every gym time on the grid (queries are plain lookups and the
        # loop seam is exact): the clip is time-scaled by at most half a step per cycle (<= 1% for the bundled clips).
        cycle_frames = max(2, int(round(clip.duration / dt)))
        clip = replace(clip, times=clip.times * (cycle_frames * dt / clip.duration))
        n = cycle_frames + 1
        k = np.arange(-1, n + 1)
    else:
        root_pos, root_rot, joint_rot = clip.root_pos, clip.root_rot, clip.joint_rot
        n = int(np.floor(clip.duration / dt + 1e-9)) + 1
        if n < 2:
            raise MotionFormatError(f"{clip.source}: clip of {clip.duration:.4f} s is shorter than one control step "
                                    f"({dt:.4f} s)")  # fmt: skip
        k = np.arange(n)
    times = k * dt
    pos, rot, jrot = _sample_keyframes(clip, times, root_pos, root_rot, joint_rot)
    rot = quat_fix_hemisphere(rot, axis=0)

    qpos = _qpos(humanoid, pos, rot, jrot)

    qvel = np.zeros((len(k), humanoid.nv))
    hinges = np.arange(7, humanoid.nq)
    if clip.loop:
        inner = slice(1, n + 1)
        qvel_all = (qpos[2:] - qpos[:-2]) / (2 * dt)
        w_world = angular_velocity(rot[:-2], rot[2:], 2 * dt)
        qvel[inner, 0:3] = qvel_all[:, 0:3]
        qvel[inner, 6:] = qvel_all[:, hinges]
        qvel[inner, 3:6] = quat_rotate_inv(rot[inner], w_world)
        qpos, qvel = qpos[inner], qvel[inner]
    else:
        qvel[:, 0:3] = np.gradient(qpos[:, 0:3], dt, axis=0)
        qvel[:, 6:] = np.gradient(qpos[:, hinges], dt, axis=0)
        w_world = np.empty((n, 3))
        w_world[1:-1] = angular_velocity(rot[:-2], rot[2:], 2 * dt)
        w_world[0] = angular_velocity(rot[0], rot[1], dt)
        w_world[-1] = angular_velocity(rot[-2], rot[-1], dt)
        qvel[:, 3:6] = quat_rotate_inv(rot, w_world)
    yaw, shift = cycle_transform(clip) if clip.loop else (0.0, np.zeros(3))
    return ClipFrames(clip.name, clip.source, clip.loop, clip.duration, yaw, shift, body_states(humanoid, qpos, qvel),
                      clip.terrain)  # fmt: skip


def body_states(humanoid: Humanoid, qpos: np.ndarray, qvel: np.ndarray) -> CharacterState:
    """Per-body world states from generalised coordinates with MuJoCo's kinematics.

    Args:
        humanoid: The model.
        qpos: Shape: (T, nq).
        qvel: Shape: (T, nv).
    """
    from common.character.kinematics import ForwardKinematics

    return ForwardKinematics(humanoid)(qpos.copy(), qvel.copy())


class MotionLibrary:
    """Clips on one control-rate grid, with vectorised queries and weighted sampling of start points.

    Args:
        clips: Resampled clips (from :func:`resample_clip` or a dataset file).
        control_dt: The grid step in seconds.
    """

    def __init__(self, clips: list[ClipFrames], control_dt: float) -> None:
        if not clips:
            raise ValueError("a motion library needs at least one clip")
        self.clips = clips
        self.dt = control_dt
        self.names = [c.name for c in clips]
        counts = np.array([len(c.frames.qpos) for c in clips])
        self.start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        self.num_frames = counts
        self.loop = np.array([c.loop for c in clips])
        self.duration = np.array([c.duration for c in clips])
        self.cycle_yaw = np.array([c.cycle_yaw for c in clips])
        self.cycle_shift = np.stack([c.cycle_shift for c in clips])
        self.frames = CharacterState(**{f: np.concatenate([getattr(c.frames, f) for c in clips]) for f in FRAME_FIELDS})
        # The last time a one-shot clip can be queried on its grid; wrap clips never end.
        self.end_time = np.where(self.loop, np.inf, (counts - 1) * control_dt)
        self.cycle_wind = np.stack([self._cycle_wind(c) for c in range(len(clips))])

    def _cycle_wind(self, c: int) -> np.ndarray:
        """What a wrap clip's hinge angles gain per cycle: whole turns (nq,).

        The hinge angles of a wrap clip are its joint rotations as continuous Euler angles over the cycle, which may
        end a whole turn away from where they began (a shoulder's x and z angles go once round in dance_a, crawl,
        cartwheel and sideflip): the same rotation, but cycle c + 1 starting again from the first frame's angles made
        the PD targets jump by 2 pi at every loop seam, and the character's joint was driven a whole turn back. Cycle
        c's angles are the first cycle's plus c times these turns, so that angles and targets run on continuously.
        Only exact whole turns count (a seam that lands on the other Euler solution of a joint, which no shift mends,
        is left as it is)."""
        if not self.loop[c]:
            return np.zeros(self.frames.qpos.shape[1])
        q = self.frames.qpos[self.start[c] : self.start[c] + self.num_frames[c]]
        change = q[-1] - q[0]
        turns = 2.0 * np.pi * np.rint(change / (2.0 * np.pi))
        turns[:7] = 0.0  # the free joint: the cycle transform moves the root
        return np.where(np.abs(change - turns) < 1e-6, turns, 0.0)

    @classmethod
    def from_clips(cls, clips: list[Clip], humanoid: Humanoid, seam_bridge: float = 0.0) -> MotionLibrary:
        return cls([resample_clip(c, humanoid, seam_bridge) for c in clips], humanoid.physics.control_dt)

    @property
    def num_clips(self) -> int:
        return len(self.clips)

    def clip_weights(self, by_name: Mapping[str, float]) -> np.ndarray | None:
        """RSI sampling weights per clip from ``{clip name: weight}``; unnamed clips weigh 1. None when empty.

        Raises:
            ValueError: A name that is not a clip of the library, or a negative weight (named).
        """
        if not by_name:
            return None
        weights = np.ones(self.num_clips)
        for name, w in by_name.items():
            if name not in self.names:
                raise ValueError(f"clip weight for '{name}': no such clip among the motions ({', '.join(self.names)})")
            if not w >= 0.0:
                raise ValueError(f"clip weight for '{name}' must be >= 0, got {w}")
            weights[self.names.index(name)] = w
        if weights.sum() <= 0.0:
            raise ValueError("clip weights are all 0: no clip could start an episode")
        return weights

    def clip_index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no clip '{name}' in the motion library; clips: {self.names}") from None

    def query(self, clip_ids: np.ndarray, times: np.ndarray) -> CharacterState:
        """The reference state of N characters at the given clips and times.

        Frames are interpolated linearly (rotations by normalised lerp, which equals slerp to 1e-4 rad over one
        60 Hz step); wrap clips are continued by the cycle transform, one-shot clips are held at their end.

        Args:
            clip_ids: Clip index per character. Shape: (N,).
            times: Time in seconds since the clip's start per character. Shape: (N,).

        Returns:
            CharacterState with leading shape (N,).
        """
        clip_ids = np.asarray(clip_ids, dtype=np.int64)
        times = np.asarray(times, dtype=np.float64)
        loop = self.loop[clip_ids]
        dur = self.duration[clip_ids]
        cycles = np.where(loop, np.floor(times / dur), 0.0)
        local = np.where(loop, times - cycles * dur, np.clip(times, 0.0, self.end_time[clip_ids]))
        u = local / self.dt
        k = np.rint(u)
        on_grid = np.abs(u - k) < 1e-6
        i0 = np.clip(np.where(on_grid, k, np.floor(u)).astype(np.int64), 0, self.num_frames[clip_ids] - 1)
        state = self.frames[self.start[clip_ids] + i0]
        off = np.flatnonzero(~on_grid)
        if len(off):
            self._interpolate(state, clip_ids[off], i0[off], (u - np.floor(u))[off], off)
        if np.any(cycles > 0):
            yaw_c, shift_c = cycle_power(self.cycle_yaw[clip_ids], self.cycle_shift[clip_ids], cycles)
            _move_yaw(state, yaw_c, shift_c)
            state.qpos += cycles[:, None] * self.cycle_wind[clip_ids]
        return state

    def _interpolate(self, state: CharacterState, clip_ids: np.ndarray, i0: np.ndarray, w: np.ndarray,
                     rows: np.ndarray) -> None:  # fmt: skip
        """Replaces ``rows`` of ``state`` by the blend of frames i0 and i0 + 1 with weight w (times off the grid)."""
        i0 = np.minimum(i0, self.num_frames[clip_ids] - 2)
        a = self.frames[self.start[clip_ids] + i0]
        b = self.frames[self.start[clip_ids] + i0 + 1]
        w1, w2 = w[:, None], w[:, None, None]
        qpos = a.qpos + w1 * (b.qpos - a.qpos)
        qpos[:, 3:7] = _nlerp(a.qpos[:, 3:7], b.qpos[:, 3:7], w1)
        state.qpos[rows] = qpos
        state.qvel[rows] = a.qvel + w1 * (b.qvel - a.qvel)
        state.body_pos[rows] = a.body_pos + w2 * (b.body_pos - a.body_pos)
        state.body_rot[rows] = _nlerp(a.body_rot, b.body_rot, w2)
        state.body_linvel[rows] = a.body_linvel + w2 * (b.body_linvel - a.body_linvel)
        state.body_angvel[rows] = a.body_angvel + w2 * (b.body_angvel - a.body_angvel)

    def sample_starts(
        self, n: int, rng: np.random.Generator, weights: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Draws (clip, start time) for reference state initialisation.

        Clips are drawn with probability proportional to ``weights`` (uniform by default); the start is a grid
        frame drawn uniformly among those that leave at least one step to play.

        Returns:
            clip_ids (n,) and times (n,) in seconds.
        """
        if weights is None:
            p = np.full(self.num_clips, 1.0 / self.num_clips)
        else:
            weights = np.asarray(weights, dtype=np.float64)
            if weights.shape != (self.num_clips,) or np.any(weights < 0) or weights.sum() <= 0:
                raise ValueError(f"clip weights must be {self.num_clips} non-negative numbers, not all zero")
            p = weights / weights.sum()
        clip_ids = rng.choice(self.num_clips, size=n, p=p)
        # Wrap clips: frames whose time lies in [0, duration); one-shot clips: all but the last frame.
        last = np.where(self.loop, np.ceil(self.duration / self.dt - 1e-9), self.num_frames - 1)
        frame = np.floor(rng.random(n) * last[clip_ids]).astype(np.int64)
        return clip_ids, frame * self.dt


def _nlerp(q0: np.ndarray, q1: np.ndarray, w: np.ndarray) -> np.ndarray:
    q1 = np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0, -q1, q1)
    return quat_normalize(q0 + w * (q1 - q0))


def _rotate_z(v: np.ndarray, c: np.ndarray, s: np.ndarray) -> None:
    """Rotates vectors about +z in place: (x, y) -> (c x - s y, s x + c y). c, s broadcast against v[..., 0]."""
    x = v[..., 0].copy()
    v[..., 0] = c * x - s * v[..., 1]
    v[..., 1] = s * x + c * v[..., 1]


def _yaw_mul(q: np.ndarray, c: np.ndarray, s: np.ndarray) -> None:
    """Left-multiplies quaternions in place by (c, 0, 0, s), a rotation about +z: by components (w, x, y, z)."""
    w, x, y, z = (q[..., i].copy() for i in range(4))
    q[..., 0] = c * w - s * z
    q[..., 1] = c * x - s * y
    q[..., 2] = c * y + s * x
    q[..., 3] = c * z + s * w


def _move_yaw(state: CharacterState, yaw: np.ndarray, shift: np.ndarray) -> None:
    """Applies a ground-plane transform (rotation ``yaw`` about z, then ``shift``) to a state, in place.

    Written for rotations about z only: a handful of component operations instead of general quaternion maths.
    """
    c, s = np.cos(yaw), np.sin(yaw)
    ch, sh = np.cos(0.5 * yaw), np.sin(0.5 * yaw)
    cb, sb, chb, shb = c[:, None], s[:, None], ch[:, None], sh[:, None]
    _rotate_z(state.qpos[:, 0:3], c, s)
    state.qpos[:, 0:2] += shift[:, :2]
    _yaw_mul(state.qpos[:, 3:7], ch, sh)
    _rotate_z(state.qvel[:, 0:3], c, s)
    _rotate_z(state.body_pos, cb, sb)
    state.body_pos[..., :2] += shift[:, None, :2]
    _yaw_mul(state.body_rot, chb, shb)
    _rotate_z(state.body_linvel, cb, sb)
    _rotate_z(state.body_angvel, cb, sb)
