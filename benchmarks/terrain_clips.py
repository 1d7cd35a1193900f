"""The terrain suite's clips, fixed once: walk, jog and run each fitted to one stairs, one slope and one rough ground
(``mimic-motions fit-terrain``), bundled as ``common/motion/data/deepmimic/motions/terrain_clips.h5``.

Every clip is a bundled wrap clip played for 4 cycles as one one-shot clip (walk 5.1 s, jog 3.3 s, run 3.2 s), on a
generated strip moved with ``--terrain-at`` so that it reaches at least :data:`MARGIN` beyond the reference root's
path on every side (a 1 m heightmap, 1.41 m to its corners, never leaves the grid along the reference). The
parameters were picked once, by the fit's printout (docs/motions.md, "The bundled terrain clips"):

- stairs: the tread matched to the clip's step (walk 0.62 m, jog 1.16 m, run 1.4 m: one tread per step) and the
  flight placed so that no swing foot cuts a riser (walk up 10 cm, jog down 10 cm, run up 8 cm, 6 steps each);
- slopes: walk up 6 deg, jog down 8 deg, run down 6 deg (running up, the run's left foot, which the ground fix's
  speed rule never sees in stance, lands in the slope);
- rough ground: bumps within +-3 cm every 0.3 m, the seed of 0-4 whose fit left the lowest foot of any frame least
  in the ground (the first of equals);
- jog and run with ``--stance-speed 1``: recorded at 30 fps, their planted foot rolls at 0.1-1 m/s, and the default
  0.2 m/s finds 0-2 frames of each contact (the run's left foot: none).

Build (writes the pack, printing each fit's report; the equivalent shell commands with ``--commands``):
    ``.venv/bin/python benchmarks/terrain_clips.py``
Check that the bundled pack is what this script builds (rows equal in float32, terrains bit for bit):
    ``.venv/bin/python benchmarks/terrain_clips.py --check``
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import shlex
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common.motion import terrain_generator  # noqa: E402
from common.motion.dataset import TERRAIN_PACK, bundled_motion_dir  # noqa: E402
from common.motion.motion import read_clip_pack, write_clip_pack  # noqa: E402
from common.motion.terrain import Terrain, check_terrain  # noqa: E402

CYCLES = 4  # cycles of the bundled wrap clip played as one clip: 3.2-5.1 s, 8 steps
MARGIN = 1.5  # m: the terrain reaches this far beyond the reference root's path on every side


@dataclass(frozen=True)
class TerrainClip:
    """One clip of the suite: ``mimic-motions fit-terrain SOURCE --cycles CYCLES --terrain KIND --param ...
    --seed SEED --terrain-at X Y --name NAME``.

    Attributes:
        name: The clip's name (``--motions walk_stairs``).
        source: The bundled wrap clip it is made from.
        kind: The generator's kind (``common/motion/terrain_generator.py``).
        feature: The feature's parameters (``NAME=VALUE`` separated by spaces: steps, slope, bumps).
        at: Where the strip is moved (m): its feature starts at x, it is centred on y.
        strip: The strip's size (``width``, flat ground ``before`` and ``after`` the feature, m): at least
            :data:`MARGIN` beyond the reference root's path on every side.
        seed: Seeds what the generator draws (the rough ground's bumps).
        stance_speed: ``--stance-speed`` (m/s); None: the fit's default (the ground fix's 0.2 m/s).
    """

    name: str
    source: str
    kind: str
    feature: str
    at: tuple[float, float]
    strip: str
    seed: int = 0
    stance_speed: float | None = None

    @property
    def params(self) -> list[str]:
        """The generator's parameters, ``NAME=VALUE``: the feature's, then the strip's."""
        return [*self.feature.split(), *self.strip.split()]

    def argv(self, out: str | Path) -> list[str]:
        """The ``mimic-motions`` arguments that make the clip into ``out`` (a ``.txt``, its terrain in a sidecar)."""
        params = [a for p in self.params for a in ("--param", p)]
        speed = [] if self.stance_speed is None else ["--stance-speed", f"{self.stance_speed:g}"]
        return ["fit-terrain", self.source, "--cycles", str(CYCLES), "--terrain", self.kind, *params, "--seed",
                str(self.seed), "--terrain-at", f"{self.at[0]:g}", f"{self.at[1]:g}", *speed, "--name", self.name,
                "--out", str(out)]  # fmt: skip

    def terrain(self) -> Terrain:
        """The terrain the command fits the clip to (the generator's strip moved as ``--terrain-at`` moves it)."""
        t = terrain_generator.generate(self.kind, self.seed, self.params)
        return check_terrain(t.heights, t.cell_size, t.origin + np.asarray(self.at, dtype=np.float64), self.name)


# The suite's 9 clips (the pack reads them back in alphabetical order): fixed once; changing one changes the suite.
# fmt: off
CLIPS = (
    TerrainClip("walk_stairs", "walk", "stairs", "direction=up steps=6 step_height=0.1 step_depth=0.62", (0.92, 0.45),
                "width=4 before=2.42 after=1.7"),
    TerrainClip("walk_slope", "walk", "slope", "angle_deg=6 length=3.5", (0.5, 0.45), "width=4 before=2.0 after=2.35"),
    TerrainClip("walk_rough", "walk", "rough", "length=4.3", (0.3, 0.45), "width=4 before=1.8 after=1.8", seed=1),
    TerrainClip("jog_stairs", "jog", "stairs", "direction=down steps=6 step_height=0.1 step_depth=1.16", (0.55, 1.0),
                "width=5.2 before=2.05 after=3.0", stance_speed=1.0),
    TerrainClip("jog_slope", "jog", "slope", "angle_deg=-8 length=6.5", (0.5, 1.0), "width=5.2 before=2.0 after=3.5",
                stance_speed=1.0),
    TerrainClip("jog_rough", "jog", "rough", "length=8", (0.5, 1.0), "width=5.2 before=2.0 after=2.0", seed=0,
                stance_speed=1.0),
    TerrainClip("run_stairs", "run", "stairs", "direction=up steps=6 step_height=0.08 step_depth=1.4", (0.6, -0.8),
                "width=4.8 before=2.1 after=3.75", stance_speed=1.0),
    TerrainClip("run_slope", "run", "slope", "angle_deg=-6 length=8.5", (0.6, -0.8), "width=4.8 before=2.1 after=3.65",
                stance_speed=1.0),
    TerrainClip("run_rough", "run", "rough", "length=10", (0.6, -0.8), "width=4.8 before=2.1 after=2.15", seed=3,
                stance_speed=1.0),
)
# fmt: on


def build(out: Path) -> list[str]:
    """Fits every clip of :data:`CLIPS` with ``mimic-motions fit-terrain`` into a temporary folder and packs them into
    ``out`` (a clip pack, version 2: rows in float32, terrains in float64). Returns the fits' printouts."""
    from common.tools import motions

    lines = []
    with tempfile.TemporaryDirectory() as tmp:
        files = []
        for clip in CLIPS:
            path = Path(tmp) / f"{clip.name}.txt"  # a .txt clip's name is its file's stem
            printed = io.StringIO()
            with contextlib.redirect_stdout(printed):
                status = motions.main(clip.argv(path))
            if status != 0:
                raise SystemExit(f"error: {clip.name}: mimic-motions {shlex.join(clip.argv(path))} exited with "
                                 f"{status}")  # fmt: skip
            lines += [f"== {clip.name}: mimic-motions {shlex.join(clip.argv(f'{clip.name}.txt'))}",
                      *printed.getvalue().splitlines()]  # fmt: skip
            files.append(path)
        write_clip_pack(out, files)
    return lines


def check(bundled: Path) -> list[str]:
    """Differences between the bundled pack and a fresh build (empty: the same clips)."""
    with tempfile.TemporaryDirectory() as tmp:
        fresh = Path(tmp) / "fresh.h5"
        build(fresh)
        new = {c.name: c for c in read_clip_pack(fresh)}
    old = {c.name: c for c in read_clip_pack(bundled)}
    if sorted(new) != sorted(old):
        return [f"clips {sorted(old)} bundled, {sorted(new)} built"]
    problems = []
    for name, a in old.items():
        b = new[name]
        same = a.loop == b.loop and all(np.array_equal(getattr(a, k), getattr(b, k)) for k in
                                        ("times", "root_pos", "root_rot", "joint_rot"))  # fmt: skip
        terrain = a.terrain is not None and b.terrain is not None and a.terrain.key() == b.terrain.key()
        if not (same and terrain):
            problems.append(f"{name}: {'frames' if not same else 'terrain'} differ")
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="terrain_clips.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=bundled_motion_dir() / TERRAIN_PACK,
                        help="the clip pack to write (default: the bundled one)")  # fmt: skip
    parser.add_argument("--check", action="store_true", help="build into a temporary file and compare with --out")
    parser.add_argument("--commands", action="store_true", help="print the equivalent shell commands and stop")
    args = parser.parse_args(argv)
    if args.commands:
        for clip in CLIPS:
            print(f"mimic-motions {shlex.join(clip.argv(f'{clip.name}.txt'))}")
        files = json.dumps([f"{c.name}.txt" for c in CLIPS])
        print(f"python -c 'from common.motion.motion import write_clip_pack; write_clip_pack(\"{TERRAIN_PACK}\", "
              f"{files})'")  # fmt: skip
        return 0
    if args.check:
        problems = check(args.out)
        print("\n".join(problems) or f"{args.out}: the same {len(CLIPS)} clips as a fresh build")
        return 1 if problems else 0
    print("\n".join(build(args.out)))
    print(f"wrote {args.out}: {len(CLIPS)} clips")
    return 0


if __name__ == "__main__":
    sys.exit(main())
