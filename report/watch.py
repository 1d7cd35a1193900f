"""``watch-policy``: a trained policy tracking a clip, the reference as a translucent ghost.

The policy is rebuilt from a run's checkpoint by its learner's ``export.py`` (as the comparison report does) and played
from t = 0 like the evaluator, until the episode fails or ``--frames`` pass. Where a display exists the recorded
episode loops in MuJoCo's interactive viewer; otherwise (or with ``--out``) it is written as an MP4 by the report's
offscreen renderer. A clip on a terrain is drawn on it.

Examples::

    watch-policy runs/st-walk                                   # the viewer, or runs/st-walk/watch_walk.mp4
    watch-policy runs/st-walk --motions take.txt --out take.mp4 # the walk policy on an imported clip
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from common.bundled_configs import PRETRAINED_ROOT, plain_help
from common.character.humanoid import Humanoid
from common.cli import (
    EXIT_NO_RENDERER,
    EXIT_RUN_FAILED,
    MAX_FRAMES,
    CommandParser,
    check_output_file,
    exit_status,
    fail,
    frame_count,
    non_negative_int,
    one_line,
    pixels,
)
from common.config import ConfigError
from common.motion.dataset import load_motions
from common.motion.motion import MotionFormatError
from common.motion.terrain import Terrain
from common.run.checkpoint import CheckpointError
from common.sim.terrain import terrain_model
from common.tools import render
from common.tools.motions import clip_option
from report.runs import ReportError, export_module, load_run


def has_display() -> bool:
    """True where an interactive window can open (an X11 or Wayland display, or macOS / Windows)."""
    return sys.platform in ("darwin", "win32") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def view(sim_qpos: np.ndarray, ref_qpos: np.ndarray, humanoid: Humanoid, fps: float,
         terrain: Terrain | None = None) -> None:  # fmt: skip
    """Loops the recorded episode in MuJoCo's viewer until its window is closed; the reference as a ghost.

    Args:
        sim_qpos: The simulated character per frame. Shape: (T, nq).
        ref_qpos: The reference per frame. Shape: (T, nq).
        humanoid: The model.
        fps: Playback rate.
        terrain: The clip's terrain, drawn with the gym's terrain model (:func:`common.sim.terrain.terrain_model`);
            None: the flat floor.
    """
    import mujoco
    import mujoco.viewer

    model = humanoid.model if terrain is None else terrain_model(humanoid, terrain)
    d_sim, d_ref = mujoco.MjData(model), mujoco.MjData(model)
    with mujoco.viewer.launch_passive(model, d_sim) as viewer:
        t = 0
        while viewer.is_running():
            start = time.perf_counter()
            d_sim.qpos[:], d_ref.qpos[:] = sim_qpos[t], ref_qpos[t]
            mujoco.mj_kinematics(model, d_sim)
            mujoco.mj_kinematics(model, d_ref)
            with viewer.lock():
                viewer.user_scn.ngeom = 0
                mujoco.mjv_addGeoms(model, d_ref, viewer.opt, viewer.perturb, mujoco.mjtCatBit.mjCAT_DYNAMIC,
                                    viewer.user_scn)  # fmt: skip
                for g in range(viewer.user_scn.ngeom):
                    viewer.user_scn.geoms[g].rgba[:] = render.GHOST_RGBA
            viewer.sync()
            t = (t + 1) % len(sim_qpos)
            time.sleep(max(0.0, 1.0 / fps - (time.perf_counter() - start)))


def main(argv: list[str] | None = None) -> int:
    """``watch-policy``: bad input ends in one line and exit status 2 with nothing written; a video that cannot be
    written (a full disk) in one line and exit status 1; no display and no renderer: exit status 3."""
    return exit_status(lambda: _main(argv), ReportError, MotionFormatError, ConfigError, CheckpointError)


def _main(argv: list[str] | None) -> int:
    parser = CommandParser(prog="watch-policy", description=plain_help(__doc__),
                           formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("run", help="a training run directory, or 'pretrained' for the general tracker that ships with "
                                    "the project")
    parser.add_argument("--motions", nargs="+", help="motions to track (default: the run's training motions)")
    parser.add_argument("--clip", help="which clip of the motions (default: the first)")
    parser.add_argument("--checkpoint", type=non_negative_int, help="checkpoint iteration (default: the newest)")
    parser.add_argument("--frames", type=frame_count, default=512,
                        help=f"most steps played (default 512, at most {MAX_FRAMES})")  # fmt: skip
    parser.add_argument("--out", help="write an MP4 here instead of opening the viewer")
    parser.add_argument("--size", type=pixels, nargs=2, default=(480, 360), metavar=("W", "H"), help="video pixels")
    args = parser.parse_args(argv)
    if args.out is not None:
        check_output_file(args.out)
    run = load_run(args.run, args.checkpoint)
    humanoid = Humanoid(run.physics())
    library = load_motions(args.motions or run.motions, humanoid)
    clip = clip_option(library, args.clip)
    out, backend, why = None, None, ""
    if args.out is not None or not has_display():
        # Beside the run, except for a bundled policy (the project's own folder): then in the working directory.
        folder = Path.cwd() if run.path.is_relative_to(PRETRAINED_ROOT) else run.path
        out = Path(args.out or folder / f"watch_{library.names[clip]}.mp4")
        if args.out is None:
            check_output_file(out, "video")
        backend, why = render.find_backend()
        if backend is None:
            fail(f"no display and {why}", EXIT_NO_RENDERER)
    try:
        policy = export_module(run.learner).load_eval_policy(run.path, run.checkpoint, humanoid, library)
    except ValueError as e:  # a checkpoint that is not this learner's
        fail(one_line(e))
    sim, ref = render.record_rollout(policy, library, humanoid, clip, args.frames, run.eval_config())
    fps = humanoid.physics.control_hz
    terrain = library.clips[clip].terrain  # drawn as the gym simulated it
    note = f"{run.label} on {library.names[clip]}: {len(sim)} frames before the episode ended or --frames"
    if out is None:
        print(note + "; close the viewer window to quit")
        view(sim, ref, humanoid, fps, terrain)
        return 0
    assert backend is not None
    try:
        render.video(sim, ref, humanoid, out, backend, fps=fps, width=args.size[0], height=args.size[1],
                     terrain=terrain)  # fmt: skip
    except OSError as e:
        fail(f"{out}: cannot write it: {e.strerror or one_line(e)}", EXIT_RUN_FAILED)
    print(f"{note}; wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
