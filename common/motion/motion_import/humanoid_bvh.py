"""A clip as BVH on the humanoid3d skeleton (centimetres, Y up or Z up), the form ``maps/humanoid3d.yaml`` reads.

One BVH joint per body, named as the body, with the body's zero-pose offset; the pelvis carries the root position.
Each joint's rotation channels use one of the six Euler orders in turn, so that a round trip exercises all of them.
The head and the feet get End Sites along the tips of ``maps/humanoid3d.yaml``; the hands have no channels (they are
welded to the forearms).
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from common.character.humanoid import Humanoid
from common.motion.motion import Clip, MotionFormatError
from common.motion.motion_import.bvh import BvhJoint, quat_to_euler, write_bvh
from common.motion.motion_import.deepmimic import check_writable, z_up_to_y_up_pos, z_up_to_y_up_quat
from common.motion.motion_import.retarget import zero_pose

CM = 100.0
ORDERS = tuple("".join(p) for p in itertools.permutations("ZYX"))
# End Sites (Z up, metres, body frame): the directions of maps/humanoid3d.yaml's tips.
END_SITES = {"head": (0.0, 0.0, 0.2), "right_foot": (0.1, 0.0, -0.02), "left_foot": (0.1, 0.0, -0.02)}


def humanoid_bvh(clip: Clip, humanoid: Humanoid, up: str = "y") -> tuple[tuple[BvhJoint, ...], float, np.ndarray]:
    """The BVH hierarchy, frame time and motion rows of ``clip`` on the humanoid3d skeleton.

    Args:
        clip: The clip (Z up, metres).
        humanoid: The character.
        up: ``"y"``: DeepMimic's frame, (x, y, z) -> (x, z, -y); ``"z"``: the project's own axes.

    Raises:
        MotionFormatError: a clip the DeepMimic reader would refuse (:func:`check_writable`: one keyframe, a frame
            time or a root out of bounds, ...), or keyframes not evenly spaced (BVH has one frame time).
    """
    check_writable(clip)
    steps = np.diff(clip.times)
    if not np.allclose(steps, steps[0], rtol=1e-6, atol=1e-9):
        raise MotionFormatError(f"{clip.source}: keyframes are not evenly spaced; BVH needs one frame time")
    if up not in ("y", "z"):
        raise ValueError(f"up must be 'y' or 'z', got {up!r}")
    pos_axes = z_up_to_y_up_pos if up == "y" else np.asarray
    rot_axes = z_up_to_y_up_quat if up == "y" else np.asarray
    zero = zero_pose(humanoid)
    parent = humanoid.parent_index
    group_of = {g.body: j for j, g in enumerate(humanoid.joint_groups)}
    joints, columns, column = [], [], 0
    for b, name in enumerate(humanoid.body_names):
        offset = zero[b] - (zero[parent[b]] if parent[b] >= 0 else zero[b])
        order = ORDERS[b % len(ORDERS)]
        rot = tuple(f"{a}rotation" for a in order)
        if parent[b] < 0:
            channels, q, pos = ("Xposition", "Yposition", "Zposition", *rot), clip.root_rot, clip.root_pos
            columns.append(np.concatenate([pos_axes(pos) * CM, quat_to_euler(rot_axes(q), order)], axis=-1))
        elif name in group_of:
            channels = rot
            columns.append(quat_to_euler(rot_axes(clip.joint_rot[:, group_of[name]]), order))
        else:
            channels = ()
        end = END_SITES.get(name)
        joints.append(BvhJoint(name, int(parent[b]), pos_axes(offset) * CM, channels, column,
                               None if end is None else pos_axes(np.array(end)) * CM))  # fmt: skip
        column += len(channels)
    return tuple(joints), float(steps[0]), np.concatenate(columns, axis=-1)


def write_humanoid_bvh(path: str | Path, clip: Clip, humanoid: Humanoid, up: str = "y") -> None:
    """Writes ``clip`` as a BVH file on the humanoid3d skeleton (see :func:`humanoid_bvh`)."""
    write_bvh(path, *humanoid_bvh(clip, humanoid, up))
