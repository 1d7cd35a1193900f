"""Every reader of motion data (clips, clip packs, motion datasets, BVH, joint maps, ``mimic-motions import``) and the
config loader, given bad inputs: one line naming the file and the problem, the reader's own error type, and nothing in
the workspace changed (no file written, none removed). Then every writer against its reader: what it writes, its
reader takes; what the reader would refuse, the writer refuses, writing nothing.

The bounds the cases cross are those of :mod:`common.motion.limits`. A case that could hang (a FIFO) runs under an
alarm, so that a reader that blocks fails the test instead of stopping the suite.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import signal
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

from common.character.humanoid import Humanoid
from common.config import ConfigError, load_config
from common.motion.dataset import bundled_motion_dir, load_dataset, load_motions, resolve_clips, save_dataset
from common.motion.library import MotionLibrary
from common.motion.limits import MAX_FRAME_DURATION, MIN_FRAME_DURATION
from common.motion.motion import Clip, MotionFormatError, read_clip_pack, read_deepmimic, write_clip_pack
from common.motion.motion_import import bundled_bvh_dir
from common.motion.motion_import.bvh import BvhFormatError, read_bvh
from common.motion.motion_import.deepmimic import clip_to_rows, write_deepmimic
from common.motion.motion_import.humanoid_bvh import write_humanoid_bvh
from common.motion.motion_import.joint_map import load_joint_map
from common.motion.motion_import.pipeline import ImportOptions, import_clip, write_clip
from ppo.config import PPOTrackerConfig

TAKE = bundled_bvh_dir() / "131_01.bvh"
CMU_MAP = Path(str(resources.files("common.motion.motion_import") / "maps" / "cmu.yaml"))


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory, humanoid: Humanoid) -> dict[str, Path]:
    """Good inputs that the cases damage: a clip, a clip pack, a two-clip motion dataset, a short CMU take."""
    base = tmp_path_factory.mktemp("good")
    shutil.copy(bundled_motion_dir() / "humanoid3d_walk.txt", base / "walk.txt")
    write_clip_pack(base / "pack.h5", [base / "walk.txt"])
    save_dataset(base / "motions.h5", MotionLibrary.from_clips(resolve_clips(["walk", "jog"]), humanoid), humanoid)
    (base / "take.bvh").write_text(_take_text(60))
    return {"clip": base / "walk.txt", "pack": base / "pack.h5", "dataset": base / "motions.h5",
            "bvh": base / "take.bvh"}  # fmt: skip


# ---- building bad inputs ------------------------------------------------------------------------------------------


def _row(dur: float | Any = 1 / 30) -> list[Any]:
    """One DeepMimic row: the character standing at 0.85 m, every rotation the identity (44 values)."""
    ident = [1.0, 0.0, 0.0, 0.0]
    row: list[Any] = [dur, 0.0, 0.85, 0.0, *ident]
    for kind in ("s", "s", "s", "r", "s", "s", "r", "s", "r", "s", "s", "r"):
        row += ident if kind == "s" else [0.0]
    return row


def _set(row: list[Any], column: int, value: Any) -> list[Any]:
    return [*row[:column], value, *row[column + 1 :]]


def _clip(rows: list[list[Any]], loop: Any = "none", name: str = "clip.txt") -> Callable[[Path, dict], Path]:
    """A maker writing a DeepMimic clip of these rows as JSON."""

    def make(ws: Path, good: dict[str, Path]) -> Path:
        path = ws / name
        path.write_text(json.dumps({"Loop": loop, "Frames": rows}))
        return path

    return make


def _text(text: str | bytes, name: str = "clip.txt") -> Callable[[Path, dict], Path]:
    """A maker writing this text (or bytes) as the file."""

    def make(ws: Path, good: dict[str, Path]) -> Path:
        path = ws / name
        if isinstance(text, bytes):
            path.write_bytes(text)
        else:
            path.write_text(text)
        return path

    return make


def _special(kind: str, name: str) -> Callable[[Path, dict], Path]:
    """A maker of what is not a regular file (a FIFO, a link to a device, a folder) or a huge sparse file."""

    def make(ws: Path, good: dict[str, Path]) -> Path:
        path = ws / name
        if kind == "fifo":
            os.mkfifo(path)
        elif kind == "device":
            path.symlink_to("/dev/zero")
        elif kind == "folder":
            path.mkdir()
        else:  # 300 MiB of nothing, sparse: no disk used
            with open(path, "wb") as f:
                f.truncate(300 * 2**20)
        return path

    return make


def _h5(which: str, edit: Callable[[h5py.File], None], name: str | None = None) -> Callable[[Path, dict], Path]:
    """A maker copying the good clip pack or dataset and editing the copy with h5py."""

    def make(ws: Path, good: dict[str, Path]) -> Path:
        path = ws / (name or good[which].name)
        shutil.copy(good[which], path)
        with h5py.File(path, "a") as f:
            edit(f)
        return path

    return make


def _replace(group: str, key: str, data: Any = None, **kwargs: Any) -> Callable[[h5py.File], None]:
    """An edit replacing array ``key`` of ``group`` (``data`` of None: a chunked array of that shape, never written)."""

    def edit(f: h5py.File) -> None:
        g = f[group] if group else f
        attrs = dict(g[key].attrs)
        del g[key]
        if data is None:
            g.create_dataset(key, chunks=True, compression="gzip", **kwargs)
        else:
            g.create_dataset(key, data=data, **kwargs)
        g[key].attrs.update(attrs)

    return edit


def _attr(path: str, key: str, value: Any) -> Callable[[h5py.File], None]:
    def edit(f: h5py.File) -> None:
        (f[path] if path else f).attrs[key] = value

    return edit


def _scale(path: str, column: int, value: float, rows: slice = slice(None)) -> Callable[[h5py.File], None]:
    """An edit setting column ``column`` of the rows of array ``path`` (as float64 where needed)."""

    def edit(f: h5py.File) -> None:
        data = f[path][()].astype(np.float64)
        data[rows, column] = value
        group, _, key = path.rpartition("/")
        _replace(group, key, data)(f)

    return edit


def _take_text(frames: int, frame_time: str = ".0083333", edit: Callable[[np.ndarray], None] | None = None) -> str:
    """The shipped CMU take cut to its first ``frames`` frames (``edit`` changes the motion rows in place)."""
    lines = TAKE.read_text().splitlines()
    motion = lines.index("MOTION")
    rows = np.array([[float(v) for v in line.split()] for line in lines[motion + 3 : motion + 3 + frames]])
    if edit is not None:
        edit(rows)
    return "\n".join([*lines[: motion + 1], f"Frames: {frames}", f"Frame Time: {frame_time}",
                      *(" ".join(f"{v:.4f}" for v in row) for row in rows)]) + "\n"  # fmt: skip


def _nested_bvh(depth: int) -> str:
    """A chain of ``depth`` joints, each inside the last."""
    channels = "CHANNELS 3 Zrotation Xrotation Yrotation"
    head = "".join(f"JOINT j{i}\n{{\nOFFSET 0 1 0\n{channels}\n" for i in range(1, depth))
    return (f"HIERARCHY\nROOT j0\n{{\nOFFSET 0 0 0\n{channels}\n{head}" + "}\n" * depth
            + f"MOTION\nFrames: 1\nFrame Time: 0.01\n{' '.join(['0'] * 3 * depth)}\n")  # fmt: skip


def _map(edit: Callable[[str], str]) -> Callable[[Path, dict], Path]:
    def make(ws: Path, good: dict[str, Path]) -> Path:
        path = ws / "map.yaml"
        path.write_text(edit(CMU_MAP.read_text()))
        return path

    return make


R = _row()
DIGITS = "9" * 5000


# ---- the cases ----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    """One bad input: ``make`` writes it into the workspace and returns its path; ``reader`` (a key of
    :func:`_readers`) reads it; the one line must match ``problem`` and the error be exactly ``error``."""

    id: str
    reader: str
    make: Callable[[Path, dict[str, Path]], Path]
    problem: str
    error: type[Exception] = MotionFormatError
    alarm_s: int = 60  # a FIFO is refused before it is opened: its cases wait 3 s at most


def _cases() -> Iterator[Case]:
    # fmt: off
    # DeepMimic clips (.txt), read as every command reads its --motions.
    yield Case("clip_fifo", "motions", _special("fifo", "pipe.txt"), r"not a regular file \(a FIFO \(named pipe\)\)",
               alarm_s=3)
    yield Case("clip_link_to_a_device", "motions", _special("device", "zero.txt"), r"not a regular file \(a device\)")
    yield Case("clip_folder_named_txt", "clip", _special("folder", "dir.txt"), r"not a regular file \(a directory\)")
    yield Case("clip_too_large", "motions", _special("sparse", "big.txt"),
               r"314,572,800 bytes, more than the 268,435,456 this reader takes")
    yield Case("clip_empty", "motions", _text(""), r"not valid JSON \(Expecting value: line 1 column 1")
    yield Case("clip_utf8_bom", "motions", _text("\ufeff" + json.dumps({"Frames": [R, R]})), "Unexpected UTF-8 BOM")
    yield Case("clip_nested_200k", "motions", _text("[" * 200_000 + "]" * 200_000), "JSON nested too deep to read")
    yield Case("clip_nested_in_a_frame", "motions",
               _text('{"Loop": "none", "Frames": ' + "[" * 200_000 + "]" * 200_000 + "}"), "nested too deep")
    yield Case("clip_integer_of_5000_digits", "motions", _text('{"Loop": "none", "Frames": [[' + DIGITS + "]]}"),
               "an integer of 5,000 digits; no value of a clip needs more than 20")
    yield Case("clip_negative_integer_of_5000_digits", "motions",
               _text('{"Frames": [[0.03, -' + DIGITS + "]]}"), "an integer of 5,000 digits")
    yield Case("clip_number_of_5000_digits", "motions",
               _text(json.dumps({"Frames": [R, R]}).replace("0.85", DIGITS + ".0", 1)),
               "frame 0: value inf at column 2 is not finite")
    yield Case("clip_duration_as_a_string", "motions", _clip([_set(R, 0, "0.0333"), R]),
               r"frame 0: column 0 holds '0.0333' \(a string\), not a number")
    yield Case("clip_position_true", "motions", _clip([R, _set(R, 2, True)]), "frame 1: column 2 holds true, not a")
    yield Case("clip_position_false", "motions", _clip([R, _set(R, 1, False)]), "column 1 holds false, not a number")
    yield Case("clip_quaternion_null", "motions", _clip([R, _set(R, 5, None)]), "column 5 holds null, not a number")
    yield Case("clip_value_a_list", "motions", _clip([R, _set(R, 9, [1.0])]), "column 9 holds a list, not a number")
    yield Case("clip_value_an_object", "motions", _clip([_set(R, 3, {"z": 0}), R]), "column 3 holds an object")
    yield Case("clip_frames_of_1e-9_s", "motions", _clip([_row(1e-9)] * 3),
               r"frame 0: frame duration 1e-09 s is below 0.0001 s")
    yield Case("clip_frame_of_59_s", "motions", _clip([R, _row(59.0), R]), "frame 1: frame duration 59 s is above 1 s")
    yield Case("clip_negative_duration", "motions", _clip([_row(-0.5), R]),
               "frame 0: frame duration must be positive, got -0.5")
    yield Case("clip_root_900_m_away", "motions", _clip([R, _set(R, 1, 900.0)]),
               r"frame 1: root 900 m from the origin, farther than 100 m")
    yield Case("clip_quaternion_of_1e200", "motions", _clip([R, _set(R, 4, 1e200)]),
               r"frame 1: quaternion of length 1e\+200 for joint 'root' is not a rotation \(lengths 0.1 to 10")
    yield Case("clip_quaternion_of_length_0.001", "motions", _clip([R, _set(R, 12, 1e-3)]),
               r"frame 1: quaternion of length 0.001 for joint 'neck' is not a rotation")
    yield Case("clip_knee_of_1e200_rad", "motions", _clip([R, _set(R, 20, 1e200)]),
               r"frame 1: 'right_knee' angle 1e\+200 rad is beyond 6.28319 rad")
    yield Case("clip_of_one_frame", "motions", _clip([R]), "a clip needs at least 2 frames, got 1")
    yield Case("clip_of_601_s", "motions", _clip([_row(1.0)] * 602), "the clip lasts 601 s, longer than 600 s")
    yield Case("clip_loop_a_number", "motions", _clip([R, R], loop=1), r"'Loop' must be one of .*, got 1$")
    yield Case("clip_loop_true", "motions", _clip([R, R], loop=True), r"'Loop' must be one of .*, got true$")
    yield Case("clip_a_list", "motions", _text(json.dumps([R, R])), "missing the 'Frames' key")
    yield Case("clip_frames_a_string", "motions", _text(json.dumps({"Frames": "abc"})), "no frames")
    yield Case("clip_frame_a_string", "motions", _text(json.dumps({"Frames": ["abc", R]})),
               r"frame 0: expected 44 values, got 'abc' \(a string\)")
    yield Case("clip_infinity", "motions", _text(json.dumps({"Frames": [R, _set(R, 1, float("inf"))]})),
               "frame 1: value inf at column 1 is not finite")
    yield Case("clip_key_twice", "motions", _text('{"Loop": "none", "Frames": [' + json.dumps(R) + "],\n"
                                                  ' "Frames": [' + json.dumps(R) + "]}"),
               r"not valid JSON \(duplicate key 'Frames' \(first at line 1\): line 2 column 2")
    yield Case("clip_key_twice_with_an_escape", "motions", _text('{"Loop": "none", "\\u004Coop": "wrap"}'),
               r"duplicate key 'Loop' \(first at line 1\): line 1 column 18")
    yield Case("clip_a_bvh_given_as_motions", "motions", lambda ws, good: Path(shutil.copy(good["bvh"], ws)),
               r"not a motion file .*import it with `mimic-motions import`")
    # Clip packs (.h5 of raw DeepMimic rows).
    no_clips = _h5("pack", lambda f: f.__delitem__("walk"))
    yield Case("pack_with_no_clips", "motions", no_clips, "a clip pack with no clips")
    yield Case("pack_rows_of_40", "motions", _h5("pack", _replace("", "walk", np.zeros((39, 40), np.float32))),
               r":walk: 'walk' has shape \(39, 40\), expected \(frames, 44\)")
    yield Case("pack_one_dimensional", "motions", _h5("pack", _replace("", "walk", np.zeros(44, np.float32))),
               r"'walk' has shape \(44,\), expected \(frames, 44\)")
    yield Case("pack_rows_of_strings", "motions", _h5("pack", _replace("", "walk", np.full((3, 44), b"0.5"))),
               r"'walk' holds \|S3 values, not numbers")
    yield Case("pack_rows_of_booleans", "motions", _h5("pack", _replace("", "walk", np.ones((3, 44), bool))),
               "'walk' holds bool values, not numbers")
    yield Case("pack_without_loop", "motions", _h5("pack", lambda f: f["walk"].attrs.__delitem__("loop")),
               ":walk: no 'loop' attribute")
    yield Case("pack_loop_a_number", "motions", _h5("pack", _attr("walk", "loop", 1)),
               ":walk: attribute 'loop' must be a string, got 1")
    yield Case("pack_negative_duration", "motions", _h5("pack", _scale("walk", 0, -0.03, slice(4, 5))),
               ":walk: frame 4: frame duration must be positive, got -0.03")
    yield Case("pack_frames_of_1e-9_s", "motions", _h5("pack", _scale("walk", 0, 1e-9)),
               r":walk: frame 0: frame duration 1e-09 s is below 0.0001 s")
    yield Case("pack_root_900_m_away", "motions", _h5("pack", _scale("walk", 3, 900.0, slice(7, 8))),
               r":walk: frame 7: root 900.* m from the origin, farther than 100 m")
    yield Case("pack_quaternion_of_1e200", "motions", _h5("pack", _scale("walk", 8, 1e200, slice(2, 3))),
               r":walk: frame 2: quaternion of length 1e\+200 for joint 'chest' is not a rotation")
    yield Case("pack_clip_a_group", "motions", _h5("pack", lambda f: (f.__delitem__("walk"), f.create_group("walk"))),
               r":walk: no 'walk' array \(a group is there\)")
    yield Case("pack_version_a_string", "motions", _h5("pack", _attr("", "version", "1")),
               r"attribute 'version' must be an integer, got '1' \(a string\)")
    yield Case("pack_of_a_million_rows_declared", "motions",
               _h5("pack", _replace("", "walk", shape=(10**6, 44), dtype="f4")),
               "'walk' has 1,000,000 rows, more than 300,000")
    yield Case("pack_fifo", "motions", _special("fifo", "pipe.h5"), r"not a regular file \(a FIFO", alarm_s=3)
    yield Case("pack_read_directly_not_a_pack", "pack", lambda ws, good: Path(shutil.copy(good["dataset"], ws)),
               "not a clip pack \\(format 'mimictrack.motion_dataset'\\)")
    # Motion datasets (.h5 of clips on the control grid with their states).
    walk = "clips/walk"
    yield Case("dataset_negative_duration", "motions", _h5("dataset", _attr(walk, "duration", -1.2666)),
               r"clip 'walk': duration -1.2666 s does not fit its 77 frames at 60 Hz \(1.26667 s\)")
    yield Case("dataset_duration_of_1e-9_s", "motions", _h5("dataset", _attr(walk, "duration", 1e-9)),
               "clip 'walk': duration 1e-09 s does not fit its 77 frames")
    yield Case("dataset_with_no_clips", "motions",
               _h5("dataset", lambda f: (f["clips"].__delitem__("walk"), f["clips"].__delitem__("jog"))),
               "a motion dataset with no clips")
    yield Case("dataset_without_clips_group", "motions", _h5("dataset", lambda f: f.__delitem__("clips")),
               "no 'clips' group; not a complete motion dataset")
    yield Case("dataset_qpos_of_30", "motions", _h5("dataset", _replace(walk, "qpos", np.zeros((77, 30)))),
               r"clip 'walk': 'qpos' has shape \(77, 30\), expected \(frames, 35\)")
    yield Case("dataset_body_pos_flat", "motions", _h5("dataset", _replace(walk, "body_pos", np.zeros((77, 45)))),
               r"'body_pos' has shape \(77, 45\), expected \(frames, 15, 3\)")
    yield Case("dataset_without_qvel", "motions", _h5("dataset", lambda f: f[walk].__delitem__("qvel")),
               "clip 'walk': no 'qvel' array")
    yield Case("dataset_fields_disagree_in_length", "motions",
               _h5("dataset", _replace(walk, "qvel", np.zeros((76, 34)))),
               r"clip 'walk': qvel has shape \(76, 34\), expected \(77, 34\)")
    yield Case("dataset_control_hz_a_string", "motions", _h5("dataset", _attr("", "control_hz", "60")),
               r"attribute 'control_hz' must be a finite number, got '60' \(a string\)")
    yield Case("dataset_control_hz_true", "motions", _h5("dataset", _attr("", "control_hz", True)),
               r"attribute 'control_hz' must be a finite number, got True \(a boolean\)")
    yield Case("dataset_version_a_string", "motions", _h5("dataset", _attr("", "version", "2")),
               "attribute 'version' must be an integer, got '2'")
    yield Case("dataset_loop_a_string", "motions", _h5("dataset", _attr(walk, "loop", "yes")),
               r"clip 'walk': attribute 'loop' must be true or false, got 'yes' \(a string\)")
    yield Case("dataset_duration_a_string", "motions", _h5("dataset", _attr(walk, "duration", "1.27")),
               "clip 'walk': attribute 'duration' must be a finite number, got '1.27'")
    yield Case("dataset_order_a_fraction", "motions", _h5("dataset", _attr(walk, "order", 0.5)),
               "clip 'walk': attribute 'order' must be an integer, got 0.5")
    yield Case("dataset_orders_repeated", "motions", _h5("dataset", _attr(walk, "order", 1)),
               r"two clips share one 'order' \(\[1, 1\]\)")
    yield Case("dataset_source_a_number", "motions", _h5("dataset", _attr(walk, "source", 3)),
               "clip 'walk': attribute 'source' must be a string, got 3")
    yield Case("dataset_body_names_a_number", "motions", _h5("dataset", _attr("", "body_names", 15)),
               "attribute 'body_names' must be a list of strings, got 15")
    yield Case("dataset_format_an_array", "motions", _h5("dataset", _attr("", "format", [1, 2])),
               r"neither a clip pack nor a motion dataset \(format '\[1 2\]'\)")
    yield Case("dataset_format_an_array_read_directly", "dataset", _h5("dataset", _attr("", "format", [1, 2])),
               r"attribute 'format' must be a string, got an array of shape \(2,\)")
    yield Case("dataset_root_900_m_away", "motions", _h5("dataset", _scale(f"{walk}/qpos", 0, 900.0, slice(5, 6))),
               r"clip 'walk': frame 5: root 900.* m from the origin, farther than 100 m")
    yield Case("dataset_quaternion_of_1e200", "motions",
               _h5("dataset", _scale(f"{walk}/qpos", 3, 1e200, slice(6, 7))),
               r"clip 'walk': frame 6: root quaternion is not a unit quaternion \(length off 1 by 1e\+200\)")
    yield Case("dataset_qpos_of_strings", "motions", _h5("dataset", _replace(walk, "qpos", np.full((77, 35), b"1"))),
               r"clip 'walk': 'qpos' holds \|S1 values, not numbers")
    yield Case("dataset_of_ten_million_frames_declared", "motions",
               _h5("dataset", _replace(walk, "qpos", shape=(10**7, 35), dtype="f8")),
               "10,000,051 frames in all, more than 2,000,000")
    yield Case("dataset_clip_of_40000_frames_declared", "motions",
               _h5("dataset", _replace(walk, "qpos", shape=(40_000, 35), dtype="f8")),
               "clip 'walk': 'qpos' has 40,000 rows, more than 36,003")
    yield Case("dataset_clip_of_one_frame", "motions", _h5("dataset", _one_frame), r"clip 'jog': 1 frame\(s\)")
    yield Case("dataset_cycle_shift_of_2", "motions", _h5("dataset", _replace(walk, "cycle_shift", np.zeros(2))),
               r"'cycle_shift' has shape \(2,\), expected \(3,\)")
    yield Case("dataset_cycle_yaw_nan", "motions", _h5("dataset", _attr(walk, "cycle_yaw", float("nan"))),
               "attribute 'cycle_yaw' must be a finite number, got nan")
    yield Case("dataset_clip_an_array", "motions",
               _h5("dataset", lambda f: (f["clips"].__delitem__("jog"), f["clips"].create_dataset("jog", data=[1.0]))),
               "clip 'jog': not a group of arrays")
    yield Case("dataset_fifo", "dataset", _special("fifo", "pipe.h5"), r"not a regular file \(a FIFO", alarm_s=3)
    yield Case("dataset_truncated", "motions", _truncated, "not a readable HDF5 file")
    # BVH takes.
    yield Case("bvh_3000_nested_joints", "bvh", _text(_nested_bvh(3000), "deep.bvh"),
               "line 258: joint 'j64' is 65 joints deep; at most 64 are read", BvhFormatError)
    yield Case("bvh_fifo", "bvh", _special("fifo", "pipe.bvh"), r"not a regular file \(a FIFO", BvhFormatError,
               alarm_s=3)
    yield Case("bvh_folder", "bvh", _special("folder", "dir.bvh"), r"not a regular file \(a directory", BvhFormatError)
    yield Case("bvh_too_large", "bvh", _special("sparse", "big.bvh"), "314,572,800 bytes", BvhFormatError)
    yield Case("bvh_frame_time_of_100_s", "bvh", _text(_take_text(3, "100"), "t.bvh"),
               "line 187: frame time 100 s is outside 0.0001 to 1 s", BvhFormatError)
    yield Case("bvh_frame_time_of_1e-9_s", "bvh", _text(_take_text(3, "1e-9"), "t.bvh"),
               "line 187: frame time 1e-09 s is outside 0.0001 to 1 s", BvhFormatError)
    yield Case("bvh_angle_of_1e200", "bvh", _text(_take_text(3).replace("-5.4029", "1e200", 1), "t.bvh"),
               r"line 188: frame 0: value 1e\+200 is beyond \+-1e\+06 \(file units or degrees\)", BvhFormatError)
    yield Case("bvh_frame_count_of_5000_digits", "bvh", _text(_take_text(3).replace("Frames: 3", f"Frames: {DIGITS}"),
               "t.bvh"), r"line 186: frame count 9{37}\.\.\. \(5,000 characters\) is more than 300,000", BvhFormatError)
    yield Case("bvh_offset_a_word", "bvh", _text(_take_text(3).replace("OFFSET 0 0 0", "OFFSET 0 zero 0", 1), "t.bvh"),
               "line 8: OFFSET: not a number in '0 zero 0'", BvhFormatError)
    yield Case("bvh_frames_true", "bvh", _text(_take_text(3).replace("Frames: 3", "Frames: true"), "t.bvh"),
               "line 186: frame count 'true' is not an integer", BvhFormatError)
    # mimic-motions import of a take: what it would write, every loader must take, or it refuses.
    yield Case("import_one_frame", "import", _text(_take_text(1), "one.bvh"), "a clip needs at least 2 frames, got 1")
    yield Case("import_frame_time_of_100_s", "import", _text(_take_text(5, "100"), "slow.bvh"),
               "frame time 100 s is outside", BvhFormatError)
    yield Case("import_root_1000_m_away", "import",
               _text(_take_text(5, edit=lambda rows: rows.__setitem__((slice(None), 0), 20_000.0)), "far.bvh"),
               r"frame 0: root \d+\.?\d* m from the origin, farther than 100 m")
    yield Case("import_shorter_than_a_control_step", "import", _text(_take_text(2), "short.bvh"),
               r"the clip lasts 0.008333 s, shorter than one control step \(0.01667 s\): no command could play it")
    # Joint maps (YAML).
    yield Case("map_fifo", "joint_map", _special("fifo", "map.yaml"), r"not a regular file \(a FIFO", alarm_s=3)
    yield Case("map_along_strings", "joint_map", _map(lambda t: t.replace("[0.0, 0.0, 1.0]", "['0', '0', '1']")),
               r"tips.head.along: expected a non-zero vector of 3 numbers \[x, y, z\], got \['0', '0', '1'\]")
    yield Case("map_along_true", "joint_map", _map(lambda t: t.replace("[0.0, 0.0, 1.0]", "[true, 0, 0]")),
               r"tips.head.along: expected a non-zero vector of 3 numbers")
    yield Case("map_nested_200k", "joint_map", _map(lambda t: t + "extra: " + "[" * 200_000 + "]" * 200_000 + "\n"),
               "not valid YAML")
    # A key given twice in one mapping: PyYAML would keep the last without a word.
    yield Case("map_body_mapped_twice", "joint_map", _map(lambda t: t.replace("  head: [Head]\n",
                                                                              "  head: [Head]\n  pelvis: [Spine]\n")),
               r"not valid YAML \(duplicate key 'pelvis' \(first at line \d+\) at line \d+, column 3\)")
    yield Case("map_tip_key_twice", "joint_map",
               _map(lambda t: t.replace("along: [0.0, 0.0, 1.0]}", "along: [0.0, 0.0, 1.0], along: [1, 0, 0]}")),
               r"duplicate key 'along' \(first at line (\d+)\) at line \1, column \d+")
    yield Case("map_up_twice", "joint_map", _map(lambda t: t + "up: z\n"),
               r"duplicate key 'up' \(first at line \d+\) at line \d+, column 1")
    # Configs (common/config.py): numbers must be numbers.
    yield Case("config_float_a_string", "config", _text("ppo:\n  actor_lr: '1e-3'\n", "c.yaml"),
               r"key 'ppo.actor_lr' expects float, got '1e-3' \(str\)", ConfigError)
    yield Case("config_float_true", "config", _text("ppo:\n  actor_lr: true\n", "c.yaml"),
               r"key 'ppo.actor_lr' expects float, got True \(bool\)", ConfigError)
    yield Case("config_int_true", "config", _text("gym:\n  num_envs: true\n", "c.yaml"),
               r"key 'gym.num_envs' expects int, got True \(bool\)", ConfigError)
    yield Case("config_int_a_string", "config", _text("gym:\n  num_envs: '8'\n", "c.yaml"),
               r"key 'gym.num_envs' expects int, got '8' \(str\)", ConfigError)
    yield Case("config_int_a_fraction", "config", _text("gym:\n  num_envs: 8.5\n", "c.yaml"),
               r"key 'gym.num_envs' expects int, got 8.5 \(float\)", ConfigError)
    yield Case("config_python_tag", "config", _text("ppo: !!python/object:os.system {}\n", "c.yaml"),
               "could not determine a constructor for the tag", ConfigError)
    yield Case("config_key_twice_at_the_top", "config", _text("ppo:\n  epochs: 2\nppo:\n  epochs: 3\n", "c.yaml"),
               r"invalid YAML: duplicate key 'ppo' \(first at line 1\) at line 3, column 1", ConfigError)
    yield Case("config_key_twice_in_a_section", "config", _text("gym: {num_envs: 8, num_envs: 16}\n", "c.yaml"),
               r"duplicate key 'num_envs' \(first at line 1\) at line 1, column 20", ConfigError)
    yield Case("config_key_twice_in_a_list_of_mappings", "config",
               _text("train:\n  motions:\n  - {clip: walk}\n  - {clip: run, clip: jog}\n", "c.yaml"),
               r"duplicate key 'clip' \(first at line 4\) at line 4, column 17", ConfigError)
    # fmt: on


def _one_frame(f: h5py.File) -> None:
    g = f["clips/jog"]
    for key in ("qpos", "qvel", "body_pos", "body_rot", "body_linvel", "body_angvel"):
        _replace("clips/jog", key, g[key][:1])(f)


def _truncated(ws: Path, good: dict[str, Path]) -> Path:
    data = good["dataset"].read_bytes()
    path = ws / "cut.h5"
    path.write_bytes(data[: len(data) // 2])
    return path


CASES = list(_cases())


def _readers(humanoid: Humanoid) -> dict[str, Callable[[Path], Any]]:
    def import_and_write(path: Path) -> None:
        clip, _ = import_clip(str(path), humanoid, ImportOptions(joint_map="cmu", fix_ground=True))
        write_clip(path.parent / "out.txt", clip, humanoid)

    return {
        "clip": read_deepmimic,
        "motions": lambda path: load_motions([str(path)], humanoid),
        "pack": read_clip_pack,
        "dataset": lambda path: load_dataset(path, humanoid),
        "bvh": read_bvh,
        "import": import_and_write,
        "joint_map": lambda path: load_joint_map(path, humanoid.body_names),
        "config": lambda path: load_config(PPOTrackerConfig, path),
    }


def _tree(root: Path) -> dict[str, Any]:
    """Every entry under ``root``: a file's size and digest, a link's target, a FIFO or folder's kind (never opened)."""
    out: dict[str, Any] = {}
    for p in sorted(root.rglob("*")):
        st = p.lstat()
        key = str(p.relative_to(root))
        if p.is_symlink():
            out[key] = ("link", os.readlink(p))
        elif p.is_fifo() or p.is_dir():
            out[key] = ("fifo" if p.is_fifo() else "dir",)
        elif st.st_size > 2**24:  # the sparse 300 MiB files: size and time of change
            out[key] = ("big", st.st_size, st.st_mtime_ns)
        else:
            out[key] = ("file", st.st_size, hashlib.sha256(p.read_bytes()).hexdigest())
    return out


def _on_alarm(signum: int, frame: object) -> None:
    raise TimeoutError("the reader blocked")


def test_the_corpus_is_large_and_its_ids_unique() -> None:
    ids = [c.id for c in CASES]
    assert len(set(ids)) == len(ids)
    assert len(ids) >= 100


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_a_reader_refuses_a_bad_input_in_one_line_naming_the_file(
    case: Case, good: dict[str, Path], humanoid: Humanoid, tmp_path: Path
) -> None:
    ws = tmp_path / "ws"
    ws.mkdir()
    path = case.make(ws, good)
    before = _tree(ws)
    previous = signal.signal(signal.SIGALRM, _on_alarm)
    signal.alarm(case.alarm_s)
    try:
        with pytest.raises(Exception) as caught:  # its type is checked exactly below
            _readers(humanoid)[case.reader](path)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    if not isinstance(caught.value, MotionFormatError | ConfigError):
        raise caught.value  # not the reader's own error: show it as it came (an xfail names the type it expects)
    message = str(caught.value)
    assert type(caught.value) is case.error, f"{type(caught.value).__name__}: {message}"
    assert "\n" not in message and len(message) < 400, message
    assert str(path) in message, message
    assert re.search(case.problem, message), message
    assert _tree(ws) == before  # nothing written, changed or removed


# ---- writers against their readers --------------------------------------------------------------------------------


def _edge(name: str) -> Clip:
    """Edge clips standing in walk's first pose: (keyframe count, frame duration, root offset, loop) by name."""
    walk = resolve_clips(["walk"])[0]
    count, step, offset, loop = {
        "one keyframe": (1, 1 / 30, 0.0, False),
        "frames of 100 s": (3, 100.0, 0.0, False),
        "frames of 1e-9 s": (3, 1e-9, 0.0, False),
        "frames of 1 s (the most)": (3, MAX_FRAME_DURATION, 0.0, False),
        "frames of 1e-4 s (the least)": (200, MIN_FRAME_DURATION, 0.0, False),
        "root 95 m away": (10, 1 / 30, 95.0, False),
        "root 900 m away": (10, 1 / 30, 900.0, False),
        "0.01 s long": (2, 0.01, 0.0, False),
        "a looped clip": (0, 0.0, 0.0, True),
    }[name]
    if loop:
        return replace(walk, name="edge", source=name)
    pick = np.arange(count) % walk.num_keyframes
    return Clip("edge", name, False, np.arange(count) * step, walk.root_pos[pick] + [offset, 0.0, 0.0],
                walk.root_rot[pick], walk.joint_rot[pick])  # fmt: skip


# Which writers write each edge clip (True) and which refuse it (False): the .txt clip and the clip pack take what the
# clip reader takes, except a frame of exactly 1e-4 s, which float32 rounds below the bound (the pack refuses it); a
# motion dataset and an imported take must also last a control step (1/60 s). A motion dataset holds the clip on the
# control grid, not its keyframes: frames of 100 s are interpolated like any (its source clip file is refused).
EDGES = {
    "one keyframe": (False, False, False, False),
    "frames of 100 s": (False, False, True, False),
    "frames of 1e-9 s": (False, False, False, False),
    "frames of 1 s (the most)": (True, True, True, True),
    "frames of 1e-4 s (the least)": (True, False, True, True),
    "root 95 m away": (True, True, True, True),
    "root 900 m away": (False, False, False, False),
    "0.01 s long": (True, True, False, False),
    "a looped clip": (True, True, True, True),
}
WRITERS = ("clip .txt", "clip pack", "motion dataset", "BVH import")


def _write_and_read(writer: str, clip: Clip, ws: Path, humanoid: Humanoid) -> tuple[Path, Any]:
    """Writes ``clip`` with ``writer``; returns the file and what its reader gives back."""
    if writer == "clip .txt":
        write_deepmimic(ws / "edge.txt", clip)
        return ws / "edge.txt", read_deepmimic(ws / "edge.txt")
    if writer == "clip pack":
        # The pack's source: the clip's rows written as a user's file would hold them, beside the workspace.
        src = ws / "src" / "edge.txt"
        src.parent.mkdir(exist_ok=True)
        src.write_text(json.dumps({"Loop": "wrap" if clip.loop else "none", "Frames": clip_to_rows(clip).tolist()}))
        before = _tree(ws)
        try:
            write_clip_pack(ws / "edge.h5", [src])
        except MotionFormatError:
            assert _tree(ws) == before
            raise
        return ws / "edge.h5", read_clip_pack(ws / "edge.h5")[0]
    if writer == "motion dataset":
        save_dataset(ws / "edge.h5", MotionLibrary.from_clips([clip], humanoid), humanoid)
        return ws / "edge.h5", load_dataset(ws / "edge.h5", humanoid)
    write_humanoid_bvh(ws / "edge.bvh", clip, humanoid)
    back, _ = import_clip(str(ws / "edge.bvh"), humanoid, ImportOptions(joint_map="humanoid3d"))
    write_clip(ws / "imported.txt", replace(back, loop=clip.loop), humanoid)
    return ws / "imported.txt", read_deepmimic(ws / "imported.txt")


@pytest.mark.parametrize("edge", list(EDGES))
@pytest.mark.parametrize("writer", WRITERS)
def test_what_a_writer_writes_its_reader_takes(writer: str, edge: str, humanoid: Humanoid, tmp_path: Path) -> None:
    clip = _edge(edge)
    writes = EDGES[edge][WRITERS.index(writer)]
    ws = tmp_path / "ws"
    ws.mkdir()
    if not writes:
        with pytest.raises(MotionFormatError) as caught:
            _write_and_read(writer, clip, ws, humanoid)
        message = str(caught.value)
        assert "\n" not in message and (edge in message or str(ws) in message), message  # the clip or its file
        written = [p.name for p in ws.rglob("*") if p.name in ("edge.txt", "edge.h5", "imported.txt")
                   and p.parent == ws or p.suffix == ".tmp"]  # fmt: skip
        assert not written  # no output, no temporary file
        return
    path, back = _write_and_read(writer, clip, ws, humanoid)
    if writer == "motion dataset":
        reference = MotionLibrary.from_clips([clip], humanoid)
        np.testing.assert_array_equal(back.frames.qpos, reference.frames.qpos)
        assert back.loop[0] == clip.loop
        return
    # 9 significant digits in .txt; float32 in a pack; 6 decimals of cm and degrees in BVH, then retargeted.
    atol = {"clip .txt": 1e-6, "clip pack": 2e-5, "BVH import": 1e-4}[writer]
    assert back.num_keyframes == clip.num_keyframes and back.loop == clip.loop
    np.testing.assert_allclose(back.times, clip.times, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(back.root_pos, clip.root_pos, atol=atol)
    np.testing.assert_allclose(np.abs(np.sum(back.joint_rot * clip.joint_rot, axis=-1)), 1.0, atol=atol)
    assert path.exists() and not list(ws.rglob("*.tmp"))
