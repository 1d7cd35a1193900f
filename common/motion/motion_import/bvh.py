"""Reading and writing BVH motion capture files, and their forward kinematics.

A BVH file has a ``HIERARCHY`` (joints with an ``OFFSET`` from their parent, a ``CHANNELS`` list and optional
``End Site`` leaves) and a ``MOTION`` block (``Frames:``, ``Frame Time:`` and one row of channel values per frame).

Conventions, as in the format's usual readers (Biovision's definition, Blender, MotionBuilder):

* Rotation channels are degrees. A joint's rotation channels, in the order listed, compose as *intrinsic* rotations:
  ``Zrotation Xrotation Yrotation`` is ``R = Rz(a) Rx(b) Ry(c)``, so a child offset ``v`` sits at ``R v`` in the
  parent's frame. Any permutation (and any subset) of the three axes is accepted.
* A joint with position channels takes its translation from them (any order of X/Y/Z); its ``OFFSET`` is then only
  the rest translation. Joints without position channels are translated by their ``OFFSET``.
* Units and the up axis are whatever the file used; :mod:`common.motion.motion_import.retarget` converts them.

Errors name the file, the line and the problem (:class:`BvhFormatError`, a
:class:`~common.motion.errors.MotionFormatError`). The bounds of :mod:`common.motion.limits` apply: the frame time,
the number of frames, the depth and size of the hierarchy, and every number's size.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from common.maths.rotations import quat_mul, quat_rotate, quat_to_matrix
from common.motion.errors import MotionFormatError
from common.motion.limits import (
    MAX_BVH_DEPTH,
    MAX_BVH_JOINTS,
    MAX_BVH_VALUE,
    MAX_FRAME_DURATION,
    MAX_KEYFRAMES,
    MIN_FRAME_DURATION,
    check_regular_file,
)

ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
END_SUFFIX = "/end"  # names an End Site in joint maps: "Head/end" is the End Site below joint "Head"


class BvhFormatError(MotionFormatError):
    """A BVH file that cannot be read; the message names the file, the line and the problem."""


@dataclass(frozen=True)
class BvhJoint:
    """One joint of a BVH hierarchy.

    Attributes:
        name: Joint name.
        parent: Index of the parent joint, -1 for the root.
        offset: Translation from the parent joint in the parent's frame (file units). Shape: (3,).
        channels: Channel names in file order, e.g. ``("Zrotation", "Xrotation", "Yrotation")``.
        column: Column of the first channel in a motion row.
        end_site: Offset of the joint's End Site, or None. Shape: (3,).
    """

    name: str
    parent: int
    offset: np.ndarray
    channels: tuple[str, ...]
    column: int
    end_site: np.ndarray | None = None

    @property
    def rotation_order(self) -> str:
        """The rotation axes in channel order, e.g. ``"ZXY"``."""
        return "".join(c[0] for c in self.channels if c in ROTATION_CHANNELS)


@dataclass(frozen=True)
class Bvh:
    """A parsed BVH file.

    Attributes:
        source: The file (for messages).
        joints: Joints in file order (parents before children).
        frame_time: Seconds per frame.
        motion: Channel values per frame (degrees, file units). Shape: (F, C).
    """

    source: str
    joints: tuple[BvhJoint, ...]
    frame_time: float
    motion: np.ndarray

    @property
    def num_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"{self.source}: no joint '{name}'") from None


class _Lines:
    """The file's non-empty lines as token lists, with their line numbers, for error messages."""

    def __init__(self, path: Path, text: str) -> None:
        self.path = path
        self.items = [(n, line.split()) for n, line in enumerate(text.splitlines(), 1) if line.strip()]
        self.pos = 0

    def error(self, problem: str, line: int | None = None) -> BvhFormatError:
        if line is None:
            line = self.items[min(self.pos, len(self.items) - 1)][0] if self.items else 1
        return BvhFormatError(f"{self.path}: line {line}: {problem}")

    def next(self, what: str) -> tuple[int, list[str]]:
        if self.pos >= len(self.items):
            last = self.items[-1][0] if self.items else 1
            raise self.error(f"file ends where {what} was expected", last)
        item = self.items[self.pos]
        self.pos += 1
        return item


def _floats(lines: _Lines, line: int, tokens: list[str], count: int, what: str) -> np.ndarray:
    if len(tokens) != count:
        raise lines.error(f"{what} needs {count} numbers, got {len(tokens)}", line)
    try:
        values = np.array([float(t) for t in tokens])
    except ValueError:
        raise lines.error(f"{what}: not a number in {_short(' '.join(tokens))!r}", line) from None
    if not np.all(np.isfinite(values)):
        raise lines.error(f"{what}: value {_short(tokens[int(np.flatnonzero(~np.isfinite(values))[0])])} is not finite",
                          line)  # fmt: skip
    big = np.flatnonzero(np.abs(values) > MAX_BVH_VALUE)
    if len(big):
        raise lines.error(f"{what}: value {values[big[0]]:.6g} is beyond +-{MAX_BVH_VALUE:g} (file units or degrees)",
                          line)  # fmt: skip
    return values


def _short(text: str, limit: int = 40) -> str:
    """``text`` cut to ``limit`` characters for a message (a 5,000-digit number stays one readable line)."""
    return text if len(text) <= limit else f"{text[: limit - 3]}... ({len(text):,} characters)"


def _block_start(lines: _Lines, what: str) -> np.ndarray:
    """Reads the ``{`` and ``OFFSET x y z`` that open a joint or End Site block; returns the offset."""
    n, tok = lines.next("'{'")
    if tok != ["{"]:
        raise lines.error(f"expected '{{' after {what}, got {' '.join(tok)!r}", n)
    n, tok = lines.next("OFFSET")
    if tok[0] != "OFFSET":
        raise lines.error(f"{what}: expected OFFSET, got {tok[0]!r}", n)
    return _floats(lines, n, tok[1:], 3, "OFFSET")


def _joint(lines: _Lines, joints: list[BvhJoint], name: str, parent: int, column: int, depth: int = 1) -> int:
    """Parses one joint block (after its ``ROOT``/``JOINT`` line); returns the next free motion column.

    ``depth`` counts the joints from the root to this one; deeper than :data:`~common.motion.limits.MAX_BVH_DEPTH`
    is refused before recursing further (3,000 nested joints ran Python out of stack).
    """
    here = lines.items[lines.pos - 1][0]  # the ROOT or JOINT line
    if depth > MAX_BVH_DEPTH:
        raise lines.error(f"joint '{name}' is {depth} joints deep; at most {MAX_BVH_DEPTH} are read", here)
    if len(joints) >= MAX_BVH_JOINTS:
        raise lines.error(f"joint '{name}': more than {MAX_BVH_JOINTS} joints", here)
    offset = _block_start(lines, f"joint '{name}'")
    n, tok = lines.next("CHANNELS")
    if tok[0] != "CHANNELS" or len(tok) < 2:
        raise lines.error(f"joint '{name}': expected CHANNELS, got {' '.join(tok)!r}", n)
    try:
        count = int(tok[1])
    except ValueError:
        raise lines.error(f"joint '{name}': channel count {tok[1]!r} is not an integer", n) from None
    channels = tuple(tok[2:])
    if count != len(channels):
        raise lines.error(f"joint '{name}': CHANNELS says {count} but lists {len(channels)}", n)
    for c in channels:
        if c not in ROTATION_CHANNELS + POSITION_CHANNELS:
            raise lines.error(f"joint '{name}': unknown channel {c!r}", n)
    if len(set(channels)) != len(channels):
        raise lines.error(f"joint '{name}': a channel is listed twice", n)
    if name in (j.name for j in joints):
        raise lines.error(f"joint name '{name}' is used twice", n)
    index = len(joints)
    joints.append(BvhJoint(name, parent, offset, channels, column))
    column += count
    while True:
        n, tok = lines.next(f"'}}' closing joint '{name}'")
        if tok == ["}"]:
            return column
        if tok[0] == "JOINT" and len(tok) == 2:
            column = _joint(lines, joints, tok[1], index, column, depth + 1)
        elif tok[:2] == ["End", "Site"]:
            site = _end_site(lines, name)
            old = joints[index]
            joints[index] = BvhJoint(old.name, old.parent, old.offset, old.channels, old.column, site)
        else:
            raise lines.error(f"joint '{name}': expected JOINT, End Site or '}}', got {' '.join(tok)!r}", n)


def _end_site(lines: _Lines, name: str) -> np.ndarray:
    offset = _block_start(lines, f"End Site of '{name}'")
    n, tok = lines.next("'}'")
    if tok != ["}"]:
        raise lines.error(f"End Site of '{name}': expected '}}', got {' '.join(tok)!r}", n)
    return offset


def _header_value(lines: _Lines, key: str) -> tuple[int, str]:
    n, tok = lines.next(key)
    words = key.split()
    if tok[: len(words)] != words or len(tok) != len(words) + 1:
        raise lines.error(f"expected '{key} <value>', got {' '.join(tok)!r}", n)
    return n, tok[-1]


def parse_bvh(text: str, source: str | Path = "<bvh>") -> Bvh:
    """Parses BVH text (see :func:`read_bvh`)."""
    lines = _Lines(Path(source), text)
    n, tok = lines.next("HIERARCHY")
    if tok != ["HIERARCHY"]:
        raise lines.error(f"expected HIERARCHY, got {' '.join(tok)!r}", n)
    n, tok = lines.next("ROOT")
    if tok[0] != "ROOT" or len(tok) != 2:
        raise lines.error(f"expected 'ROOT <name>', got {' '.join(tok)!r}", n)
    joints: list[BvhJoint] = []
    columns = _joint(lines, joints, tok[1], -1, 0)
    if lines.pos >= len(lines.items) or lines.items[lines.pos][1] != ["MOTION"]:
        where = lines.items[lines.pos][0] if lines.pos < len(lines.items) else lines.items[-1][0]
        got = " ".join(lines.items[lines.pos][1]) if lines.pos < len(lines.items) else "the end of the file"
        raise lines.error(f"missing MOTION after the hierarchy (got {got!r}; one ROOT per file)", where)
    lines.pos += 1
    n, value = _header_value(lines, "Frames:")
    if value.isdigit() and len(value) > len(str(MAX_KEYFRAMES)):
        raise lines.error(f"frame count {_short(value)} is more than {MAX_KEYFRAMES:,}", n)
    try:
        frames = int(value)
    except ValueError:
        raise lines.error(f"frame count {_short(value)!r} is not an integer", n) from None
    if frames < 1:
        raise lines.error(f"frame count must be >= 1, got {frames}", n)
    if frames > MAX_KEYFRAMES:
        raise lines.error(f"frame count {frames:,} is more than {MAX_KEYFRAMES:,}", n)
    n, value = _header_value(lines, "Frame Time:")
    try:
        frame_time = float(value)
    except ValueError:
        raise lines.error(f"frame time {_short(value)!r} is not a number", n) from None
    if not (math.isfinite(frame_time) and frame_time > 0):
        raise lines.error(f"frame time must be positive, got {_short(value)}", n)
    if not MIN_FRAME_DURATION <= frame_time <= MAX_FRAME_DURATION:
        raise lines.error(f"frame time {frame_time:g} s is outside {MIN_FRAME_DURATION:g} to {MAX_FRAME_DURATION:g} s",
                          n)  # fmt: skip
    rows = lines.items[lines.pos :]
    if len(rows) != frames:
        raise lines.error(f"'Frames: {frames}' but {len(rows)} frame rows follow", rows[-1][0] if rows else n)
    motion = np.empty((frames, columns))
    for f, (n, tok) in enumerate(rows):
        motion[f] = _floats(lines, n, tok, columns, f"frame {f}")
    return Bvh(str(source), tuple(joints), frame_time, motion)


def read_bvh(path: str | Path) -> Bvh:
    """Reads a BVH file.

    Raises:
        BvhFormatError: naming the file, the line and the problem (not a regular file or too large, missing MOTION, a
            row of the wrong length, a value that is not a finite number or beyond the bounds, a frame time out of
            bounds, a malformed or too deep hierarchy, ...).
    """
    path = Path(path)
    check_regular_file(path, BvhFormatError)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise BvhFormatError(f"{path}: cannot read ({e.strerror})") from None
    return parse_bvh(text, path)


def _axis_quat(axis: str, degrees: np.ndarray) -> np.ndarray:
    half = np.radians(degrees) * 0.5
    q = np.zeros((*half.shape, 4))
    q[..., 0] = np.cos(half)
    q[..., 1 + "XYZ".index(axis)] = np.sin(half)
    return q


def euler_to_quat(degrees: np.ndarray, order: str) -> np.ndarray:
    """Intrinsic Euler angles in ``order`` (e.g. ``"ZXY"``) -> quaternions ``q1 * q2 * q3``. (..., k) -> (..., 4)."""
    q = np.zeros((*degrees.shape[:-1], 4))
    q[..., 0] = 1.0
    for i, axis in enumerate(order):
        q = quat_mul(q, _axis_quat(axis, degrees[..., i]))
    return q


def quat_to_euler(q: np.ndarray, order: str) -> np.ndarray:
    """Intrinsic Euler angles in degrees, (..., 4) -> (..., 3), for any order of three distinct axes.

    With R = R_i(a) R_j(b) R_k(c) and s = +1 for a cyclic order (XYZ, YZX, ZXY), -1 otherwise:
    b = asin(s R_ik), a = atan2(-s R_jk, R_kk), c = atan2(-s R_ij, R_ii).
    """
    i, j, k = ("XYZ".index(a) for a in order)
    s = 1.0 if (j - i) % 3 == 1 else -1.0
    m = quat_to_matrix(q)
    b = np.arcsin(np.clip(s * m[..., i, k], -1.0, 1.0))
    a = np.arctan2(-s * m[..., j, k], m[..., k, k])
    c = np.arctan2(-s * m[..., i, j], m[..., i, i])
    return np.degrees(np.stack([a, b, c], axis=-1))


def local_transforms(bvh: Bvh) -> tuple[np.ndarray, np.ndarray]:
    """Every joint's translation and rotation relative to its parent, per frame.

    Returns:
        (translation (F, J, 3) in file units, rotation (F, J, 4) unit quaternions).
    """
    f = bvh.num_frames
    trans = np.empty((f, len(bvh.joints), 3))
    rot = np.empty((f, len(bvh.joints), 4))
    for j, joint in enumerate(bvh.joints):
        trans[:, j] = joint.offset
        cols = {c: bvh.motion[:, joint.column + i] for i, c in enumerate(joint.channels)}
        if any(c in cols for c in POSITION_CHANNELS):
            for axis, c in enumerate(POSITION_CHANNELS):
                trans[:, j, axis] = cols.get(c, 0.0)
        order = joint.rotation_order
        angles = np.stack([cols[f"{a}rotation"] for a in order], axis=-1) if order else np.zeros((f, 0))
        rot[:, j] = euler_to_quat(angles, order)
    return trans, rot


def forward_kinematics(bvh: Bvh) -> tuple[np.ndarray, np.ndarray]:
    """World position and rotation of every joint, per frame, in the file's frame and units.

    Returns:
        (positions (F, J, 3), rotations (F, J, 4)).
    """
    trans, rot = local_transforms(bvh)
    pos = np.empty_like(trans)
    world = np.empty_like(rot)
    for j, joint in enumerate(bvh.joints):
        if joint.parent < 0:
            pos[:, j], world[:, j] = trans[:, j], rot[:, j]
        else:
            p = joint.parent
            pos[:, j] = pos[:, p] + quat_rotate(world[:, p], trans[:, j])
            world[:, j] = quat_mul(world[:, p], rot[:, j])
    return pos, world


def rest_positions(bvh: Bvh) -> dict[str, np.ndarray]:
    """Positions of every joint and End Site (``"<joint>/end"``) in the rest pose (all rotations zero, offsets only).

    Returns:
        Name -> position (3,) in file units, the root at its OFFSET.
    """
    out: dict[str, np.ndarray] = {}
    for joint in bvh.joints:
        base = out[bvh.joints[joint.parent].name] if joint.parent >= 0 else np.zeros(3)
        out[joint.name] = base + joint.offset
        if joint.end_site is not None:
            out[joint.name + END_SUFFIX] = out[joint.name] + joint.end_site
    return out


def write_bvh(path: str | Path, joints: tuple[BvhJoint, ...], frame_time: float, motion: np.ndarray) -> None:
    """Writes a BVH file (atomically: to a temporary file renamed over ``path`` when complete).

    Args:
        path: Output file.
        joints: Hierarchy in file order (parents before children, each joint's channels at its ``column``).
        frame_time: Seconds per frame.
        motion: Channel values. Shape: (F, C).

    Raises:
        BvhFormatError: what :func:`read_bvh` would refuse in the file (a hierarchy too deep, a frame time or a value
            out of bounds, ...): the text is parsed before it is written, and nothing is written.
    """
    path = Path(path)
    children: dict[int, list[int]] = {}
    depth = np.zeros(len(joints), dtype=np.int64)
    for j, joint in enumerate(joints):
        children.setdefault(joint.parent, []).append(j)
        depth[j] = depth[joint.parent] + 1 if joint.parent >= 0 else 1
    if len(joints) and depth.max() > MAX_BVH_DEPTH:  # the writer recurses as the reader does
        raise BvhFormatError(f"{path}: a hierarchy {depth.max()} joints deep; at most {MAX_BVH_DEPTH} are read")
    out = ["HIERARCHY"]

    def block(j: int, depth: int) -> None:
        pad, joint = "\t" * depth, joints[j]
        out.append(f"{pad}{'ROOT' if joint.parent < 0 else 'JOINT'} {joint.name}")
        out.append(f"{pad}{{")
        out.append(f"{pad}\tOFFSET {' '.join(f'{v:.6f}' for v in joint.offset)}")
        out.append(f"{pad}\tCHANNELS {len(joint.channels)} {' '.join(joint.channels)}".rstrip())
        for c in children.get(j, []):
            block(c, depth + 1)
        if joint.end_site is not None:
            site = " ".join(f"{v:.6f}" for v in joint.end_site)
            out.extend([f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {site}", f"{pad}\t}}"])
        out.append(f"{pad}}}")

    block(children[-1][0], 0)
    out += ["MOTION", f"Frames: {len(motion)}", f"Frame Time: {frame_time:.9g}"]
    out += [" ".join(f"{v:.6f}" for v in row) for row in motion]
    text = "\n".join(out) + "\n"
    parse_bvh(text, path)  # what is written, the reader takes
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
