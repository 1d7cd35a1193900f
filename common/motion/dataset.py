"""Finding motion clips by name, folder or file, and the native HDF5 motion dataset.

A motion dataset holds every clip already resampled to the control rate with its per-frame states, so that
loading it skips the conversion and the kinematics. It records the control rate and the character's body names;
a dataset built for another rate or character is refused rather than silently misused.
"""

from __future__ import annotations

import warnings
from importlib import resources
from pathlib import Path

import h5py
import numpy as np

from common.character.humanoid import Humanoid
from common.character.state import FRAME_FIELDS, CharacterState
from common.config import hdf5_output
from common.motion import hdf5
from common.motion.library import ClipFrames, MotionLibrary
from common.motion.limits import (
    MAX_CLIP_DURATION,
    MAX_CLIPS,
    MAX_ROOT_DISTANCE,
    MAX_TOTAL_FRAMES,
    check_regular_file,
    lengths,
)
from common.motion.motion import CLIP_PACK_FORMAT, Clip, MotionFormatError, read_clip_pack, read_deepmimic
from common.motion.terrain import check_terrain, read_terrain, write_terrain

DATASET_FORMAT = "mimictrack.motion_dataset"
DATASET_VERSION = 2
"""2: looped clips keep the recorded floor clearance (session 13's loop bend). Version 1 files still load, with a
warning when they hold a looped clip: its frames may have the feet up to 9 cm in the floor (jump, crawl)."""
DATASET_TERRAIN_VERSION = 3
"""3: version 2 whose clips may carry a terrain (group ``terrain`` beside the frames); written only when one does, so
that code that would drop the terrain refuses the file and a flat dataset is written as before."""
READABLE_VERSIONS = (1, 2, 3)
UNIT_QUAT_TOLERANCE = 1e-3  # a stored rotation's length may be off 1 by this much (written normalised in float64)


TERRAIN_PACK = "terrain_clips.h5"
"""The terrain suite's clips (walk, jog, run on stairs, a slope and rough ground; ``benchmarks/terrain_clips.py``)."""


def bundled_motion_dir() -> Path:
    """The folder of the bundled DeepMimic clips (``humanoid3d_*.txt``; long clips in ``long_clips.h5``, the terrain
    suite's in :data:`TERRAIN_PACK`)."""
    return Path(str(resources.files("common.motion") / "data" / "deepmimic" / "motions"))


def bundled_clip_names() -> list[str]:
    """The 20 short clips, ``all``."""
    return sorted(p.stem.removeprefix("humanoid3d_") for p in bundled_motion_dir().glob("humanoid3d_*.txt"))


def bundled_terrain_clip_names() -> list[str]:
    """The terrain suite's clips, ``terrain`` (``walk_stairs``, ...), each a name of its own; none before
    ``benchmarks/terrain_clips.py`` has built the pack."""
    path = bundled_motion_dir() / TERRAIN_PACK
    if not path.exists():
        return []
    with h5py.File(path, "r") as f:
        return sorted(k for k in f.keys() if isinstance(f[k], h5py.Dataset))


def _hdf5_format(path: Path) -> str | None:
    check_regular_file(path, MotionFormatError, max_bytes=None)
    try:
        with h5py.File(path, "r") as f:
            return str(f.attrs.get("format"))
    except OSError as e:
        raise MotionFormatError(f"{path}: not a readable HDF5 file ({e})") from None


def resolve_clips(specs: list[str]) -> list[Clip]:
    """Reads clips from a list of specs: a bundled clip name (``walk``, or a terrain clip's: ``walk_stairs``), ``all``
    (the 20 short clips), ``long`` (the bundled long clips), ``terrain`` (the terrain suite's 9 clips, each with its
    terrain), a DeepMimic ``.txt`` file, a folder of them, or a clip pack ``.h5``.
    """
    clips: list[Clip] = []
    terrain_pack: list[Clip] | None = None  # read once for all the specs that name its clips
    for spec in specs:
        path = Path(spec)
        if spec == "all":
            clips += [read_deepmimic(p) for p in sorted(bundled_motion_dir().glob("humanoid3d_*.txt"))]
        elif spec == "long":
            clips += read_clip_pack(bundled_motion_dir() / "long_clips.h5")
        elif path.is_dir():
            files = sorted(path.glob("*.txt"))
            if not files:
                raise MotionFormatError(f"{path}: folder holds no .txt motion clips")
            clips += [read_deepmimic(p) for p in files]
        elif path.suffix == ".txt" and path.exists():
            clips.append(read_deepmimic(path))
        elif path.suffix == ".h5" and path.exists():
            fmt = _hdf5_format(path)
            if fmt == DATASET_FORMAT:
                raise MotionFormatError(f"{path}: a motion dataset is given alone, not with other motions")
            if fmt != CLIP_PACK_FORMAT:
                raise MotionFormatError(f"{path}: neither a clip pack nor a motion dataset (format {fmt!r})")
            clips += read_clip_pack(path)
        elif (bundled_motion_dir() / f"humanoid3d_{spec}.txt").exists():
            clips.append(read_deepmimic(bundled_motion_dir() / f"humanoid3d_{spec}.txt"))
        elif spec == "terrain" or (not path.exists() and spec in bundled_terrain_clip_names()):
            if terrain_pack is None:
                terrain_pack = read_clip_pack(bundled_motion_dir() / TERRAIN_PACK)
            clips += [c for c in terrain_pack if spec in ("terrain", c.name)]
        elif path.exists():
            hint = "; import it with `mimic-motions import`" if path.suffix.lower() == ".bvh" else ""
            raise MotionFormatError(f"{path}: not a motion file (a DeepMimic .txt clip, or a clip pack or motion "
                                    f"dataset .h5){hint}")  # fmt: skip
        else:
            raise MotionFormatError(
                f"{spec}: no such motion file, folder or bundled clip (bundled: {', '.join(bundled_clip_names())},"
                f" 'all', 'long'; on terrain: {', '.join(bundled_terrain_clip_names())}, 'terrain')"
            )
    names = [c.name for c in clips]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise MotionFormatError(f"clip names must be unique, repeated: {dupes}")
    return clips


def load_motions(specs: list[str], humanoid: Humanoid) -> MotionLibrary:
    """A motion library from specs (see :func:`resolve_clips`) or from one motion dataset ``.h5``."""
    if len(specs) == 1 and specs[0].endswith(".h5") and Path(specs[0]).exists():
        if _hdf5_format(Path(specs[0])) == DATASET_FORMAT:
            return load_dataset(specs[0], humanoid)
    return MotionLibrary.from_clips(resolve_clips(specs), humanoid)


def save_dataset(path: str | Path, library: MotionLibrary, humanoid: Humanoid) -> None:
    """Writes a motion library to HDF5: built in memory, then written to a temporary file renamed over ``path``.

    Every clip is checked first as :func:`load_dataset` will check it, so that what is written loads. HDF5 writing to
    a file on a full disk fails in its own way (errors while objects are freed, then a segfault); in memory it cannot,
    and the one plain write that follows raises ``OSError`` (ENOSPC) with ``path`` as it was and no temporary file
    left.

    Raises:
        MotionFormatError: A clip the loader would refuse; nothing is written.
        OSError: If the file cannot be written; ``path`` keeps its previous content.
    """
    _check_library(library, humanoid, str(path))
    with hdf5_output(path) as f:
        f.attrs["format"] = DATASET_FORMAT
        has_terrain = any(clip.terrain is not None for clip in library.clips)
        f.attrs["version"] = DATASET_TERRAIN_VERSION if has_terrain else DATASET_VERSION
        f.attrs["control_hz"] = humanoid.physics.control_hz
        f.attrs["body_names"] = np.array(humanoid.body_names, dtype="S")
        f.attrs["nq"] = humanoid.nq
        group = f.create_group("clips")
        for order, clip in enumerate(library.clips):
            g = group.create_group(clip.name)
            g.attrs.update(
                order=order,
                source=clip.source,
                loop=clip.loop,
                duration=clip.duration,
                cycle_yaw=clip.cycle_yaw,
            )
            g.create_dataset("cycle_shift", data=clip.cycle_shift)
            for field in FRAME_FIELDS:
                g.create_dataset(field, data=getattr(clip.frames, field), compression="gzip", compression_opts=1)
            if clip.terrain is not None:
                write_terrain(g.create_group("terrain"), clip.terrain)


def _check_library(library: MotionLibrary, humanoid: Humanoid, where: str) -> None:
    """The checks of :func:`load_dataset` on a library about to be written."""
    if not library.clips:
        raise MotionFormatError(f"{where}: a motion dataset needs at least one clip")
    if len(library.clips) > MAX_CLIPS:
        raise MotionFormatError(f"{where}: {len(library.clips):,} clips, more than {MAX_CLIPS:,}")
    if library.num_frames.sum() > MAX_TOTAL_FRAMES:
        raise MotionFormatError(f"{where}: {library.num_frames.sum():,} frames, more than {MAX_TOTAL_FRAMES:,}")
    for clip in library.clips:
        _check_clip(clip, f"{where}: clip '{clip.name}'", humanoid)


def _frame_shapes(humanoid: Humanoid) -> dict[str, tuple[int, ...]]:
    """The shape of one frame of each field of :class:`~common.character.state.CharacterState`."""
    b = humanoid.num_bodies
    return {"qpos": (humanoid.nq,), "qvel": (humanoid.nv,), "body_pos": (b, 3), "body_rot": (b, 4),
            "body_linvel": (b, 3), "body_angvel": (b, 3)}  # fmt: skip


def _check_clip(clip: ClipFrames, where: str, humanoid: Humanoid) -> None:
    """MotionFormatError at ``where`` naming the first problem of a clip on the control grid: frames of the wrong
    shape or number, values that are not finite, a root beyond :data:`~common.motion.limits.MAX_ROOT_DISTANCE`,
    rotations that are not unit quaternions, a duration that does not fit the frames, a cycle transform out of range.
    """
    frames, dt = clip.frames, humanoid.physics.control_dt
    shapes = _frame_shapes(humanoid)
    n = len(frames.qpos)
    for field in FRAME_FIELDS:
        values = getattr(frames, field)
        if values.shape != (n, *shapes[field]):
            raise MotionFormatError(f"{where}: {field} has shape {values.shape}, expected ({n}, "
                                    f"{', '.join(map(str, shapes[field]))})")  # fmt: skip
        bad = np.flatnonzero(~np.isfinite(values.reshape(n, -1)).all(axis=1))
        if len(bad):
            raise MotionFormatError(f"{where}: frame {bad[0]}: {field} holds a value that is not finite")
    if n < 2:
        raise MotionFormatError(f"{where}: {n} frame(s); a clip needs at least 2")
    distance = lengths(frames.qpos[:, :3])
    far = np.flatnonzero(distance > MAX_ROOT_DISTANCE)
    if len(far):
        raise MotionFormatError(f"{where}: frame {far[0]}: root {distance[far[0]]:.6g} m from the origin, farther than "
                                f"{MAX_ROOT_DISTANCE:g} m")  # fmt: skip
    for what, q in (("root quaternion", frames.qpos[:, 3:7]), ("body_rot", frames.body_rot)):
        off = np.abs(lengths(q) - 1.0).reshape(n, -1).max(axis=1)
        bad = np.flatnonzero(off > UNIT_QUAT_TOLERANCE)
        if len(bad):
            raise MotionFormatError(f"{where}: frame {bad[0]}: {what} is not a unit quaternion (length off 1 by "
                                    f"{off[bad[0]]:.3g})")  # fmt: skip
    if not (np.isfinite(clip.duration) and abs(clip.duration - (n - 1) * dt) <= dt + 1e-9):
        raise MotionFormatError(f"{where}: duration {clip.duration:.6g} s does not fit its {n} frames at "
                                f"{1 / dt:g} Hz ({(n - 1) * dt:.6g} s)")  # fmt: skip
    if not abs(clip.cycle_yaw) <= np.pi + 1e-6:
        raise MotionFormatError(f"{where}: cycle_yaw {clip.cycle_yaw:.6g} rad is outside [-pi, pi]")
    shift = np.asarray(clip.cycle_shift, dtype=np.float64)
    if shift.shape != (3,) or not np.all(np.isfinite(shift)) or np.linalg.norm(shift) > 2.0 * MAX_ROOT_DISTANCE:
        raise MotionFormatError(f"{where}: cycle_shift must be 3 finite numbers within {2 * MAX_ROOT_DISTANCE:g} m, "
                                f"got {np.array2string(shift, precision=4)}")  # fmt: skip
    if clip.terrain is not None:
        check_terrain(clip.terrain.heights, clip.terrain.cell_size, clip.terrain.origin, where)


def _body_names(f: h5py.File, where: str) -> tuple[str, ...]:
    value = f.attrs.get("body_names")
    if not (isinstance(value, np.ndarray) and value.ndim == 1 and all(isinstance(v, bytes | str) for v in value)):
        raise MotionFormatError(f"{where}: attribute 'body_names' must be a list of strings, got "
                                f"{hdf5.describe(value)}")  # fmt: skip
    return tuple(v.decode("utf-8", "replace") if isinstance(v, bytes) else v for v in value)


def _read_clip(item: object, name: str, where: str, humanoid: Humanoid) -> tuple[int, ClipFrames]:
    """(order, clip) of one clip group of a dataset, every attribute and array checked (see :func:`_check_clip`)."""
    if not isinstance(item, h5py.Group):
        raise MotionFormatError(f"{where}: not a group of arrays")
    max_rows = int(MAX_CLIP_DURATION * humanoid.physics.control_hz) + 3
    shapes = _frame_shapes(humanoid)
    frames = CharacterState(**{k: hdf5.array(item, k, where, (None, *shapes[k]), max_rows) for k in FRAME_FIELDS})
    clip = ClipFrames(
        name,
        hdf5.attr(item, "source", "str", where),
        hdf5.attr(item, "loop", "bool", where),
        hdf5.attr(item, "duration", "number", where),
        hdf5.attr(item, "cycle_yaw", "number", where),
        hdf5.array(item, "cycle_shift", where, (3,), 3),
        frames,
        read_terrain(item["terrain"], where) if "terrain" in item else None,
    )
    _check_clip(clip, where, humanoid)
    return hdf5.attr(item, "order", "int", where), clip


def load_dataset(path: str | Path, humanoid: Humanoid) -> MotionLibrary:
    """Reads a motion dataset written by :func:`save_dataset`.

    Raises:
        MotionFormatError: naming the file (and the clip) and the problem on one line: not a regular file, unreadable
            or truncated, of another format or version, built for another control rate or character, no clips, an
            attribute of the wrong type (a string or ``true`` where a number belongs), an array of the wrong shape or
            size (checked before it is read), or a clip :func:`_check_clip` refuses.
    """
    path = Path(path)
    check_regular_file(path, MotionFormatError, max_bytes=None)
    where = str(path)
    try:
        with h5py.File(path, "r") as f:
            version = hdf5.check_header(f, where, DATASET_FORMAT, "motion dataset", READABLE_VERSIONS,
                                        "; rebuild it with `mimic-motions convert`")  # fmt: skip
            control_hz = hdf5.attr(f, "control_hz", "number", where)
            if not np.isclose(control_hz, humanoid.physics.control_hz):
                raise MotionFormatError(
                    f"{path}: built at {control_hz} Hz but the physics config runs at"
                    f" {humanoid.physics.control_hz} Hz; rebuild it with `mimic-motions convert`"
                )
            names = _body_names(f, where)
            if names != humanoid.body_names:
                raise MotionFormatError(f"{path}: built for bodies {names}, the model has {humanoid.body_names}")
            group = f.get("clips")
            if not isinstance(group, h5py.Group):
                raise MotionFormatError(f"{path}: no 'clips' group; not a complete motion dataset")
            if len(group) == 0:
                raise MotionFormatError(f"{path}: a motion dataset with no clips")
            if len(group) > MAX_CLIPS:
                raise MotionFormatError(f"{path}: {len(group):,} clips, more than {MAX_CLIPS:,}")
            total = sum(item["qpos"].shape[0] for item in group.values()
                        if isinstance(item, h5py.Group) and isinstance(item.get("qpos"), h5py.Dataset)
                        and item["qpos"].ndim > 0)  # fmt: skip
            if total > MAX_TOTAL_FRAMES:
                raise MotionFormatError(f"{path}: {total:,} frames in all, more than {MAX_TOTAL_FRAMES:,}")
            read = [_read_clip(group[name], name, f"{path}: clip '{name}'", humanoid) for name in group]
    except (OSError, KeyError) as e:
        raise MotionFormatError(f"{path}: unreadable or incomplete motion dataset ({e})") from None
    orders = [order for order, _ in read]
    if len(set(orders)) != len(orders):
        raise MotionFormatError(f"{path}: two clips share one 'order' ({sorted(orders)})")
    clips = [clip for _, clip in sorted(read, key=lambda r: r[0])]
    looped = [c.name for c in clips if c.loop]
    if version == 1 and looped:
        warnings.warn(f"{path}: a version-1 motion dataset: its looped clips ({', '.join(looped)}) were bent before "
                      "the loop fix of session 13 and may have their feet in the floor; rebuild it with "
                      "`mimic-motions convert` from the source clips", stacklevel=2)  # fmt: skip
    return MotionLibrary(clips, humanoid.physics.control_dt)
