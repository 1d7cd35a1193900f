"""Finding motion clips by name, folder or file, and the native HDF5 motion dataset.

A motion dataset holds every clip already resampled to the control rate with its per-frame states, so that
loading it skips the conversion and the kinematics. It records the control rate and the character's body names;
a dataset built for another rate or character is refused rather than silently misused.
"""

from __future__ import annotations

import io
import warnings
from importlib import resources
from pathlib import Path

import h5py
import numpy as np

from common.character.humanoid import Humanoid
from common.character.state import FRAME_FIELDS, CharacterState
from common.config import atomic_output
from common.motion.library import ClipFrames, MotionLibrary
from common.motion.motion import (
    CLIP_PACK_FORMAT,
    MAX_ROOT_DISTANCE,
    Clip,
    MotionFormatError,
    read_clip_pack,
    read_deepmimic,
)

DATASET_FORMAT = "mimictrack.motion_dataset"
DATASET_VERSION = 2
"""2: looped clips keep the recorded floor clearance (session 13's loop bend). Version 1 files still load, with a
warning when they hold a looped clip: its frames may have the feet up to 9 cm in the floor (jump, crawl)."""
READABLE_VERSIONS = (1, 2)


def bundled_motion_dir() -> Path:
    """The folder of the bundled DeepMimic clips (``humanoid3d_*.txt``; long clips in ``long_clips.h5``)."""
    return Path(str(resources.files("common.motion") / "data" / "deepmimic" / "motions"))


def bundled_clip_names() -> list[str]:
    return sorted(p.stem.removeprefix("humanoid3d_") for p in bundled_motion_dir().glob("humanoid3d_*.txt"))


def _hdf5_format(path: Path) -> str | None:
    try:
        with h5py.File(path, "r") as f:
            return str(f.attrs.get("format"))
    except OSError as e:
        raise MotionFormatError(f"{path}: not a readable HDF5 file ({e})") from None


def resolve_clips(specs: list[str]) -> list[Clip]:
    """Reads clips from a list of specs: a bundled clip name (``walk``), ``all`` (the 20 short clips), ``long``
    (the bundled long clips), a DeepMimic ``.txt`` file, a folder of them, or a clip pack ``.h5``.
    """
    clips: list[Clip] = []
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
            if _hdf5_format(path) != CLIP_PACK_FORMAT:
                raise MotionFormatError(f"{path}: not a clip pack; load motion datasets with load_dataset()")
            clips += read_clip_pack(path)
        elif (bundled_motion_dir() / f"humanoid3d_{spec}.txt").exists():
            clips.append(read_deepmimic(bundled_motion_dir() / f"humanoid3d_{spec}.txt"))
        else:
            raise MotionFormatError(
                f"{spec}: no such motion file, folder or bundled clip (bundled: {', '.join(bundled_clip_names())},"
                " 'all', 'long')"
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

    HDF5 writing to a file on a full disk fails in its own way (errors while objects are freed, then a segfault);
    in memory it cannot, and the one plain write that follows raises ``OSError`` (ENOSPC) with ``path`` as it was
    and no temporary file left.

    Raises:
        OSError: If the file cannot be written; ``path`` keeps its previous content.
    """
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as f:
        f.attrs["format"] = DATASET_FORMAT
        f.attrs["version"] = DATASET_VERSION
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
    with atomic_output(path) as tmp:
        tmp.write_bytes(buffer.getbuffer())


def _check_frames(frames: CharacterState, where: str, humanoid: Humanoid) -> None:
    """MotionFormatError at ``where`` naming the first frame that is not finite, of the wrong size, or with a root
    farther than :data:`~common.motion.motion.MAX_ROOT_DISTANCE` from the origin."""
    if frames.qpos.ndim != 2 or frames.qpos.shape[1] != humanoid.nq:
        raise MotionFormatError(f"{where}: qpos has shape {frames.qpos.shape}, the model needs (frames, {humanoid.nq})")
    for field in FRAME_FIELDS:
        values = getattr(frames, field)
        if len(values) != len(frames.qpos):
            raise MotionFormatError(f"{where}: {field} has {len(values)} frames, qpos {len(frames.qpos)}")
        bad = np.flatnonzero(~np.isfinite(values.reshape(len(values), -1)).all(axis=1))
        if len(bad):
            raise MotionFormatError(f"{where}: frame {bad[0]}: {field} holds a value that is not finite")
    distance = np.linalg.norm(frames.qpos[:, :3], axis=-1)
    far = np.flatnonzero(distance > MAX_ROOT_DISTANCE)
    if len(far):
        raise MotionFormatError(f"{where}: frame {far[0]}: root {distance[far[0]]:.6g} m from the origin, farther than "
                                f"{MAX_ROOT_DISTANCE:g} m")  # fmt: skip


def load_dataset(path: str | Path, humanoid: Humanoid) -> MotionLibrary:
    """Reads a motion dataset written by :func:`save_dataset`.

    Raises:
        MotionFormatError: the file is unreadable or truncated, of another format or version, or built for another
            control rate or character.
    """
    path = Path(path)
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != DATASET_FORMAT:
                raise MotionFormatError(f"{path}: not a motion dataset (format {f.attrs.get('format')!r})")
            version = f.attrs.get("version")
            if version not in READABLE_VERSIONS:
                raise MotionFormatError(
                    f"{path}: motion dataset version {version}, this code reads"
                    f" {' and '.join(map(str, READABLE_VERSIONS))}; rebuild it with `mimic-motions convert`"
                )
            if not np.isclose(f.attrs["control_hz"], humanoid.physics.control_hz):
                raise MotionFormatError(
                    f"{path}: built at {f.attrs['control_hz']} Hz but the physics config runs at"
                    f" {humanoid.physics.control_hz} Hz; rebuild it with `mimic-motions convert`"
                )
            names = tuple(n.decode() for n in f.attrs["body_names"])
            if names != humanoid.body_names:
                raise MotionFormatError(f"{path}: built for bodies {names}, the model has {humanoid.body_names}")
            groups = sorted(f["clips"].values(), key=lambda g: g.attrs["order"])
            clips = []
            for g in groups:
                frames = CharacterState(**{k: g[k][()] for k in FRAME_FIELDS})
                _check_frames(frames, f"{path}: clip '{g.name.split('/')[-1]}'", humanoid)
                clips.append(
                    ClipFrames(
                        g.name.split("/")[-1],
                        str(g.attrs["source"]),
                        bool(g.attrs["loop"]),
                        float(g.attrs["duration"]),
                        float(g.attrs["cycle_yaw"]),
                        g["cycle_shift"][()],
                        frames,
                    )
                )
    except (OSError, KeyError) as e:
        raise MotionFormatError(f"{path}: unreadable or incomplete motion dataset ({e})") from None
    looped = [c.name for c in clips if c.loop]
    if version == 1 and looped:
        warnings.warn(f"{path}: a version-1 motion dataset: its looped clips ({', '.join(looped)}) were bent before "
                      "the loop fix of session 13 and may have their feet in the floor; rebuild it with "
                      "`mimic-motions convert` from the source clips", stacklevel=2)  # fmt: skip
    return MotionLibrary(clips, humanoid.physics.control_dt)
