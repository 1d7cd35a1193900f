"""Probe: time-varying LQR around a SAMCON open-loop trajectory, judged by the shared evaluator.

usage: lqr.py RUN_DIR CLIP [json of weights]
"""

import json
import os
import sys
import time
from dataclasses import replace

import h5py
import mujoco
import numpy as np

from common.character.humanoid import Humanoid
from common.maths.rotations import quat_from_yaw, quat_mul, quat_rotate, quat_yaw
from common.motion.dataset import load_motions
from common.train.config import load_config
from common.train.evaluate import evaluate
from samcon import store
from samcon.config import SamconConfig

run, clip = sys.argv[1], sys.argv[2]
w = {"rp": 0.0, "rz": 0.0, "rr": 25.0, "h": 10.0, "v": 1.0, "w": 0.1, "hv": 0.01, "u": 100.0, "lim": 0.5,
     "eps": 1e-6, "starts": 16, "frames": 512, "qf": 1.0}
if len(sys.argv) > 3:
    w.update(json.loads(sys.argv[3]))
cfg = load_config(SamconConfig, f"{run}/config.yaml", [])
humanoid = Humanoid(cfg.gym.physics)
library = load_motions([clip], humanoid)
plans, _ = store.load_plans(f"{run}/samcon.h5", humanoid.physics.control_hz)

with h5py.File(f"{run}/samcon.h5") as f:
    start_state = f[f"clips/{clip}/start_state"][()]
    end_states = f[f"clips/{clip}/end_states"][()]
    bounds = f[f"clips/{clip}/bounds"][()]
targets = plans[clip].targets
m = humanoid.model
d = mujoco.MjData(m)
FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
mujoco.mj_setState(m, d, start_state, FULL)
nv, nu, F, S = m.nv, m.nu, len(targets), humanoid.physics.substeps
A_f = np.zeros((F, 2 * nv, 2 * nv))
B_f = np.zeros((F, 2 * nv, nu))
qpos_n = np.zeros((F + 1, m.nq))
qvel_n = np.zeros((F + 1, nv))
A = np.zeros((2 * nv, 2 * nv))
B = np.zeros((2 * nv, nu))
t0 = time.perf_counter()
state = np.zeros(mujoco.mj_stateSize(m, FULL.value))

cache = f"{run}/lin-{clip}-{w['eps']}.npz"
for f in range(F if not os.path.exists(cache) else 0):
    qpos_n[f], qvel_n[f] = d.qpos, d.qvel
    d.ctrl[:] = targets[f]
    Af, Bf = np.eye(2 * nv), np.zeros((2 * nv, nu))
    for _ in range(S):
        mujoco.mjd_transitionFD(m, d, w["eps"], True, A, B, None, None)
        Af, Bf = A @ Af, A @ Bf + B
        mujoco.mj_step(m, d)
    A_f[f], B_f[f] = Af, Bf
if os.path.exists(cache):
    z = np.load(cache)
    A_f, B_f, qpos_n, qvel_n = z["A"], z["B"], z["qpos"], z["qvel"]
else:
    qpos_n[F], qvel_n[F] = d.qpos, d.qvel
    np.savez(cache, A=A_f, B=B_f, qpos=qpos_n, qvel=qvel_n)
mujoco.mj_getState(m, d, state, FULL)
print(f"linearised {F} frames in {time.perf_counter() - t0:.1f} s; replay vs stored end state: "
      f"{np.abs(state[1:] - end_states[-1][1:]).max():.2e}")
# Riccati
q = np.concatenate([[w["rp"], w["rp"], w["rz"]], [w["rr"]] * 3, [w["h"]] * (nv - 6),
                    [w["v"]] * 3, [w["w"]] * 3, [w["hv"]] * (nv - 6)])
Q, R = np.diag(q), w["u"] * np.eye(nu)
P = w["qf"] * Q
K = np.zeros((F, nu, 2 * nv))
Pf = np.zeros((F, 2 * nv, 2 * nv))
for f in range(F - 1, -1, -1):
    a, b = A_f[f], B_f[f]
    K[f] = -np.linalg.solve(R + b.T @ P @ b, b.T @ P @ a)
    P = Q + a.T @ P @ (a + b @ K[f])
    P = 0.5 * (P + P.T)
    Pf[f] = P
print("gain norms (first, mid, last):", np.linalg.norm(K[0]), np.linalg.norm(K[F // 2]), np.linalg.norm(K[-1]))

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
            dyaw = float(quat_yaw(r_g[3:7]) - quat_yaw(r_f[3:7]))
            qz = quat_from_yaw(np.array(dyaw))
            p = qpos[:3].copy()
            p[:2] -= r_f[:2]
            p = quat_rotate(qz, p)
            p[:2] += r_g[:2]
            qpos[:3] = p
            qpos[3:7] = quat_mul(qz, qpos[3:7])
            qvel[:3] = quat_rotate(qz, qvel[:3])
        mujoco.mj_differentiatePos(m, dq, 1.0, qpos_n[g], qpos)
        dx = np.concatenate([dq, qvel - qvel_n[g]])
        if result.episode_frame[i] == 0 and LOG is not None:
            LOG.append((f, float(dx @ Pf[g] @ dx), np.abs(dx[:nv]).max(), np.abs(dx[nv:]).max()))
        if TRACE is not None and i == TRACE[0]:
            u_fb = K[g] @ dx
            TRACE[1].append((int(result.episode_frame[i]), f, g, np.linalg.norm(dx[3:6]), dx[2],
                             np.sqrt(np.mean(dx[6:nv] ** 2)), np.linalg.norm(dx[nv : nv + 3]),
                             np.linalg.norm(dx[nv + 3 : nv + 6]), np.sqrt(np.mean(dx[nv + 6 :] ** 2)),
                             np.abs(u_fb).max(), float(dx @ Pf[g] @ dx)))
        out[i] = targets[g] + np.clip(K[g] @ dx, -w["lim"], w["lim"])
    return out


LOG = []
TRACE = (int(w.get("trace", 6)), []) if "trace" in w else None
ev = replace(cfg.train.eval, starts_per_clip=int(w["starts"]), max_frames=int(w["frames"]))
t0 = time.perf_counter()
res = evaluate(policy, library, humanoid, ev)
print(f"evaluated in {time.perf_counter() - t0:.1f} s")
o = res.overall
print({k: round(float(v), 3) for k, v in o.items() if np.isscalar(v)})
print("episode lengths:", res.episode_length.tolist())
for row, length in zip(LOG[: len(res.episode_length[0])], res.episode_length[0], strict=False):
    print(row[0], f"V0 {row[1]:.1f} maxdq {row[2]:.3f} maxdv {row[3]:.3f}", length)
LOG = None
if TRACE:
    print("ep_frame frame g |drot| dz hinge_rms |dv| |dw| hv_rms max|Kdx| V")
    for r in TRACE[1][::5]:
        print(" ".join(f"{x:.3g}" if isinstance(x, float) else str(x) for x in r))
TRACE = None
res0 = evaluate(policy, library, humanoid, replace(ev, starts_per_clip=1))
print("from start:", {k: round(float(v), 3) for k, v in res0.overall.items() if np.isscalar(v)})
