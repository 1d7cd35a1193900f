"""Filmstrips and MP4 videos of the simulated character (opaque) over its reference (translucent ghost), MuJoCo
offscreen; without a reference, plain kinematic playback (``mimic-motions render``).

A clip on a terrain is drawn on it: the child builds the model with the gym's terrain model builder
(:func:`common.sim.terrain.terrain_model`: the heightfield geom, the floor plane moved below it), and the camera looks
at the terrain's height under the character (smoothed over :data:`CAMERA_SMOOTHING` frames) plus the flat view's
0.9 m. A flat clip is drawn from the plain model with the camera as before.

The rollout runs in the report's process; drawing runs in a child process (``python -m common.tools.render``) with
``MUJOCO_GL`` set to the first backend that works (``egl``, then ``osmesa``), because MuJoCo picks its GL backend once,
at import, and a broken GL driver may abort the process: the report must survive a machine without a renderer.
"""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import EvalConfig, Policy
from common.motion.library import MotionLibrary
from common.motion.terrain import Terrain
from common.sim.gym import GymConfig, TrackingGym

BACKENDS = ("egl", "osmesa")
_PROBE = "import mujoco; m = mujoco.MjModel.from_xml_string('<mujoco/>'); mujoco.Renderer(m, 8, 8).render()"
_EXIT_WRITE_FAILED = 4  # the drawing child's status when it could not write its output (e.g. ENOSPC)
GHOST_RGBA = (1.0, 0.6, 0.2, 0.35)  # the reference: orange and translucent, so the simulated body stays readable
LOOK_HEIGHT = 0.9  # m: the camera looks at this height above the ground under the character
CAMERA_SMOOTHING = 15  # frames: half-width of the window smoothing the ground height the camera follows on a terrain


def find_backend(timeout_s: float = 60.0) -> tuple[str | None, str]:
    """The first MuJoCo GL backend that renders here.

    Returns:
        (backend, note): the backend name or None, and why each one tried failed (for the report).
    """
    tried = []
    preferred = os.environ.get("MUJOCO_GL")
    for backend in ([preferred] if preferred else []) + [b for b in BACKENDS if b != preferred]:
        env = {**os.environ, "MUJOCO_GL": backend}
        try:
            proc = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True,
                                  timeout=timeout_s)  # fmt: skip
        except subprocess.TimeoutExpired:
            tried.append(f"{backend}: timed out")
            continue
        if proc.returncode == 0:
            return backend, f"rendered with MUJOCO_GL={backend}"
        last = (proc.stderr.strip().splitlines() or ["exit code " + str(proc.returncode)])[-1]
        tried.append(f"{backend}: {last[:200]}")
    return None, "no MuJoCo offscreen renderer available (" + "; ".join(tried) + ")"


def record_rollout(policy: Policy, library: MotionLibrary, humanoid: Humanoid, clip: int, frames: int,
                   protocol: EvalConfig) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Plays ``policy`` on one clip from t = 0 like the evaluator and keeps the poses.

    Args:
        policy: The deterministic policy.
        library: The motions.
        humanoid: The model.
        clip: Clip index.
        frames: Maximum steps recorded.
        protocol: Evaluation protocol (seed and termination rule).

    Returns:
        (sim_qpos, ref_qpos), each (T, nq), T <= frames: shorter when a one-shot clip ends, or when the episode fails
        under the earlier protocol (``protocol.full_horizon`` False); under the full-horizon judge the character plays
        on after a failure, as the evaluator scores it.
    """
    gym = TrackingGym(
        GymConfig(num_envs=1, threads=1, seed=protocol.seed, physics=humanoid.physics,
                  termination=protocol.termination),
        library, humanoid,
    )  # fmt: skip
    if not library.loop[clip]:
        frames = min(frames, int(library.num_frames[clip]) - 1)
    sim, ref = [], []
    try:
        result = gym.reset(clips=np.array([clip]), times=np.zeros(1))
        for _ in range(frames):
            result = gym.step(policy(result), autoreset=False)
            sim.append(result.final_sim.qpos[0].copy())
            ref.append(result.final_ref.qpos[0].copy())
            if result.truncated[0] or (result.terminated[0] and not protocol.full_horizon):
                break
    finally:
        gym.close()
    return np.asarray(sim), np.asarray(ref)


def filmstrip(sim_qpos: np.ndarray, ref_qpos: np.ndarray, humanoid: Humanoid, out: Path, backend: str,
              panels: int = 6, size: int = 240, timeout_s: float = 300.0,
              terrain: Terrain | None = None) -> None:  # fmt: skip
    """Renders ``panels`` evenly spaced frames side by side into ``out`` (PNG) in a child process, on ``terrain``
    (None: the flat floor).

    Raises:
        RuntimeError: If the child process fails.
    """
    followed = ref_qpos if len(ref_qpos) else sim_qpos
    _run_child(Path(out), backend, timeout_s, sim=sim_qpos, ref=ref_qpos, xml=str(humanoid.xml_path), panels=panels,
               width=size, height=size, fps=0.0, **_terrain_data(terrain, followed))  # fmt: skip


def video(sim_qpos: np.ndarray, ref_qpos: np.ndarray | None, humanoid: Humanoid, out: Path, backend: str,
          fps: float, width: int = 480, height: int = 360, timeout_s: float = 900.0,
          terrain: Terrain | None = None) -> None:  # fmt: skip
    """Renders every frame into an MP4 video ``out`` (H.264) in a child process.

    Args:
        sim_qpos: The character drawn opaque. Shape: (T, nq).
        ref_qpos: The reference drawn as a translucent ghost, or None (kinematic playback). Shape: (T, nq).
        humanoid: The model.
        out: The .mp4 file.
        backend: MuJoCo GL backend (see :func:`find_backend`).
        fps: Frames per second of the video.
        width, height: Frame size in pixels (rounded up to even numbers for the encoder).
        terrain: The ground drawn under the character; None: the flat floor.

    Raises:
        RuntimeError: If the child process fails.
    """
    ref = np.zeros((0, sim_qpos.shape[1])) if ref_qpos is None else ref_qpos
    _run_child(Path(out), backend, timeout_s, sim=sim_qpos, ref=ref, xml=str(humanoid.xml_path), panels=0,
               width=width + width % 2, height=height + height % 2, fps=fps,
               **_terrain_data(terrain, ref if len(ref) else sim_qpos))  # fmt: skip


def _terrain_data(terrain: Terrain | None, followed: np.ndarray) -> dict[str, np.ndarray]:
    """What the drawing child needs of a terrain: its grid and, per frame, the ground height the camera follows
    under the followed character's root (a Hann-weighted mean over +-:data:`CAMERA_SMOOTHING` frames, so that the
    view glides up a flight of stairs). A flat floor: empty arrays and a height of 0."""
    if terrain is None:
        return {"terrain_heights": np.zeros((0, 0)), "terrain_cell": np.zeros(0), "terrain_origin": np.zeros(0),
                "ground": np.zeros(len(followed))}  # fmt: skip
    ground = terrain.height_at(followed[:, 0], followed[:, 1])
    half = CAMERA_SMOOTHING
    weights = np.sin(np.pi * np.arange(1, 2 * half + 2) / (2 * half + 2)) ** 2
    ground = np.convolve(np.pad(ground, half, mode="edge"), weights / weights.sum(), mode="valid")
    return {"terrain_heights": terrain.heights, "terrain_cell": np.array([terrain.cell_size]),
            "terrain_origin": terrain.origin, "ground": ground}  # fmt: skip


def write_video(frames: Iterable[np.ndarray], out: Path, fps: float) -> int:
    """Encodes RGB frames (each (H, W, 3) uint8, all one size) as H.264 MP4 with imageio-ffmpeg's bundled ffmpeg.

    Written to a temporary file first and renamed over ``out`` when complete. Returns the number of frames.
    """
    import imageio_ffmpeg

    out = Path(out)
    tmp = out.with_name(out.name + ".tmp.mp4")
    writer, count = None, 0
    try:
        for frame in frames:
            if writer is None:
                writer = imageio_ffmpeg.write_frames(str(tmp), (frame.shape[1], frame.shape[0]), fps=fps,
                                                     macro_block_size=1, quality=7)  # fmt: skip
                writer.send(None)
            writer.send(np.ascontiguousarray(frame))
            count += 1
        if writer is None:
            raise ValueError(f"{out}: no frames to write")
        writer.close()
        writer = None
        _check_video(tmp, out)
        os.replace(tmp, out)
    finally:
        if writer is not None:
            writer.close()
        tmp.unlink(missing_ok=True)
    return count


def _check_video(path: Path, out: Path) -> None:
    """Refuses a video ffmpeg could not finish (imageio-ffmpeg does not look at ffmpeg's exit status: on a full disk
    it left an MP4 without its index), by reading its container back without decoding (milliseconds).

    Raises:
        OSError: ENOSPC naming ``out`` when the disk is (nearly) full, else EIO with ffmpeg's complaint.
    """
    import imageio_ffmpeg

    proc = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-i", str(path), "-map", "0", "-c", "copy",
                           "-f", "null", "-"], capture_output=True, text=True, timeout=600)  # fmt: skip
    if proc.returncode == 0:
        return
    if shutil.disk_usage(path.parent).free < 1 << 20:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(out))
    last = (proc.stderr.strip().splitlines() or [f"exit status {proc.returncode}"])[-1]
    raise OSError(errno.EIO, f"ffmpeg could not finish the video ({last})", str(out))


def _run_child(out: Path, backend: str, timeout_s: float, **data: object) -> None:
    """Runs ``python -m common.tools.render`` on ``data`` (saved beside ``out``) with MUJOCO_GL = ``backend``."""
    path_npz = out.with_suffix(".npz")
    # The child must import this package even when it is not installed (a source checkout run from elsewhere).
    root = str(Path(__file__).resolve().parents[2])
    path = os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH", "")) if p)
    env = {**os.environ, "MUJOCO_GL": backend, "PYTHONPATH": path}
    try:
        with open(path_npz, "wb") as f:  # a file object: np.savez would add ".npz" to a name without it
            np.savez(f, **data)
        proc = subprocess.run([sys.executable, "-m", "common.tools.render", str(path_npz), str(out)], env=env,
                              capture_output=True, text=True, timeout=timeout_s)  # fmt: skip
    finally:
        path_npz.unlink(missing_ok=True)
    if proc.returncode == _EXIT_WRITE_FAILED:  # the child could not write ``out`` (a full disk): an OSError here too
        code, _, strerror = proc.stderr.strip().splitlines()[-1].partition(" ")
        raise OSError(int(code) if code.isdigit() else None, strerror, str(out))
    if proc.returncode != 0:
        raise RuntimeError(f"rendering failed: {proc.stderr.strip()[-500:]}")


def _images(model: object, sim_q: np.ndarray, ref_q: np.ndarray, frames: Iterable[int], width: int,
            height: int, ground: np.ndarray) -> Iterator[np.ndarray]:  # fmt: skip
    """Draws the given frames: the simulated character opaque, the reference (if any rows) as a ghost; the camera
    looks at :data:`LOOK_HEIGHT` above ``ground`` (per frame, 0 on the flat floor)."""
    import mujoco

    # The offscreen buffer must hold the image; the bundled model may declare a smaller one.
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
    model.vis.global_.offheight = max(model.vis.global_.offheight, height)
    d_sim, d_ref = mujoco.MjData(model), mujoco.MjData(model)
    renderer = mujoco.Renderer(model, height, width)
    option, perturb = mujoco.MjvOption(), mujoco.MjvPerturb()
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.distance, camera.azimuth, camera.elevation = 3.5, 90.0, -10.0
    try:
        for t in frames:
            d_sim.qpos[:] = sim_q[t]
            mujoco.mj_kinematics(model, d_sim)
            follow = d_sim
            if len(ref_q):
                d_ref.qpos[:] = ref_q[t]
                mujoco.mj_kinematics(model, d_ref)
                follow = d_ref  # follow the reference: drift shows as offset
            camera.lookat[:] = [follow.qpos[0], follow.qpos[1], LOOK_HEIGHT + ground[t]]
            renderer.update_scene(d_sim, camera, option)
            if len(ref_q):
                first = renderer.scene.ngeom
                mujoco.mjv_addGeoms(model, d_ref, option, perturb, mujoco.mjtCatBit.mjCAT_DYNAMIC, renderer.scene)
                for g in range(first, renderer.scene.ngeom):
                    renderer.scene.geoms[g].rgba[:] = GHOST_RGBA
            yield renderer.render().copy()
    finally:
        renderer.close()


def _draw(data_path: Path, out: Path) -> None:
    """The child process: draws the filmstrip or video described by ``data_path`` (see :func:`filmstrip`)."""
    import mujoco

    data = np.load(data_path)
    sim_q, ref_q = data["sim"], data["ref"]
    width, height, panels, fps = int(data["width"]), int(data["height"]), int(data["panels"]), float(data["fps"])
    ground = data["ground"]
    if data["terrain_heights"].size:
        from common.sim.terrain import terrain_model

        terrain = Terrain(data["terrain_heights"], float(data["terrain_cell"][0]), data["terrain_origin"])
        model = terrain_model(Humanoid(xml_path=str(data["xml"])), terrain)
    else:
        model = mujoco.MjModel.from_xml_path(str(data["xml"]))
    if fps > 0:
        write_video(_images(model, sim_q, ref_q, range(len(sim_q)), width, height, ground), out, fps)
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    picks = np.linspace(0, len(sim_q) - 1, min(panels, len(sim_q))).round().astype(int)
    images = list(_images(model, sim_q, ref_q, picks, width, height, ground))
    strip = np.concatenate(images, axis=1) if images else np.zeros((height, width, 3), np.uint8)
    plt.imsave(out, strip)


if __name__ == "__main__":
    try:
        _draw(Path(sys.argv[1]), Path(sys.argv[2]))
    except OSError as e:  # the parent raises it again: "<errno> <strerror>" on the last line
        if e.errno is None:
            raise
        print(f"{e.errno} {e.strerror}", file=sys.stderr)
        sys.exit(_EXIT_WRITE_FAILED)
