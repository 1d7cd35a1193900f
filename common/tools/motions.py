"""``mimic-motions``: inspect, import, render and convert motion clips.

Examples::

    mimic-motions summary                 # the 20 bundled short clips
    mimic-motions summary walk run long   # chosen clips, and the bundled long clips
    mimic-motions convert all --out motions.h5
    mimic-motions import take.bvh --map cmu --fix-ground --out take.txt
    mimic-motions render take.txt --out take.mp4
"""

from __future__ import annotations

import argparse
import sys
import time

from common.bundled_configs import plain_help
from common.character.humanoid import BodyGeometry, Humanoid, PhysicsConfig
from common.motion.dataset import load_motions, resolve_clips, save_dataset
from common.motion.library import MotionLibrary
from common.motion.motion import MotionFormatError


def summary(library: MotionLibrary, sources_fps: dict[str, float], humanoid: Humanoid) -> str:
    geometry = BodyGeometry(humanoid)
    lines = [f"{'clip':<20} {'frames':>6} {'duration':>9} {'src fps':>7} {'loop':>5} {'foot min':>9} {'foot max':>9}"]
    for i, clip in enumerate(library.clips):
        s = slice(library.start[i], library.start[i] + library.num_frames[i])
        low = geometry.lowest_points(library.frames.body_pos[s], library.frames.body_rot[s])[:, humanoid.foot_indices]
        low = low.min(axis=-1)
        lines.append(
            f"{clip.name:<20} {library.num_frames[i]:>6d} {clip.duration:>8.3f}s {sources_fps.get(clip.name, 0):>7.1f}"
            f" {'wrap' if clip.loop else 'none':>5} {low.min():>+8.3f}m {low.max():>+8.3f}m"
        )
    lines.append(
        f"{len(library.clips)} clips, {library.num_frames.sum()} frames at {humanoid.physics.control_hz:g} Hz,"
        f" {library.duration.sum():.1f} s; foot = lowest corner of either foot box above the ground"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="mimic-motions", description=plain_help(__doc__), formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True)
    s = sub.add_parser("summary", help="print frames, duration, source fps, loop mode and foot heights per clip")
    s.add_argument(
        "motions",
        nargs="*",
        default=["all"],
        help="clip names (e.g. walk), 'all' (20 short clips), 'long', .txt files, folders or .h5 files",
    )
    c = sub.add_parser("convert", help="resample clips to the control rate and write one HDF5 motion dataset")
    c.add_argument("motions", nargs="+", help="as for summary")
    c.add_argument("--out", required=True, help="output .h5 file (written atomically)")
    i = sub.add_parser("import", help="a BVH take (retargeted) or a clip, cleaned up, to a .txt or .h5 clip")
    i.add_argument("source", help="a .bvh file, or any one clip as for summary (for the clean-up options alone)")
    i.add_argument("--out", required=True, help="output: DeepMimic .txt or motion dataset .h5 (written atomically)")
    i.add_argument("--map", default="cmu", help="joint map: a preset (cmu, humanoid3d) or a YAML file (default cmu)")
    i.add_argument("--scale", type=float, help="metres per BVH unit (default: inferred from the skeleton's height)")
    i.add_argument("--up", choices=("y", "z"), help="the BVH's up axis (default: the joint map's, y for cmu)")
    i.add_argument("--root", choices=("legs", "source"), default="legs",
                   help="root path scaled by leg length (default) or by --scale only")  # fmt: skip
    i.add_argument("--trim", nargs=2, type=float, metavar=("START", "END"), help="keep START..END seconds")
    i.add_argument("--mirror", action="store_true", help="left-right mirror (as DeepMimic's _mirror clips)")
    i.add_argument("--fix-ground", action="store_true", help="lift or lower the clip: feet on the floor in stance")
    i.add_argument("--loop", choices=("wrap", "none"), help="loop mode (default: the source's; BVH: none)")
    i.add_argument("--name", help="clip name (default: the file stem)")
    r = sub.add_parser("render", help="kinematic playback of a clip as an MP4 video (MuJoCo offscreen)")
    r.add_argument("motions", nargs="+", help="as for summary")
    r.add_argument("--out", required=True, help="output .mp4 file")
    r.add_argument("--clip", help="which clip of the motions (default: the first)")
    r.add_argument("--seconds", type=float, help="length (default: the clip; wrap clips one cycle)")
    r.add_argument("--size", type=int, nargs=2, default=(480, 360), metavar=("W", "H"), help="pixels (480 360)")
    for p in (s, c, i, r):
        p.add_argument("--control-hz", type=float, default=60.0, help="control and reference rate in Hz (default 60)")
    args = parser.parse_args(argv)

    humanoid = Humanoid(PhysicsConfig(control_hz=args.control_hz))
    try:
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

            options = ImportOptions(
                joint_map=args.map, retarget=RetargetOptions(scale=args.scale, up=args.up, root=args.root),
                trim=tuple(args.trim) if args.trim else None, mirror=args.mirror, fix_ground=args.fix_ground,
                loop=args.loop, name=args.name,
            )  # fmt: skip
            clip, notes = import_clip(args.source, humanoid, options)
            write_clip(args.out, clip, humanoid)
            print("\n".join(notes + [f"wrote {args.out}: {clip.num_keyframes} keyframes, {clip.duration:.3f} s"]))
        elif args.command == "render":
            return _render(args, humanoid)
        else:
            start = time.perf_counter()
            library = load_motions(args.motions, humanoid)
            save_dataset(args.out, library, humanoid)
            print(
                f"wrote {args.out}: {library.num_clips} clips, {library.num_frames.sum()} frames"
                f" in {time.perf_counter() - start:.1f} s"
            )
    except (MotionFormatError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


def _render(args: argparse.Namespace, humanoid: Humanoid) -> int:
    """Kinematic playback through the report's renderer (a child process with a working MuJoCo GL backend)."""
    from pathlib import Path

    from common.motion.motion_import.pipeline import playback_qpos
    from common.tools import render

    library = load_motions(args.motions, humanoid)
    clip = library.clip_index(args.clip) if args.clip else 0
    qpos = playback_qpos(library, clip, args.seconds)
    backend, why = render.find_backend()
    if backend is None:
        print(f"error: {why}", file=sys.stderr)
        return 3
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    render.video(qpos, None, humanoid, Path(args.out), backend, fps=humanoid.physics.control_hz,
                 width=args.size[0], height=args.size[1])  # fmt: skip
    print(f"wrote {args.out}: {library.names[clip]}, {len(qpos)} frames at {humanoid.physics.control_hz:g} fps ({why})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
