"""``mimic-motions``: inspect motion clips and convert them into one HDF5 motion dataset.

Examples::

    mimic-motions summary                 # the 20 bundled short clips
    mimic-motions summary walk run long   # chosen clips, and the bundled long clips
    mimic-motions convert all --out motions.h5
"""

from __future__ import annotations

import argparse
import sys
import time

from common.humanoid import BodyGeometry, Humanoid, PhysicsConfig
from common.motion import MotionFormatError
from common.motion_dataset import load_motions, resolve_clips, save_dataset
from common.motion_library import MotionLibrary


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
        prog="mimic-motions", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
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
    for p in (s, c):
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
        else:
            start = time.perf_counter()
            library = load_motions(args.motions, humanoid)
            save_dataset(args.out, library, humanoid)
            print(
                f"wrote {args.out}: {library.num_clips} clips, {library.num_frames.sum()} frames"
                f" in {time.perf_counter() - start:.1f} s"
            )
    except MotionFormatError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
