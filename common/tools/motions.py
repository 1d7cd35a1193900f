r"""``mimic-motions``: inspect, import, render and convert motion clips, and fit them to a terrain.

Examples::

    mimic-motions summary                 # the 20 bundled short clips
    mimic-motions summary walk run long   # chosen clips, and the bundled long clips
    mimic-motions convert all --out motions.h5
    mimic-motions import take.bvh --map cmu --fix-ground --out take.txt
    mimic-motions render take.txt --out take.mp4
    mimic-motions fit-terrain walk --cycles 2 --terrain stairs --param step_depth=0.62 --terrain-at 0.5 0 \
        --out walk_up.txt                 # two walk cycles up stairs, + walk_up.terrain.h5
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from common.bundled_configs import plain_help
from common.character.humanoid import BodyGeometry, Humanoid, PhysicsConfig
from common.cli import (
    EXIT_NO_RENDERER,
    EXIT_RUN_FAILED,
    MAX_FRAMES,
    CommandParser,
    check_output_file,
    exit_status,
    fail,
    non_negative_float,
    non_negative_int,
    one_line,
    pixels,
    positive_float,
    positive_int,
)
from common.config import ConfigError
from common.motion.dataset import load_motions, resolve_clips, save_dataset
from common.motion.library import MotionLibrary
from common.motion.motion import MotionFormatError
from common.motion.motion_import.cleanup import STANCE_SPEED, ground_of
from common.motion.terrain import SIDECAR_SUFFIX, Terrain, check_terrain, read_terrain_file, sidecar_path


def summary(library: MotionLibrary, sources_fps: dict[str, float], humanoid: Humanoid) -> str:
    geometry = BodyGeometry(humanoid)
    lines = [f"{'clip':<20} {'frames':>6} {'duration':>9} {'src fps':>7} {'loop':>5} {'foot min':>9} {'foot max':>9}"]
    for i, clip in enumerate(library.clips):
        s = slice(library.start[i], library.start[i] + library.num_frames[i])
        low = geometry.clearance(library.frames.body_pos[s], library.frames.body_rot[s], ground_of(clip.terrain))
        low = low[:, humanoid.foot_indices]
        low = low.min(axis=-1)
        lines.append(
            f"{clip.name:<20} {library.num_frames[i]:>6d} {clip.duration:>8.3f}s {sources_fps.get(clip.name, 0):>7.1f}"
            f" {'wrap' if clip.loop else 'none':>5} {low.min():>+8.3f}m {low.max():>+8.3f}m"
        )
    lines.append(
        f"{len(library.clips)} clips, {library.num_frames.sum()} frames at {humanoid.physics.control_hz:g} Hz,"
        f" {library.duration.sum():.1f} s; foot = lowest corner of either foot box above the ground (the clip's "
        "terrain, if it has one)"
    )
    return "\n".join(lines)


# Hz: the highest --control-hz. Every clip is resampled to this rate and kept in memory (a 30 s clip at 1 kHz: 30,000
# frames of every body's state); 1e9 Hz asked for more memory than a machine has and was killed.
MAX_CONTROL_HZ = 1000.0


def _control_hz(text: str) -> float:
    """``--control-hz``'s value: a rate in Hz, above 0 and at most :data:`MAX_CONTROL_HZ`."""
    value = positive_float(text)
    if value > MAX_CONTROL_HZ:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_CONTROL_HZ:g} Hz, got {text}")
    return value


def clip_option(library: MotionLibrary, name: str | None, option: str = "--clip") -> int:
    """The index of the clip ``name`` (None: the first) among ``library``'s clips.

    Raises:
        CommandError: ``"--clip NAME: no such clip among the motions (walk, run)"``.
    """
    if name is None:
        return 0
    if name not in library.names:
        fail(f"{option} {name}: no such clip among the motions ({', '.join(library.names)})")
    return library.names.index(name)


def main(argv: list[str] | None = None) -> int:
    """``mimic-motions``: bad input ends in one line and exit status 2 with nothing written; a write that fails (a
    full disk) in one line and exit status 1, the previous file intact; no renderer: exit status 3."""
    return exit_status(lambda: _main(argv), MotionFormatError, ConfigError)


def _main(argv: list[str] | None) -> int:
    parser = CommandParser(
        prog="mimic-motions", description=plain_help(__doc__), formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True)
    s = sub.add_parser("summary", help="print frames, duration, source fps, loop mode and foot heights per clip")
    s.add_argument(
        "motions",
        nargs="*",
        default=["all"],
        help="clip names (e.g. walk, walk_stairs), 'all' (20 short clips), 'long', 'terrain' (the 9 clips on "
        "terrain), .txt files, folders or .h5 files",
    )
    c = sub.add_parser("convert", help="resample clips to the control rate and write one HDF5 motion dataset")
    c.add_argument("motions", nargs="+", help="as for summary")
    c.add_argument("--out", required=True, help="output .h5 file (written atomically)")
    i = sub.add_parser("import", help="a BVH take (retargeted) or a clip, cleaned up, to a .txt or .h5 clip")
    i.add_argument("source", help="a .bvh file, or any one clip as for summary (for the clean-up options alone)")
    i.add_argument("--out", required=True, help="output: DeepMimic .txt or motion dataset .h5 (written atomically)")
    i.add_argument("--map", default="cmu", help="joint map: a preset (cmu, humanoid3d) or a YAML file (default cmu)")
    i.add_argument("--scale", type=positive_float,
                   help="metres per BVH unit (default: inferred from the skeleton's height)")  # fmt: skip
    i.add_argument("--up", choices=("y", "z"), help="the BVH's up axis (default: the joint map's, y for cmu)")
    i.add_argument("--root", choices=("legs", "source"), default="legs",
                   help="root path scaled by leg length (default) or by --scale only")  # fmt: skip
    i.add_argument("--trim", nargs=2, type=non_negative_float, metavar=("START", "END"),
                   help="keep START..END seconds")  # fmt: skip
    i.add_argument("--mirror", action="store_true", help="left-right mirror (as DeepMimic's _mirror clips)")
    i.add_argument("--fix-ground", action="store_true", help="lift or lower the clip: feet on the floor in stance")
    i.add_argument("--loop", choices=("wrap", "none"), help="loop mode (default: the source's; BVH: none)")
    i.add_argument("--name", help="clip name (default: the file stem)")
    r = sub.add_parser("render", help="kinematic playback of a clip as an MP4 video (MuJoCo offscreen), on its "
                                       "terrain if it has one")  # fmt: skip
    r.add_argument("motions", nargs="+", help="as for summary")
    r.add_argument("--out", required=True, help="output .mp4 file")
    r.add_argument("--clip", help="which clip of the motions (default: the first)")
    r.add_argument("--seconds", type=positive_float,
                   help=f"length (default: the clip; wrap clips one cycle); at most {MAX_FRAMES} frames")  # fmt: skip
    r.add_argument("--size", type=pixels, nargs=2, default=(480, 360), metavar=("W", "H"), help="pixels (480 360)")
    f = sub.add_parser(
        "fit-terrain", help="fit a clip to a terrain: stance feet on it, the root raised per frame (docs/motions.md)",
        description="Fits a clip recorded on flat ground to a terrain: the root raised or lowered per frame by the "
        "terrain's height under the stance foot (handed over between the feet in double support, smoothed at "
        "most 1 m/s faster or slower vertically, never below the stance ground), then the ground fix of "
        "`import --fix-ground` measured against the terrain. On a terrain flat at height 0 it is exactly "
        "--fix-ground. Writes the clip with its terrain (.txt: a .terrain.h5 sidecar beside it; .h5: in the "
        "dataset) and prints the offset's range, the stance frames found and the lowest foot before and after.",
    )  # fmt: skip
    f.add_argument("source", help="one clip, as for summary (a bundled name, a .txt, or a clip pack with --clip)")
    f.add_argument("--terrain", required=True,
                   help="a generator kind (stairs, slope, rough, boxes: common/motion/terrain_generator.py), a "
                        ".terrain.h5 file, or motions (as for summary) whose clips carry one terrain")  # fmt: skip
    f.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="a generator parameter, repeatable: stairs direction=down, steps, step_height, step_depth; "
                        "slope angle_deg, length; rough amplitude, bump_spacing, length; boxes count, "
                        "height_range=LO,HI, size_range=LO,HI, length; all width, before, after, cell (metres, "
                        "degrees); unset ranges are drawn with --seed")  # fmt: skip
    f.add_argument("--seed", type=non_negative_int, default=0, help="seeds what the generator draws (default 0)")
    f.add_argument("--terrain-at", type=float, nargs=2, default=None, metavar=("X", "Y"),
                   help="move the terrain by X, Y metres (a generated strip's feature starts at x = 0, centred on "
                        "y = 0)")  # fmt: skip
    f.add_argument("--clip", help="which clip of the source (default: its only one)")
    f.add_argument("--cycles", type=positive_int,
                   help="play a wrap clip for this many cycles first, as one one-shot clip (a walk long enough for "
                        "a flight of stairs)")  # fmt: skip
    f.add_argument("--stance-speed", type=positive_float, default=STANCE_SPEED,
                   help="a foot slower than this (m/s) may be in stance (default: the ground fix's "
                        f"{STANCE_SPEED:g}; a jog or run recorded at 30 fps: 1)")  # fmt: skip
    f.add_argument("--name", help="clip name (default: the source's)")
    f.add_argument("--out", required=True, help="output: DeepMimic .txt (+ .terrain.h5 sidecar) or motion dataset "
                                                ".h5 (written atomically)")  # fmt: skip
    for p in (s, c, i, r, f):
        p.add_argument("--control-hz", type=_control_hz, default=60.0,
                       help=f"control and reference rate in Hz (default 60, at most {MAX_CONTROL_HZ:g})")  # fmt: skip
    args = parser.parse_args(argv)
    if args.command != "summary":
        check_output_file(args.out)
    humanoid = Humanoid(PhysicsConfig(control_hz=args.control_hz))
    if args.command == "summary":
        if any(m.endswith(".h5") for m in args.motions) and len(args.motions) == 1:
            library = load_motions(args.motions, humanoid)
            fps: dict[str, float] = {}
        else:
            clips = resolve_clips(args.motions)
            fps = {cl.name: cl.source_fps for cl in clips}
            library = MotionLibrary.from_clips(clips, humanoid)
        print(summary(library, fps, humanoid))
    elif args.command == "import":
        from common.motion.motion_import.pipeline import ImportOptions, import_clip, write_clip
        from common.motion.motion_import.retarget import RetargetOptions

        try:
            options = ImportOptions(
                joint_map=args.map, retarget=RetargetOptions(scale=args.scale, up=args.up, root=args.root),
                trim=tuple(args.trim) if args.trim else None, mirror=args.mirror, fix_ground=args.fix_ground,
                loop=args.loop, name=args.name,
            )  # fmt: skip
            clip, notes = import_clip(args.source, humanoid, options)
        except (ValueError, KeyError) as e:  # options the source cannot take (a trim beyond its end), a joint map's
            fail(one_line(e))
        _write(args.out, lambda: write_clip(args.out, clip, humanoid))
        print("\n".join(notes + [f"wrote {args.out}: {clip.num_keyframes} keyframes, {clip.duration:.3f} s"]))
    elif args.command == "render":
        return _render(args, humanoid)
    elif args.command == "fit-terrain":
        return _fit_terrain(args, humanoid)
    else:
        started = time.perf_counter()
        library = load_motions(args.motions, humanoid)
        _write(args.out, lambda: save_dataset(args.out, library, humanoid))
        print(f"wrote {args.out}: {library.num_clips} clips, {library.num_frames.sum()} frames"
              f" in {time.perf_counter() - started:.1f} s")  # fmt: skip
    return 0


def _write(out: str, write: Callable[[], None]) -> None:
    """Runs ``write``; a failure of the disk (full, read-only) ends in one line, the previous ``out`` intact."""
    try:
        write()
    except OSError as e:
        fail(f"{out}: cannot write it: {e.strerror or one_line(e)}; nothing was changed", EXIT_RUN_FAILED)


def _render(args: argparse.Namespace, humanoid: Humanoid) -> int:
    """Kinematic playback through the report's renderer (a child process with a working MuJoCo GL backend)."""
    from common.motion.motion_import.pipeline import playback_qpos
    from common.tools import render

    library = load_motions(args.motions, humanoid)
    clip = clip_option(library, args.clip)
    # As playback_qpos counts them, checked before anything is allocated.
    seconds = args.seconds if args.seconds is not None else float(library.duration[clip])
    frames = int(round(seconds / library.dt)) + 1
    if not library.loop[clip]:
        frames = min(frames, int(library.num_frames[clip]))
    if frames > MAX_FRAMES:
        what = f"--seconds {args.seconds:g}" if args.seconds is not None else f"clip {library.names[clip]}"
        fail(f"{what}: {frames} frames at {humanoid.physics.control_hz:g} Hz, more than {MAX_FRAMES}; render a "
             "shorter stretch with --seconds")  # fmt: skip
    qpos = playback_qpos(library, clip, args.seconds)
    backend, why = render.find_backend()
    if backend is None:
        fail(why, EXIT_NO_RENDERER)
    terrain = library.clips[clip].terrain
    _write(args.out, lambda: render.video(qpos, None, humanoid, Path(args.out), backend,
                                          fps=humanoid.physics.control_hz, width=args.size[0],
                                          height=args.size[1], terrain=terrain))  # fmt: skip
    on = "" if terrain is None else f" on its terrain ({describe_terrain(terrain)})"
    print(f"wrote {args.out}: {library.names[clip]}{on}, {len(qpos)} frames at {humanoid.physics.control_hz:g} fps "
          f"({why})")  # fmt: skip
    return 0


def describe_terrain(terrain: Terrain) -> str:
    """``"120 x 41 nodes of 5 cm, x -1.00 to 5.00 m, y -1.00 to 1.00 m, heights 0.00 to 0.60 m"``."""
    lo, hi = terrain.origin, terrain.origin + terrain.size
    rows, cols = terrain.shape
    return (f"{cols} x {rows} nodes of {terrain.cell_size * 100:g} cm, x {lo[0]:.2f} to {hi[0]:.2f} m, y {lo[1]:.2f} "
            f"to {hi[1]:.2f} m, heights {terrain.heights.min():.2f} to {terrain.heights.max():.2f} m")  # fmt: skip


def _terrain_option(args: argparse.Namespace, humanoid: Humanoid) -> tuple[Terrain, str]:
    """The terrain ``--terrain`` names (moved by ``--terrain-at``), and where it came from."""
    from common.motion import terrain_generator

    spec = args.terrain
    if spec in terrain_generator.KINDS:
        try:
            terrain = terrain_generator.generate(spec, args.seed, args.param)
        except ValueError as e:
            fail(f"--terrain {one_line(e)}")  # "--terrain stairs: step_height 0.5 is outside 0.05 to 0.15"
        where = " ".join([f"{spec} seed {args.seed}", *args.param])
    else:
        if args.param:
            fail(f"--param {args.param[0]}: parameters are for the generator's kinds "
                 f"({', '.join(terrain_generator.KINDS)}), not for a file ({spec})")  # fmt: skip
        if spec.endswith(SIDECAR_SUFFIX):
            terrain = read_terrain_file(spec)
        else:
            clips = load_motions([spec], humanoid).clips
            found = {t.key(): t for t in (clip.terrain for clip in clips) if t is not None}
            if len(found) != 1:
                fail(f"--terrain {spec}: its clips carry {len(found)} terrains; it must hold one (or give a generator "
                     f"kind: {', '.join(terrain_generator.KINDS)}, or a {SIDECAR_SUFFIX} file)")  # fmt: skip
            terrain = next(iter(found.values()))
        where = spec
    if args.terrain_at is not None:
        moved = terrain.origin + np.asarray(args.terrain_at, dtype=np.float64)
        terrain = check_terrain(terrain.heights, terrain.cell_size, moved, f"--terrain-at {args.terrain_at[0]:g} "
                                f"{args.terrain_at[1]:g}")  # fmt: skip
        where += f", moved by ({args.terrain_at[0]:g}, {args.terrain_at[1]:g}) m"
    return terrain, where


def _fit_terrain(args: argparse.Namespace, humanoid: Humanoid) -> int:
    """``fit-terrain``: one clip fitted to a terrain and written with it (motion_import/terrain_fit.py)."""
    from dataclasses import replace

    from common.motion.motion_import import cleanup
    from common.motion.motion_import.pipeline import check_playable, write_clip
    from common.motion.motion_import.terrain_fit import fit_terrain

    if Path(args.out).suffix not in (".txt", ".h5"):
        fail(f"--out {args.out}: must be a DeepMimic .txt or a motion dataset .h5")
    terrain, where = _terrain_option(args, humanoid)
    clips = resolve_clips([args.source])
    if args.clip is None and len(clips) != 1:
        fail(f"{args.source}: holds {len(clips)} clips; pick one with --clip ({', '.join(c.name for c in clips)})")
    names = [c.name for c in clips]
    if args.clip is not None and args.clip not in names:
        fail(f"--clip {args.clip}: no such clip in {args.source} ({', '.join(names)})")
    clip = clips[names.index(args.clip) if args.clip is not None else 0]
    clip = replace(clip, name=args.name or clip.name)
    notes = [f"read {clip.source}: {clip.num_keyframes} keyframes, {clip.duration:.3f} s"]
    try:
        if args.cycles is not None:
            clip = cleanup.unroll(clip, humanoid, args.cycles)
            notes.append(f"unrolled {args.cycles} cycles: {clip.num_keyframes} keyframes, {clip.duration:.3f} s, "
                         "one-shot")  # fmt: skip
        notes.append(f"terrain {where}: {describe_terrain(terrain)}")
        fitted, fit = fit_terrain(clip, humanoid, terrain, args.stance_speed)
    except ValueError as e:  # a clip that leaves the terrain, --cycles on a one-shot clip
        fail(one_line(e))
    check_playable(fitted, humanoid)
    _write(args.out, lambda: write_clip(args.out, fitted, humanoid))
    sidecar = f" and {sidecar_path(args.out)}" if Path(args.out).suffix == ".txt" else " (terrain inside)"
    wrote = f"wrote {args.out}{sidecar}: {fitted.num_keyframes} keyframes, {fitted.duration:.3f} s, loop " + (
        "wrap" if fitted.loop else "none"
    )
    print("\n".join([*notes, *fit.report(), wrote]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
