"""Probe: several SAMCON paths each stabilised by time-varying LQR; the policy follows the path of least
cost-to-go (LQR-trees style switching).

usage: lqr2.py CLIP '{weights}' RUN_DIR [RUN_DIR ...]
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

MASK = np.zeros(68, dtype=bool)
FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS


def linearise(m, start_state, targets, substeps, eps):
    d = mujoco.MjData(m)
    mujoco.mj_setState(m, d, start_state, FULL)
    nv, nu, F = m.nv, m.nu, len(targets)
    A_f, B_f = np.zeros((F, 2 * nv, 2 * nv)), np.zeros((F, 2 * nv, nu))
    qpos, qvel = np.zeros((F + 1, m.nq)), np.zeros((F + 1, nv))
    A, B = np.zeros((2 * nv, 2 * nv)), np.zeros((2 * nv, nu))
    for f in range(F):
        qpos[f], qvel[f] = d.qpos, d.qvel
        d.ctrl[:] = targets[f]
        Af, Bf = np.eye(2 * nv), np.zeros((2 * nv, nu))
        for _ in range(substeps):
            mujoco.mjd_transitionFD(m, d, eps, True, A, B, None, None)
            Af, Bf = A @ Af, A @ Bf + B
            mujoco.mj_step(m, d)
        A_f[f], B_f[f] = Af, Bf
    qpos[F], qvel[F] = d.qpos, d.qvel
    return A_f, B_f, qpos, qvel


def linearise_sampled(humanoid, start_state, targets, scale, n, seed=0):
    from common.sim.sim import BatchedSim
    m = humanoid.model
    nv, nu, F = m.nv, m.nu, len(targets)
    rng = np.random.default_rng(seed)
    one = BatchedSim(humanoid, 1, threads=1)
    one.state[0] = start_state
    states = np.zeros((F + 1, len(start_state)))
    states[0] = start_state
    for f in range(F):
        one.step(targets[f][None])
        states[f + 1] = one.state[0]
    qp = slice(1, 1 + m.nq)
    qv = slice(1 + m.nq, 1 + m.nq + nv)
    sig = np.concatenate([[0.01] * 3, [0.02] * 3, [0.02] * (nv - 6), [0.1] * 3, [0.2] * 3, [0.2] * (nv - 6)]) * scale
    sig_u = 0.05 * scale
    sim = BatchedSim(humanoid, n, threads=1)
    A_f, B_f = np.zeros((F, 2 * nv, 2 * nv)), np.zeros((F, 2 * nv, nu))
    dq, tmp = np.zeros(nv), np.zeros(m.nq)
    for f in range(F):
        half = n // 2
        dx = rng.standard_normal((half, 2 * nv)) * sig
        du = rng.standard_normal((half, nu)) * sig_u
        dx, du = np.concatenate([dx, -dx]), np.concatenate([du, -du])
        sim.state[:] = states[f]
        for i in range(n):
            tmp[:] = states[f, qp]
            mujoco.mj_integratePos(m, tmp, dx[i, :nv], 1.0)
            sim.state[i, qp] = tmp
        sim.state[:, qv] += dx[:, nv:]
        sim.step(targets[f][None] + du)
        y = np.zeros((n, 2 * nv))
        for i in range(n):
            mujoco.mj_differentiatePos(m, dq, 1.0, states[f + 1, qp], sim.state[i, qp])
            y[i, :nv] = dq
        y[:, nv:] = sim.state[:, qv] - states[f + 1, qv]
        X = np.concatenate([dx, du, np.ones((n, 1))], axis=1)
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        A_f[f], B_f[f] = coef[: 2 * nv].T, coef[2 * nv : 2 * nv + nu].T
    return A_f, B_f, states[:, qp], states[:, qv]


def riccati(A_f, B_f, Q, R, P_end):
    F, n, nu = len(A_f), A_f.shape[1], B_f.shape[2]
    K, Ps = np.zeros((F, nu, n)), np.zeros((F, n, n))
    P = P_end
    for f in range(F - 1, -1, -1):
        a, b = A_f[f], B_f[f]
        K[f] = -np.linalg.solve(R + b.T @ P @ b, b.T @ P @ a)
        P = Q + a.T @ P @ (a + b @ K[f])
        P = 0.5 * (P + P.T)
        Ps[f] = P
    return K, Ps


def main():
    clip = sys.argv[1]
    w = {"rp": 0.0, "rz": 0.0, "rr": 25.0, "h": 10.0, "v": 1.0, "w": 0.1, "hv": 0.01, "u": 10.0, "lim": 0.5,
         "eps": 1e-6, "starts": 16, "frames": 512, "qf": 1.0, "switch": "step", "paths": 99}
    w.update(json.loads(sys.argv[2]))
    runs = sys.argv[3:][: int(w["paths"])]
    cfg = load_config(SamconConfig, f"{runs[0]}/config.yaml", [])
    humanoid = Humanoid(cfg.gym.physics)
    library = load_motions([clip], humanoid)
    m = humanoid.model
    nv, nu = m.nv, m.nu
    q = np.concatenate([[w["rp"], w["rp"], w["rz"]], [w["rr"]] * 3, [w["h"]] * (nv - 6),
                        [w["v"]] * 3, [w["w"]] * 3, [w["hv"]] * (nv - 6)])
    Q, R = np.diag(q), w["u"] * np.eye(nu)
    paths = []
    for run in runs:
        plans, _ = store.load_plans(f"{run}/samcon.h5", humanoid.physics.control_hz)
        with h5py.File(f"{run}/samcon.h5") as f:
            start_state = f[f"clips/{clip}/start_state"][()]
        targets = plans[clip].targets
        tag = w["eps"] if "smooth" not in w else f"s{w['smooth']}-{w.get('n', 256)}"
        cache = f"{run}/lin-{clip}-{tag}.npz"
        if os.path.exists(cache):
            z = np.load(cache)
            A_f, B_f, qpos_n, qvel_n = z["A"], z["B"], z["qpos"], z["qvel"]
        else:
            t0 = time.perf_counter()
            if "smooth" in w:
                n = int(w.get("n", 256))
                A_f, B_f, qpos_n, qvel_n = linearise_sampled(humanoid, start_state, targets, w["smooth"], n)
            else:
                A_f, B_f, qpos_n, qvel_n = linearise(m, start_state, targets, humanoid.physics.substeps, w["eps"])
            np.savez(cache, A=A_f, B=B_f, qpos=qpos_n, qvel=qvel_n)
            print(f"{run}: linearised in {time.perf_counter() - t0:.1f} s")
        K, Ps = riccati(A_f, B_f, Q, R, w["qf"] * Q)
        paths.append((0, targets, qpos_n, qvel_n, K, Ps))
    F = min(len(p[1]) for p in paths)
    loop = int(round(library.duration[0] / library.dt)) if library.loop[0] else None
    dq = np.zeros(nv)
    chosen = {}

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
            key = int(result.episode_id[i])
            ts = int(w.get("tshift", 0))
            for j, (_, _targets, qpos_n, qvel_n, _gain, Ps) in enumerate(paths):
                if w["switch"] == "start" and key in chosen and chosen[key] != j:
                    continue
                for gg in range(max(0, g - ts), min(F - 1, g + ts) + 1):
                    mujoco.mj_differentiatePos(m, dq, 1.0, qpos_n[gg], qpos)
                    dx = np.concatenate([dq, qvel - qvel_n[gg]])
                    dx[MASK] = 0.0
                    v = float(dx @ Ps[gg] @ dx) * (1.0 + w.get("tpen", 0.0) * abs(gg - g))
                    if best is None or v < best[0]:
                        best = (v, j, dx, gg)
            chosen.setdefault(key, best[1])
            _, targets, _, _, K, _ = paths[best[1]]
            gg = best[3]
            out[i] = targets[gg] + np.clip(K[gg] @ best[2], -w["lim"], w["lim"])
        return out

    MASK[:] = False
    for part in w.get("mask", []):
        parts = {"hv": slice(nv + 6, None), "w": slice(nv + 3, nv + 6), "v": slice(nv, nv + 3), "rp": slice(0, 3)}
        MASK[parts[part]] = True
    ev = replace(cfg.train.eval, starts_per_clip=int(w["starts"]), max_frames=int(w["frames"]))
    res = evaluate(policy, library, humanoid, ev)
    o = res.overall
    print(json.dumps({k: round(float(o[k]), 3) for k in ("survival", "episode_len_ratio", "mpjpe_g", "mpjpe_g_succ",
                                                          "mpjpe_l_succ")}), res.episode_length.tolist())


if __name__ == "__main__":
    main()
