"""The BVH reader and writer: the shipped CMU take, hand-written tiny files and malformed ones."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest

from common.maths.rotations import quat_to_matrix
from common.motion.motion_import import bundled_bvh_dir
from common.motion.motion_import.bvh import (
    BvhFormatError,
    euler_to_quat,
    forward_kinematics,
    parse_bvh,
    quat_to_euler,
    read_bvh,
    rest_positions,
    write_bvh,
)

ORDERS = ["".join(p) for p in itertools.permutations("XYZ")]


def _rot(axis: str, degrees: float) -> np.ndarray:
    """Rotation matrix about one axis, written out (independent of the quaternion code)."""
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return {"X": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "Y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "Z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]  # fmt: skip


def _one_joint(order: str, angles: tuple[float, ...], position_order: str = "XYZ", position=(0.0, 0.0, 0.0)) -> str:
    """A root with position and rotation channels and a child joint one unit up (+y) with an End Site."""
    value = dict(zip("XYZ", position, strict=True))
    pos_ch = " ".join(f"{a}position" for a in position_order)
    rot_ch = " ".join(f"{a}rotation" for a in order)
    row = [value[a] for a in position_order] + list(angles) + [0.0, 0.0, 0.0]
    return f"""HIERARCHY
ROOT hips
{{
  OFFSET 0 0 0
  CHANNELS 6 {pos_ch} {rot_ch}
  JOINT spine
  {{
    OFFSET 0 1 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {{
      OFFSET 0 0 2
    }}
  }}
}}
MOTION
Frames: 1
Frame Time: 0.02
{" ".join(str(v) for v in row)}
"""


def test_shipped_take_reads_as_documented() -> None:
    bvh = read_bvh(bundled_bvh_dir() / "131_01.bvh")
    assert len(bvh.joints) == 31 and bvh.num_frames == 994 and bvh.frame_time == pytest.approx(0.0083333)
    assert bvh.motion.shape == (994, 6 + 30 * 3)
    root = bvh.joints[0]
    assert root.name == "Hips" and root.channels[:3] == ("Xposition", "Yposition", "Zposition")
    assert root.rotation_order == "ZYX" and bvh.joints[bvh.index("LeftShoulder")].rotation_order == "ZXY"
    rest = rest_positions(bvh)
    np.testing.assert_allclose(rest["LeftHip"], [1.24777, -1.64261, 0.71711])
    # LeftToe's End Site: LeftToe at Hips + the offsets of LeftHip, LeftKnee, LeftAnkle, LeftToe, plus the site.
    np.testing.assert_allclose(rest["LeftToe/end"][2], 0.71711 + 2.21395 + 1.13491)
    pos, _ = forward_kinematics(bvh)
    np.testing.assert_allclose(pos[0, 0], [5.2300, 16.9002, -33.8986])  # the first row's root channels


@pytest.mark.parametrize("order", ORDERS)
def test_every_rotation_order_is_intrinsic_in_listed_order(order: str) -> None:
    angles = (30.0, -45.0, 60.0)
    bvh = parse_bvh(_one_joint(order, angles), "tiny.bvh")
    assert bvh.joints[0].rotation_order == order
    expected = _rot(order[0], angles[0]) @ _rot(order[1], angles[1]) @ _rot(order[2], angles[2])
    pos, rot = forward_kinematics(bvh)
    np.testing.assert_allclose(quat_to_matrix(rot[0, 0]), expected, atol=1e-12)
    np.testing.assert_allclose(pos[0, 1], expected @ [0.0, 1.0, 0.0], atol=1e-12)


def test_rotation_hand_worked() -> None:
    # ZXY (90, 90, 0) = Rz(90) Rx(90): Rx(90) takes +y to +z, Rz(90) leaves +z; the End Site (0, 0, 2) of the
    # unrotated child goes to Rz(90) Rx(90) (0, 0, 2) = Rz(90) (0, -2, 0) = (2, 0, 0), added to the child at (0, 0, 1).
    bvh = parse_bvh(_one_joint("ZXY", (90.0, 90.0, 0.0)), "tiny.bvh")
    pos, rot = forward_kinematics(bvh)
    np.testing.assert_allclose(pos[0, 1], [0.0, 0.0, 1.0], atol=1e-12)
    from common.maths.rotations import quat_rotate

    np.testing.assert_allclose(pos[0, 1] + quat_rotate(rot[0, 1], bvh.joints[1].end_site), [2.0, 0.0, 1.0], atol=1e-12)
    # The extrinsic reading (Rx(90) Rz(90)) would put the child at (0, 0, 1) too but the site at (0, -2, 1): differ.


@pytest.mark.parametrize("position_order", ["XYZ", "ZXY", "YZX"])
def test_position_channels_in_any_order(position_order: str) -> None:
    bvh = parse_bvh(_one_joint("ZYX", (0.0, 0.0, 0.0), position_order, (1.0, 2.0, 3.0)), "tiny.bvh")
    pos, _ = forward_kinematics(bvh)
    np.testing.assert_allclose(pos[0, 0], [1.0, 2.0, 3.0])
    np.testing.assert_allclose(pos[0, 1], [1.0, 3.0, 3.0])


def test_end_site_and_rest_positions() -> None:
    bvh = parse_bvh(_one_joint("XYZ", (0.0, 0.0, 0.0)), "tiny.bvh")
    np.testing.assert_allclose(bvh.joints[1].end_site, [0.0, 0.0, 2.0])
    assert bvh.joints[0].end_site is None
    rest = rest_positions(bvh)
    assert sorted(rest) == ["hips", "spine", "spine/end"]
    np.testing.assert_allclose(rest["spine/end"], [0.0, 1.0, 2.0])


@pytest.mark.parametrize("order", ORDERS)
def test_quat_to_euler_inverts_euler_to_quat(order: str) -> None:
    rng = np.random.default_rng(3)
    angles = rng.uniform(-170.0, 170.0, (50, 3))
    angles[:, 1] = rng.uniform(-85.0, 85.0, 50)
    np.testing.assert_allclose(quat_to_euler(euler_to_quat(angles, order), order), angles, atol=1e-9)


def test_write_then_read_gives_the_file_back(tmp_path: Path) -> None:
    bvh = read_bvh(bundled_bvh_dir() / "131_01.bvh")
    write_bvh(tmp_path / "copy.bvh", bvh.joints, bvh.frame_time, bvh.motion[:20])
    back = read_bvh(tmp_path / "copy.bvh")
    assert back.names == bvh.names and back.frame_time == bvh.frame_time
    np.testing.assert_allclose(back.motion, bvh.motion[:20], atol=5e-7)
    for a, b in zip(back.joints, bvh.joints, strict=True):
        assert a.channels == b.channels and a.parent == b.parent
        np.testing.assert_allclose(a.offset, b.offset, atol=5e-7)
        assert (a.end_site is None) == (b.end_site is None)


def _malformed(kind: str) -> tuple[str, int, str]:
    """A broken variant of the tiny file: (text, line of the fault, words of the message)."""
    good = _one_joint("ZXY", (1.0, 2.0, 3.0)).splitlines()
    motion = good.index("MOTION") + 1  # 1-based line number of MOTION
    if kind == "missing MOTION":
        return "\n".join(good[: motion - 1] + good[motion:]), motion, "missing MOTION"
    if kind == "wrong row length":
        return "\n".join(good[:-1] + [good[-1] + " 4.0"]), motion + 3, "frame 0 needs 9 numbers, got 10"
    if kind == "NaN":
        return "\n".join(good[:-1] + [good[-1].replace("2.0", "nan", 1)]), motion + 3, "nan is not finite"
    if kind == "zero frame time":
        return "\n".join(good).replace("Frame Time: 0.02", "Frame Time: 0"), motion + 2, "frame time must be positive"
    if kind == "negative frame time":
        return "\n".join(good).replace("Frame Time: 0.02", "Frame Time: -0.01"), motion + 2, "must be positive"
    if kind == "too few rows":
        return "\n".join(good).replace("Frames: 1", "Frames: 2"), motion + 3, "'Frames: 2' but 1 frame rows follow"
    if kind == "unknown channel":
        # The root's CHANNELS line (line 5) ends in Yrotation for the order ZXY.
        return "\n".join(good).replace("Yrotation\n", "Wrotation\n", 1), 5, "unknown channel 'Wrotation'"
    raise AssertionError(kind)


@pytest.mark.parametrize("kind", ["missing MOTION", "wrong row length", "NaN", "zero frame time",
                                  "negative frame time", "too few rows", "unknown channel"])  # fmt: skip
def test_malformed_file_names_file_line_and_problem(tmp_path: Path, kind: str) -> None:
    text, line, words = _malformed(kind)
    path = tmp_path / "bad.bvh"
    path.write_text(text)
    with pytest.raises(BvhFormatError) as e:
        read_bvh(path)
    message = str(e.value)
    assert message.startswith(f"{path}: line {line}: "), message
    assert words in message and "\n" not in message


def test_child_with_position_channels_takes_its_translation_from_them() -> None:
    # Some exporters give every joint 6 channels; the channels then replace the OFFSET as the translation.
    six = "CHANNELS 6 Yposition Xposition Zposition Zrotation Xrotation Yrotation"
    text = _one_joint("ZYX", (0.0, 0.0, 90.0)).replace("CHANNELS 3 Zrotation Xrotation Yrotation", six)
    text = text.replace("0.0 0.0 0.0 0.0 0.0 90.0 0.0 0.0 0.0", "0.0 0.0 0.0 0.0 0.0 90.0 5.0 4.0 0.0 0.0 0.0 0.0")
    bvh = parse_bvh(text, "tiny.bvh")
    pos, _ = forward_kinematics(bvh)
    # Root: Rx(90) (the order ZYX with (0, 0, 90)); the child's translation (x, y, z) = (4, 5, 0) -> (4, 0, 5).
    np.testing.assert_allclose(pos[0, 1], [4.0, 0.0, 5.0], atol=1e-12)
