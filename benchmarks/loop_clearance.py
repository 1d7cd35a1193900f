"""How far each looping clip's reference reaches below the floor, as recorded and as the motion library loops it.

The library closes a wrap clip's loop by bending its joints towards the first keyframe (``common/motion/library.py``)
and sets the root height so that the lowest collision-geom point keeps the recorded clearance. This prints, per wrap
clip, the lowest point over the clip played one-shot (no bend: the recording) and looped (what every learner and the
evaluator track), the largest per-frame difference, and the seam's own clearance mismatch (last keyframe minus first),
which the library takes out over the cycle's last 0.5 s.

Run: ``.venv/bin/python benchmarks/loop_clearance.py [MOTIONS ...]`` (default: the 20 bundled clips)
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.character.humanoid import BodyGeometry, Humanoid  # noqa: E402
from common.motion.dataset import resolve_clips  # noqa: E402
from common.motion.library import MotionLibrary  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="loop_clearance.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("motions", nargs="*", default=["all"], help="clips or folders (default: all)")
    args = parser.parse_args(argv)
    humanoid = Humanoid()
    geometry = BodyGeometry(humanoid)
    print(f"{'clip':16} {'recorded min':>12} {'looped min':>10} {'max change':>10} {'seam mismatch':>13}   (cm)")
    for clip in resolve_clips(args.motions):
        if not clip.loop:
            print(f"{clip.name:16} one-shot: not looped")
            continue
        lows = []
        for loop in (False, True):
            frames = MotionLibrary.from_clips([replace(clip, loop=loop)], humanoid).frames
            lows.append(geometry.lowest_points(frames.body_pos, frames.body_rot).min(axis=-1))
        n = min(len(lows[0]), len(lows[1]))
        change = np.abs(lows[1][:n] - lows[0][:n]).max()
        seam = lows[0][-1] - lows[0][0]
        print(f"{clip.name:16} {100 * lows[0].min():12.1f} {100 * lows[1].min():10.1f} {100 * change:10.2f} "
              f"{100 * seam:13.2f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
