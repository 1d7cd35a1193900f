"""Probe: LQR-trees with SAMCON: the main path + recovery paths searched from states where the tree policy falls
(random starts, not the evaluator's), each stabilised by TVLQR; policy = least cost-to-go path.

usage: lqr3.py RUN_DIR CLIP '{opts}'
"""

import json
import sys
import time
from dataclasses import replace

import h5py
import mujoco
import numpy as np

sys.path.insert(0, "results/session18-samcon/scratch")
from lqr2 import linearise, riccati  # noqa: E402

from common.character.humanoid import Humanoid  # noqa: E402
from common.maths.rotations import quat_from_yaw, quat_mul, quat_rotate, quat_yaw  # noqa: E402
from common.motion.dataset import load_motions  # noqa: E402
from common.sim.gym import GymConfig, TrackingGym  # noqa: E402
from common.train.config import load_config  # noqa: E402
from common.train.evaluate import evaluate  # noqa: E402
from samcon import store  # noqa: E402
from samcon.config import SamconConfig  # noqa: E402
from samcon.search import samcon  # noqa: E402

run, clip = sys.argv[1], sys.argv[2]
w = {"rp": 0.0, "rz": 0.0, "rr": 25.0, "h": 10.0, "v": 1.0, "w": 0.1, "hv": 0.01, "u": 10.0, "lim": 0.5,
     "eps": 1e-6, "rounds": 3, "episodes": 24, "lead": 36, "segments": 8, "seed": 0, "sigma": 0.1}
w.update(json.loads(sys.argv[3]) if len(sys.argv) > 3 else {})
cfg = load_config(SamconConfig, f"{run}/config.yaml", [])
humanoid = Humanoid(cfg.gym.physics)
library = load_motions([clip], humanoid)
m = humanoid.model
nv, nu = m.nv, m.nu
q = np.concatenate([[w["rp"], w["rp"], w["rz"]], [w["rr"]] * 3, [w["h"]] * (nv - 6),
                    [w["v"]] * 3, [w["w"]] * 3, [w["hv"]] * (nv - 6)])
Q, R = np.diag(q), w["u"] * np.eye(nu)
plans, _ = store.load_plans(f"{run}/samcon.h5", humanoid.physics.control_hz)
with h5py.File(f"{run}/samcon.h5") as f:
    start_state = f[f"clips/{clip}/start_state"][()]
    grid = f[f"clips/{clip}/bounds"][()]
targets0 = plans[clip].targets
F = len(targets0)
z = np.load(f"{run}/lin-{clip}-{w['eps']}.npz")
K0, P0 = riccati(z["A"], z["B"], Q, R, Q)
paths = [(0, F, targets0, z["qpos"], z["qvel"], K0, P0)]  # (first, end, targets, qpos, qvel, K, P) frame-indexed
loop = int(round(library.duration[0] / library.dt)) if library.loop[0] else None
dq = np.zeros(nv)


def wrap(f):
    if loop and f >= F:
        f -= int(np.ceil((f - F + 1) / loop)) * loop
    return min(max(f, 0), F - 1)


def policy(result):
    n = len(result.clip)
    out = np.zeros((n, nu))
    frame = np.rint(result.time / library.dt).astype(int)
    for i in range(n):
        f = int(frame[i])
        g = wrap(f)
        qpos, qvel = result.sim.qpos[i].copy(), result.sim.qvel[i].copy()
        if g != f:
            ref_g = library.query(np.array([0]), np.array([g * library.dt]))
            r_f, r_g = result.ref.qpos[i], ref_g.qpos[0]
            qz = quat_from_yaw(np.array(float(quat_yaw(r_g[3:7]) - quat_yaw(r_f[3:7]))))
            p = qpos[:3].copy()
            p[:2] -= r_f[:2]
            p = quat_rotate(qz, p)
            p[:2] += r_g[:2]
            qpos[:3] = p
            qpos[3:7] = quat_mul(qz, qpos[3:7])
            qvel[:3] = quat_rotate(qz, qvel[:3])
        best = None
        for first, end, targets, qpos_n, qvel_n, K, P in paths:
            if not first <= g < end:
                continue
            k = g - first
            mujoco.mj_differentiatePos(m, dq, 1.0, qpos_n[k], qpos)
            dx = np.concatenate([dq, qvel - qvel_n[k]])
            v = float(dx @ P[k] @ dx)
            if best is None or v < best[0]:
                best = (v, targets[k] + np.clip(K[k] @ dx, -w["lim"], w["lim"]))
        out[i] = best[1]
    return out


def judge(label):
    t0 = time.perf_counter()
    res = evaluate(policy, library, humanoid, replace(cfg.train.eval, starts_per_clip=16, max_frames=512))
    o = res.overall
    print(label, len(paths), "paths:", json.dumps({k: round(float(o[k]), 3) for k in (
        "survival", "episode_len_ratio", "mpjpe_g", "mpjpe_g_succ", "mpjpe_l_succ")}), res.episode_length.tolist(),
        f"{time.perf_counter() - t0:.0f} s", flush=True)


def visits(rng, n):
    """Random start frames in the first cycle (not the evaluator's); states at grid frames; falls."""
    cid = 0
    first = rng.integers(0, loop, n)
    gym = TrackingGym(GymConfig(num_envs=n, threads=1, seed=cfg.train.eval.seed, physics=humanoid.physics,
                                termination=cfg.train.eval.termination, rsi_lift=cfg.train.eval.rsi_lift),
                      library, humanoid)
    on_grid = set(int(x) for x in grid[:-1])
    states = [{} for _ in range(n)]
    failed = np.full(n, -1)
    result = gym.reset(clips=np.full(n, cid), times=first * library.dt)
    alive = np.ones(n, dtype=bool)
    for step in range(1, 513):
        result = gym.step(policy(result), autoreset=False)
        frame = first + step
        newly = alive & result.terminated
        failed[newly] = frame[newly]
        alive &= ~result.terminated
        for i in np.flatnonzero(alive):
            g = wrap(int(frame[i]))
            if g in on_grid and frame[i] == g:  # only states before the wrap
                states[i][g] = gym.sim.state[i].copy()
        if not alive.any():
            break
    gym.close()
    out = []
    seg = int(w["segments"])
    for i in np.flatnonzero(failed >= 0):
        ok = [f for f in states[i] if f <= failed[i] - w["lead"] and np.searchsorted(grid, f) + seg <= len(grid) - 1]
        if ok:
            out.append((max(ok), states[i][max(ok)]))
    return out, float(np.mean(failed >= 0)), failed


judge("start")
rng = np.random.default_rng(int(w["seed"]))
search = replace(cfg.search, sigma_init=w["sigma"])
for r in range(int(w["rounds"])):
    t0 = time.perf_counter()
    vs, share, failed = visits(rng, int(w["episodes"]))
    print(f"round {r + 1}: {share:.0%} of visit episodes fell; {len(vs)} searches", flush=True)
    for first, state in vs:
        i = int(np.searchsorted(grid, first))
        end = int(grid[i + int(w["segments"])])
        traj = samcon(humanoid, library, 0, F, search, cfg.cost, rng, start_frame=first, end_frame=end, start=state)
        if traj.segment_terms["fallen"].sum() > 0:
            print(f"  search from {first} fell; dropped")
            continue
        A_f, B_f, qpos_n, qvel_n = linearise(m, state, traj.targets, humanoid.physics.substeps, w["eps"])
        K, P = riccati(A_f, B_f, Q, R, P0[end] if end < F else Q)
        paths.append((first, end, traj.targets, qpos_n, qvel_n, K, P))
    print(f"round {r + 1} took {time.perf_counter() - t0:.0f} s", flush=True)
    judge(f"after round {r + 1}")
