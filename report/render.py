"""Filmstrips of the simulated character (opaque) over its reference (translucent ghost), MuJoCo offscreen.

The rollout runs in the report's process; drawing runs in a child process (``python -m report.render``) with
``MUJOCO_GL`` set to the first backend that works (``egl``, then ``osmesa``), because MuJoCo picks its GL backend once,
at import, and a broken GL driver may abort the process: the report must survive a machine without a renderer.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from common.evaluate import EvalConfig, Policy
from common.gym import GymConfig, TrackingGym
from common.humanoid import Humanoid
from common.motion_library import MotionLibrary

BACKENDS = ("egl", "osmesa")
_PROBE = "import mujoco; m = mujoco.MjModel.from_xml_string('<mujoco/>'); mujoco.Renderer(m, 8, 8).render()"
GHOST_RGBA = (1.0, 0.6, 0.2, 0.35)  # the reference: orange and translucent, so the simulated body stays readable


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
        (sim_qpos, ref_qpos), each (T, nq), T <= frames (shorter when the episode fails or the clip ends).
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
            if result.terminated[0] or result.truncated[0]:
                break
    finally:
        gym.close()
    return np.asarray(sim), np.asarray(ref)


def filmstrip(sim_qpos: np.ndarray, ref_qpos: np.ndarray, humanoid: Humanoid, out: Path, backend: str,
              panels: int = 6, size: int = 240, timeout_s: float = 300.0) -> None:  # fmt: skip
    """Renders ``panels`` evenly spaced frames side by side into ``out`` (PNG) in a child process.

    Raises:
        RuntimeError: If the child process fails.
    """
    out = Path(out)
    data = out.with_suffix(".npz")
    np.savez(data, sim=sim_qpos, ref=ref_qpos, xml=str(humanoid.xml_path), panels=panels, size=size)
    # The child must import this package even when it is not installed (a source checkout run from elsewhere).
    root = str(Path(__file__).resolve().parents[1])
    path = os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH", "")) if p)
    env = {**os.environ, "MUJOCO_GL": backend, "PYTHONPATH": path}
    try:
        proc = subprocess.run([sys.executable, "-m", "report.render", str(data), str(out)], env=env,
                              capture_output=True, text=True, timeout=timeout_s)  # fmt: skip
    finally:
        data.unlink(missing_ok=True)
    if proc.returncode != 0:
        raise RuntimeError(f"rendering failed: {proc.stderr.strip()[-500:]}")


def _draw(data_path: Path, out: Path) -> None:
    """The child process: draws the filmstrip described by ``data_path`` (see :func:`filmstrip`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import mujoco

    data = np.load(data_path)
    sim_q, ref_q, size, panels = data["sim"], data["ref"], int(data["size"]), int(data["panels"])
    model = mujoco.MjModel.from_xml_path(str(data["xml"]))
    # The offscreen buffer must hold the image; the bundled model may declare a smaller one.
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, size)
    model.vis.global_.offheight = max(model.vis.global_.offheight, size)
    d_sim, d_ref = mujoco.MjData(model), mujoco.MjData(model)
    renderer = mujoco.Renderer(model, size, size)
    option, perturb = mujoco.MjvOption(), mujoco.MjvPerturb()
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.distance, camera.azimuth, camera.elevation = 3.5, 90.0, -10.0
    images = []
    for t in np.linspace(0, len(sim_q) - 1, min(panels, len(sim_q))).round().astype(int):
        d_sim.qpos[:], d_ref.qpos[:] = sim_q[t], ref_q[t]
        mujoco.mj_kinematics(model, d_sim)
        mujoco.mj_kinematics(model, d_ref)
        camera.lookat[:] = [d_ref.qpos[0], d_ref.qpos[1], 0.9]  # follow the reference: drift shows as offset
        renderer.update_scene(d_sim, camera, option)
        first = renderer.scene.ngeom
        mujoco.mjv_addGeoms(model, d_ref, option, perturb, mujoco.mjtCatBit.mjCAT_DYNAMIC, renderer.scene)
        for g in range(first, renderer.scene.ngeom):
            renderer.scene.geoms[g].rgba[:] = GHOST_RGBA
        image = renderer.render().copy()
        images.append(image)
    renderer.close()
    strip = np.concatenate(images, axis=1) if images else np.zeros((size, size, 3), np.uint8)
    plt.imsave(out, strip)


if __name__ == "__main__":
    _draw(Path(sys.argv[1]), Path(sys.argv[2]))
