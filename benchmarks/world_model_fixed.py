"""The world model alone on a fixed distribution: what it can learn of a clip's dynamics, per body, in minutes.

The gym plays the clip open loop (the untrained policy's offsets are ~0) plus the config's exploration noise until
the training buffer is full; nothing is collected after that, so every variant of W sees the same frames (the gym
is seeded and deterministic). W then trains for ``--updates`` steps, and every ``--eval-every`` its one-frame
error on the held-back characters' frames is printed per body next to the guess "the velocity stays the same"
(zero acceleration), split into frames where the character is still up (head within 25 cm of the reference's
height, SuperTrack's rule) and frames after it has fallen. A body where W does no better than the guess is a body
W has not learnt.

    .venv/bin/python benchmarks/world_model_fixed.py --motions run --updates 3000 --set world_model.weights.angvel=1
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common.character.humanoid import Humanoid  # noqa: E402
from common.config import load_config  # noqa: E402
from common.maths import torch_rotations as R  # noqa: E402
from common.motion.dataset import load_motions  # noqa: E402
from supertrack.config import SuperTrackConfig  # noqa: E402
from supertrack.learner import SuperTrackLearner  # noqa: E402
from supertrack.rollout import world_model_rollout  # noqa: E402
from supertrack.state import BodyState  # noqa: E402

HEAD_RULE_M = 0.25  # SuperTrack's head-height rule


def one_frame_errors(learner: SuperTrackLearner, windows: dict[str, np.ndarray], head: int) -> dict[str, np.ndarray]:
    """Per-window, per-body one-frame errors of W and of the constant-velocity guess, and the 'up' flag.

    Returns:
        ``w_vel``, ``c_vel``, ``w_ang``, ``c_ang``: (B, N) errors (m/s, rad/s); ``up``: (B,) bool.
    """
    sim = BodyState.unpack(torch.as_tensor(windows["sim"]))
    kin_next = BodyState.unpack(torch.as_tensor(windows["kin_next"]))
    with torch.no_grad():
        pred = world_model_rollout(learner.world_model, sim, torch.as_tensor(windows["target_rot"])).time(0)
    now, nxt = sim.time(0), sim.time(1)

    def err(a: torch.Tensor, b: torch.Tensor) -> np.ndarray:
        return (a - b).norm(dim=-1).numpy()

    up = (nxt.pos[:, head, 2] - kin_next.time(0).pos[:, head, 2]).abs().numpy() < HEAD_RULE_M
    return {"w_vel": err(pred.vel, nxt.vel), "c_vel": err(now.vel, nxt.vel), "w_ang": err(pred.angvel, nxt.angvel),
            "c_ang": err(now.angvel, nxt.angvel), "up": up}  # fmt: skip


def acceleration_spread(learner: SuperTrackLearner, windows: dict[str, np.ndarray]) -> str:
    """How far the simulated accelerations lie outside W's output normaliser (taken from the clips)."""
    sim = BodyState.unpack(torch.as_tensor(windows["sim"]))
    now, nxt = sim.time(0), sim.time(1)
    dt = learner.world_model.dt
    acc = torch.cat([(nxt.vel - now.vel) / dt, (nxt.angvel - now.angvel) / dt], dim=-2)  # (B, 2N, 3), world
    local = R.quat_rotate_inv(now.rot[:, :1], acc)  # root frame of frame i, as W predicts them
    z = learner.world_model.accel_norm.normalize(local.reshape(len(local), -1)).abs()
    p99, beyond = float(z.quantile(0.99)), float((z > 10).float().mean())
    return f"|normalised acceleration| of the held-back frames: 99th percentile {p99:.1f} std, {beyond:.1%} beyond 10"


def summary_line(e: dict[str, np.ndarray], names: tuple[str, ...]) -> str:
    """Mean angular-velocity error ratio W / constant on up and fallen frames, and the worst bodies."""
    parts = []
    for label, mask in (("up", e["up"]), ("fallen", ~e["up"])):
        if mask.sum() == 0:
            continue
        w, c = e["w_ang"][mask].mean(0), e["c_ang"][mask].mean(0)
        parts.append(f"{label} ({mask.mean():.0%}): angvel W {w.mean():.2f} / const {c.mean():.2f} rad/s, "
                     f"pelvis {w[0]:.2f}/{c[0]:.2f}, bodies W<const {int((w < c).sum())}/{len(w)}")  # fmt: skip
    return "; ".join(parts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(ROOT / "configs/supertrack/default.yaml"), help="SuperTrack config")
    parser.add_argument("--motions", nargs="+", default=["run"], help="clips (names, files, 'all')")
    parser.add_argument("--updates", type=int, default=3000, help="W steps on the fixed buffer")
    parser.add_argument("--eval-every", type=int, default=500, help="W steps between measurements")
    parser.add_argument("--windows", type=int, default=2048, help="held-back windows measured")
    parser.add_argument("--compile", action="store_true", help="torch.compile W's rollout step")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    args = parser.parse_args()
    overrides = [f"train.motions=[{','.join(args.motions)}]", "policy.start_iteration=1000000000",
                 "buffer.val_envs=8", f"world_model.compile={str(args.compile).lower()}", "policy.compile=false",
                 *args.set]  # fmt: skip
    cfg = load_config(SuperTrackConfig, args.config, overrides)
    torch.set_num_threads(cfg.train.torch_threads)
    torch.manual_seed(cfg.train.seed)
    humanoid = Humanoid(cfg.gym.physics)
    library = load_motions(list(cfg.train.motions), humanoid)
    learner = SuperTrackLearner(cfg, humanoid, library, np.random.default_rng(cfg.train.seed))
    try:
        t0 = time.perf_counter()
        while learner.train_buffer.size < learner.train_buffer.rows:
            learner.collect()
        print(f"collected {len(learner.train_buffer)} training and {len(learner.val_buffer)} held-back frames "
              f"in {time.perf_counter() - t0:.0f} s (open loop + noise sigma {cfg.policy.sigma})", flush=True)
        windows = learner.val_buffer.sample_windows(args.windows, 2, np.random.default_rng(1))
        head = humanoid.head_index
        e = one_frame_errors(learner, windows, head)
        print(acceleration_spread(learner, windows))
        print(f"update 0: {summary_line(e, humanoid.body_names)}", flush=True)
        t0 = time.perf_counter()
        for u in range(1, args.updates + 1):
            m = learner._world_model_step()
            if u % args.eval_every == 0 or u == args.updates:
                e = one_frame_errors(learner, windows, head)
                print(f"update {u} ({time.perf_counter() - t0:.0f} s, loss {m['losses/world_model']:.3f}): "
                      f"{summary_line(e, humanoid.body_names)}", flush=True)  # fmt: skip
    finally:
        learner.close()
    print(f"\n{'body':<16}{'up: W angvel':>13}{'const':>7}{'fallen: W':>11}{'const':>7}{'W vel up':>10}{'const':>7}")
    up, down = e["up"], ~e["up"]
    for i, name in enumerate(humanoid.body_names):
        print(f"{name:<16}{e['w_ang'][up, i].mean():>13.2f}{e['c_ang'][up, i].mean():>7.2f}"
              f"{e['w_ang'][down, i].mean():>11.2f}{e['c_ang'][down, i].mean():>7.2f}"
              f"{e['w_vel'][up, i].mean():>10.3f}{e['c_vel'][up, i].mean():>7.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
