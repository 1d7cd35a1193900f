"""Where a policy's root goes off the reference: behind or ahead, to the side, down, or turned.

MPJPE-g adds root drift to pose error; MPJPE-l removes it. When MPJPE-g is high and MPJPE-l low, this script says what
kind of drift it is. It plays a run's evaluation policy from the evaluator's start frames
(``common.evaluation.evaluate``'s protocol and full horizon: a failed episode plays on) and splits the root's
offset from the reference at chosen frames into
- **along**: along the reference root's horizontal direction of travel (mean over +-15 frames), positive ahead;
- **cross**: horizontal, to the reference's left of travel positive;
- **down**: the reference root's height minus the simulated one's;
- **heading**: the yaw of the simulated root minus the reference's, in degrees (wrapped to +-180).
It also prints the mean speed along the reference's path, simulated over reference, and the lag's growth in cm/s (a
line fitted to the along-track offset over the episode): steady lag is a speed bias, a jump is a stumble. With
``--per-episode`` it lists every episode (its start frame, its failure, its distance at the chosen frames, its mean
distance and that mean's share of the clip's total): a mean made by one stumbling episode shows there.

Run: ``.venv/bin/python benchmarks/root_drift.py runs/st-run --starts 8``
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common.character.humanoid import Humanoid  # noqa: E402
from common.evaluation.evaluate import EvalConfig, episode_starts  # noqa: E402
from common.maths.rotations import quat_yaw  # noqa: E402
from common.motion.dataset import load_motions  # noqa: E402
from common.sim.gym import GymConfig, TrackingGym  # noqa: E402
from report.runs import ReportError, export_module, load_run  # noqa: E402

MIN_SPEED = 0.3  # m/s: below it the reference has no direction of travel (along/cross are not split)


def play(policy, library, humanoid: Humanoid, protocol: EvalConfig) -> dict[str, np.ndarray]:
    """Root positions, yaws and failure flags of the protocol's episodes. Shapes: (T, N, 3), (T, N), (N,) ..."""
    clips, times, episode_max = episode_starts(library, protocol)
    config = GymConfig(num_envs=len(clips), threads=protocol.threads, seed=protocol.seed, physics=humanoid.physics,
                       termination=protocol.termination)  # fmt: skip
    gym = TrackingGym(config, library, humanoid)
    horizon = int(episode_max.max())
    out = {k: [] for k in ("sim_pos", "ref_pos", "sim_yaw", "ref_yaw", "ref_vel")}
    failed_at = np.full(len(clips), -1)
    try:
        result = gym.reset(clips=clips, times=times)
        for t in range(horizon):
            result = gym.step(policy(result), autoreset=False)
            sim, ref = result.final_sim, result.final_ref
            out["sim_pos"].append(sim.body_pos[:, 0].copy())
            out["ref_pos"].append(ref.body_pos[:, 0].copy())
            out["sim_yaw"].append(quat_yaw(sim.body_rot[:, 0]))
            out["ref_yaw"].append(quat_yaw(ref.body_rot[:, 0]))
            out["ref_vel"].append(ref.body_linvel[:, 0].copy())
            failed_at[(failed_at < 0) & result.terminated & (t < episode_max)] = t
    finally:
        gym.close()
    arrays = {k: np.asarray(v) for k, v in out.items()}
    arrays.update(clips=clips, start_frames=np.rint(times / library.dt).astype(int), episode_max=episode_max,
                  failed_at=failed_at)  # fmt: skip
    return arrays


def split(d: dict[str, np.ndarray], smooth: int = 15) -> dict[str, np.ndarray]:
    """Along / cross / down / heading offsets per frame and episode. Shapes: (T, N)."""
    vel = d["ref_vel"][..., :2]
    kernel = np.ones(2 * smooth + 1) / (2 * smooth + 1)
    mean_vel = np.stack([np.apply_along_axis(lambda v: np.convolve(v, kernel, mode="same"), 0, vel[..., i])
                         for i in range(2)], axis=-1)  # fmt: skip
    speed = np.linalg.norm(mean_vel, axis=-1)
    fwd = mean_vel / np.maximum(speed, 1e-9)[..., None]
    left = np.stack([-fwd[..., 1], fwd[..., 0]], axis=-1)
    delta = d["sim_pos"] - d["ref_pos"]
    moving = speed > MIN_SPEED
    along = np.where(moving, np.sum(delta[..., :2] * fwd, axis=-1), np.nan)
    cross = np.where(moving, np.sum(delta[..., :2] * left, axis=-1), np.nan)
    heading = np.degrees(np.angle(np.exp(1j * (d["sim_yaw"] - d["ref_yaw"]))))
    sim_step = np.diff(d["sim_pos"][..., :2], axis=0)
    ref_step = np.diff(d["ref_pos"][..., :2], axis=0)
    speed_ratio = np.sum(np.sum(sim_step * fwd[1:], axis=-1), axis=0) / np.maximum(
        np.sum(np.sum(ref_step * fwd[1:], axis=-1), axis=0), 1e-9)  # fmt: skip
    return {"distance": np.linalg.norm(delta[..., :2], axis=-1), "along": along, "cross": cross,
            "down": d["ref_pos"][..., 2] - d["sim_pos"][..., 2], "heading": heading, "speed_ratio": speed_ratio,
            "moving": moving}  # fmt: skip


def episode_rows(distance: np.ndarray, episode_max: np.ndarray, frames: list[int]) -> list[dict[str, object]]:
    """Per episode: the distance at ``frames`` (NaN past its horizon), its mean and max over its horizon, and its
    mean's share of the sum of the episodes' means (the episodes given: one clip's). Distances in m, shape (T, N)."""
    T, N = distance.shape
    live = np.arange(T)[:, None] < episode_max[None, :]
    means = np.array([distance[live[:, n], n].mean() for n in range(N)])
    total = means.sum()
    return [{"at": [float(distance[f, n]) if f < min(T, episode_max[n]) else float("nan") for f in frames],
             "mean": float(means[n]), "max": float(distance[live[:, n], n].max()),
             "share": float(means[n] / total) if total > 0 else float("nan")} for n in range(N)]  # fmt: skip


def lag_rate(along: np.ndarray, dt: float) -> float:
    """Slope in cm/s of a line fitted to the along-track offset (all episodes, frames with a direction)."""
    t = np.arange(along.shape[0])[:, None].repeat(along.shape[1], axis=1) * dt
    ok = np.isfinite(along)
    if ok.sum() < 3:
        return float("nan")
    return float(np.polyfit(t[ok], along[ok], 1)[0] * 100.0)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="root_drift.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("run", help="a training run directory (SuperTrack, PPO or SAMCON)")
    parser.add_argument("--motions", nargs="+", default=None, help="clips to play (default: the run's own)")
    parser.add_argument("--starts", type=int, default=None, help="start frames per clip (default: the run's protocol)")
    parser.add_argument("--frames", type=int, nargs="+", default=[30, 60, 120, 240, 480],
                        help="frames at which the offsets are printed")  # fmt: skip
    parser.add_argument("--per-episode", action="store_true",
                        help="also list every episode: start frame, failure, distance at --frames, mean, max and the "
                             "mean's share of the clip's total")  # fmt: skip
    parser.add_argument("--checkpoint", type=int, default=None, help="iteration of the checkpoint (default: newest)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        run = load_run(args.run, args.checkpoint)
    except ReportError as e:
        raise SystemExit(f"error: {e}") from None
    humanoid = Humanoid(run.physics())
    library = load_motions(args.motions or run.motions, humanoid)
    protocol = run.eval_config()
    if args.starts:
        protocol = replace(protocol, starts_per_clip=args.starts)
    policy = export_module(run.learner).load_eval_policy(run.path, run.checkpoint, humanoid, library)
    d = play(policy, library, humanoid, protocol)
    parts = split(d)
    print(f"{run.label}, checkpoint {run.checkpoint.name} (iteration {run.iteration}); {protocol.starts_per_clip} "
          f"starts per clip, full horizon; offsets in cm (mean over episodes; along + ahead, cross + left), "
          f"heading in deg")  # fmt: skip
    for c, name in enumerate(library.names):
        eps = d["clips"] == c
        fails = d["failed_at"][eps]
        print(f"\n{name}: {int((fails >= 0).sum())} of {int(eps.sum())} episodes failed "
              f"(first failures at frames {sorted(int(f) for f in fails if f >= 0)[:8]}); speed along the path, "
              f"sim / ref: {np.nanmean(parts['speed_ratio'][eps]):.3f}; along-track trend "
              f"{lag_rate(parts['along'][:, eps], library.dt):+.1f} cm/s")  # fmt: skip
        print(f"{'frame':>6} {'distance':>9} {'along':>8} {'cross':>8} {'|cross|':>8} {'down':>7} {'heading':>8} "
              f"{'|heading|':>9}")  # fmt: skip
        for f in args.frames:
            live = eps & (f < d["episode_max"])
            if f >= parts["distance"].shape[0] or not live.any():
                continue

            def m(x: np.ndarray, live: np.ndarray = live, f: int = f) -> float:
                v = x[f, live]
                return float(np.nanmean(v)) if np.isfinite(v).any() else float("nan")

            cm = [100 * m(parts[k]) for k in ("distance", "along", "cross")] + [100 * m(np.abs(parts["cross"]))]
            print(f"{f:>6} {cm[0]:>9.1f} {cm[1]:>8.1f} {cm[2]:>8.1f} {cm[3]:>8.1f} {100 * m(parts['down']):>7.1f} "
                  f"{m(parts['heading']):>8.1f} {m(np.abs(parts['heading'])):>9.1f}")  # fmt: skip
        if args.per_episode:
            rows = episode_rows(parts["distance"][:, eps], d["episode_max"][eps], args.frames)
            print(f"{'start':>6} {'failed':>6}  distance (cm) at frames {args.frames}, mean, max, share of the mean")
            for start, failed, row in zip(d["start_frames"][eps], fails, rows, strict=True):
                at = " ".join(f"{100 * x:6.1f}" for x in row["at"])
                print(f"{start:>6} {failed if failed >= 0 else '-':>6}  {at}  {100 * row['mean']:6.1f} "
                      f"{100 * row['max']:6.1f} {100 * row['share']:5.0f} %")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
