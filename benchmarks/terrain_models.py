"""Characters on different terrains in one rollout: a model per terrain, or PARC's grid of tiles in one model.

``mujoco.rollout`` takes one model per character. Three ways to step N characters tracking walk, each on one of K
rough terrains (+-3 cm, 0.1 m cells, 6 m x 2 m), timed in alternating blocks of control steps (8 substeps each) so
that a busy machine slows all three alike:
- ``flat``: every character in the flat model (the baseline, no terrain);
- ``per-terrain``: each character in its terrain's model (what ``common/sim/terrain.py`` does);
- ``tiles``: one model with the K terrains side by side (PARC's grid), each character moved onto its tile.

    nice -n 19 python benchmarks/terrain_models.py --envs 64 --terrains 8 --threads 1
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np
from mujoco import rollout

from common.character.humanoid import Humanoid, apply_physics
from common.motion.dataset import resolve_clips
from common.motion.library import MotionLibrary
from common.motion.terrain_generator import rough
from common.sim.terrain import FLOOR_GEOM, add_terrain, terrain_model

TILE_GAP = 1.0  # m between tiles


def tiles_model(humanoid: Humanoid, terrains: list) -> tuple[mujoco.MjModel, np.ndarray]:
    """One model holding every terrain as a tile along y; returns it and each tile's offset (K, 2)."""
    spec = mujoco.MjSpec.from_file(str(humanoid.xml_path))
    floor = spec.geom(FLOOR_GEOM)
    offsets = np.zeros((len(terrains), 2))
    for k, t in enumerate(terrains):
        offsets[k, 1] = k * (t.size[1] + TILE_GAP)
        child = mujoco.MjSpec()
        child_floor = child.worldbody.add_geom(name=FLOOR_GEOM, type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05])
        add_terrain(child, t, child_floor)
        hf = child.hfields[0]
        g = [g for g in child.geoms if g.type == mujoco.mjtGeom.mjGEOM_HFIELD][0]
        spec.add_hfield(name=f"tile{k}", nrow=hf.nrow, ncol=hf.ncol, size=hf.size, userdata=hf.userdata)
        spec.worldbody.add_geom(
            name=f"tile{k}", type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname=f"tile{k}",
            pos=[g.pos[0], g.pos[1] + offsets[k, 1], g.pos[2]], contype=floor.contype,
            conaffinity=floor.conaffinity, condim=floor.condim, friction=floor.friction,
        )  # fmt: skip
    floor.pos = [0.0, 0.0, min(t.floor for t in terrains)]
    model = spec.compile()
    apply_physics(model, humanoid.physics)
    return model, offsets


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--terrains", type=int, default=8)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--blocks", type=int, default=5)
    parser.add_argument("--steps", type=int, default=20, help="control steps per block")
    args = parser.parse_args()
    humanoid = Humanoid()
    n, k = args.envs, args.terrains
    terrains = [rough(length=4.0, seed=s) for s in range(k)]
    library = MotionLibrary.from_clips(resolve_clips(["walk"]), humanoid)
    times = (np.arange(n) % 30) * library.dt
    ref = library.query(np.zeros(n, dtype=np.int64), times)
    qpos0 = ref.qpos.copy()
    qpos0[:, 2] += 0.03  # above the bumps
    which = np.arange(n) % k
    per_terrain = [terrain_model(humanoid, t) for t in terrains]
    tiles, offsets = tiles_model(humanoid, terrains)
    flat = terrain_model(humanoid, None)
    setups = {
        "flat": ([flat] * n, qpos0),
        "per-terrain": ([per_terrain[i] for i in which], qpos0),
        "tiles": ([tiles] * n, qpos0 + np.pad(offsets[which], ((0, 0), (0, humanoid.nq - 2)))),
    }
    substeps = humanoid.physics.substeps
    pool = rollout.Rollout(nthread=args.threads if args.threads > 1 else 0)
    nstate = mujoco.mj_stateSize(flat, mujoco.mjtState.mjSTATE_FULLPHYSICS.value)
    ctrl = np.repeat(ref.qpos[:, humanoid.hinge_qpos][:, None], substeps, axis=1)
    spent = {name: 0.0 for name in setups}
    for _ in range(args.blocks):
        for name, (models, qpos) in setups.items():
            datas = [mujoco.MjData(models[0]) for _ in range(max(1, args.threads))]
            state = np.zeros((n, nstate))
            state[:, 1 : 1 + humanoid.nq] = qpos
            out = np.zeros((n, substeps, nstate))
            start = time.perf_counter()
            for _ in range(args.steps):
                pool.rollout(models, datas, state, ctrl, state=out, nstep=substeps, skip_checks=True)
                state[:] = out[:, -1]
            spent[name] += time.perf_counter() - start
    pool.close()
    total_steps = args.blocks * args.steps
    for name, seconds in spent.items():
        print(
            f"{name:12s} {1e3 * seconds / total_steps:7.2f} ms per control step of {n} characters "
            f"({n * total_steps / seconds:,.0f} character-steps/s), {spent['flat'] / seconds:.3f} x flat"
        )


if __name__ == "__main__":
    main()
