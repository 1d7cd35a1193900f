"""The HDF5 file of a SAMCON run: per clip, the open-loop trajectory, its costs and the linear feedback policies.

Layout (``samcon.h5``): attribute ``format = mimictrack.samcon``, ``version``, ``control_hz``, ``features`` (names);
group ``clips/<name>`` with datasets ``targets`` (F, nu), ``offsets`` (S, nu), ``bounds`` (S + 1,),
``segment_cost`` (S,), ``terms/<term>`` (S,), ``start_state`` (nstate,), ``end_states`` (S, nstate), ``gain``
(S, nu, D), ``bias`` (S, nu), with ``feedback.anchor: nearest`` also ``anchor_features`` (S, P, D),
``anchor_offsets`` (S, P, nu) and ``feature_scale`` (D,), with ``optimise.generations`` > 0 ``ref_gain`` (G, nu, D)
and ``ref_limit`` (), with ``optimise.offsets`` also ``ref_offset`` (S, nu) (see :class:`samcon.feedback.ClipPlan`),
with ``feedback.index: phase`` also ``plan_bounds`` (the first cycle's segments, which gain, bias and anchors index),
with ``lqr.enabled`` a group ``lqr`` (attribute ``limit``) of groups ``0``, ``1``, ... (the path from the clip's start
first; attribute ``first``) with ``targets``, ``qpos``, ``qvel``, ``gain`` and, where a clip has several paths,
``cost_to_go`` (see :class:`samcon.lqr.LqrPath`), and attributes ``samples``, ``seconds``. With ``polish``
(:mod:`samcon.polish`) ``targets``, ``offsets``, ``segment_cost``, ``terms`` and ``end_states`` are the polished
path's (each segment's offset then its mean). Written to a temporary
file and renamed.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from common.config import hdf5_output
from samcon.cost import FEATURE_NAMES
from samcon.feedback import ClipPlan
from samcon.lqr import LqrPath
from samcon.search import Trajectory

FORMAT = "mimictrack.samcon"
VERSION = 1
FILE_NAME = "samcon.h5"


_LQR = ("targets", "qpos", "qvel", "gain", "cost_to_go")
_OPTIONAL = ("anchor_features", "anchor_offsets", "feature_scale", "ref_gain", "ref_limit", "ref_offset")


def save(path: str | Path, control_hz: float, results: list[tuple[Trajectory, ClipPlan]]) -> None:
    """Writes [(trajectory, its plan)] atomically."""
    path = Path(path)
    with hdf5_output(path) as f:
        f.attrs.update(format=FORMAT, version=VERSION, control_hz=control_hz)
        f.attrs["features"] = np.array(FEATURE_NAMES, dtype="S")
        for traj, plan in results:
            g = f.create_group(f"clips/{traj.clip}")
            for name in ("targets", "offsets", "bounds", "segment_cost", "start_state", "end_states"):
                g.create_dataset(name, data=getattr(traj, name))
            for name, values in traj.segment_terms.items():
                g.create_dataset(f"terms/{name}", data=values)
            if not np.array_equal(plan.bounds, traj.bounds):
                g.create_dataset("plan_bounds", data=plan.bounds)
            for name in ("gain", "bias", *_OPTIONAL):
                if getattr(plan, name) is not None and (name != "ref_limit" or plan.ref_gain is not None):
                    g.create_dataset(name, data=getattr(plan, name))
            if plan.lqr:
                lqr = g.create_group("lqr")
                lqr.attrs["limit"] = plan.lqr_limit
                for j, lqr_path in enumerate(plan.lqr):
                    p = lqr.create_group(str(j))
                    p.attrs["first"] = lqr_path.first
                    for name in _LQR:
                        # A clip's only path needs no cost-to-go (nothing to choose between): left out.
                        if name != "cost_to_go" or len(plan.lqr) > 1:
                            p.create_dataset(name, data=getattr(lqr_path, name))
            g.attrs.update(samples=traj.samples, seconds=traj.seconds, backtracks=traj.backtracks)


def load_plans(path: str | Path, control_hz: float) -> tuple[dict[str, ClipPlan], dict[str, dict[str, float]]]:
    """The plans of every clip and {clip: {"samples", "seconds"}}.

    Raises:
        ValueError: If the file is not a SAMCON file of this version and control rate, or its features differ.
    """
    path = Path(path)
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise ValueError(f"{path}: not a readable HDF5 file ({e})") from None
    with f:
        if f.attrs.get("format") != FORMAT or int(f.attrs.get("version", -1)) != VERSION:
            raise ValueError(f"{path}: not a {FORMAT} file of version {VERSION}")
        if abs(float(f.attrs["control_hz"]) - control_hz) > 1e-9:
            rate = float(f.attrs["control_hz"])
            raise ValueError(f"{path}: tracked at {rate:g} Hz, the model runs at {control_hz:g} Hz")
        if tuple(n.decode() for n in f.attrs["features"]) != FEATURE_NAMES:
            raise ValueError(f"{path}: feedback features {list(f.attrs['features'])} differ from this version's")
        plans, info = {}, {}
        for name, g in f["clips"].items():
            anchors = {k: g[k][()] for k in _OPTIONAL if k in g}
            if "ref_limit" in anchors:
                anchors["ref_limit"] = float(anchors["ref_limit"])
            bounds = g["plan_bounds"][()] if "plan_bounds" in g else g["bounds"][()]
            if "lqr" in g:
                lqr = g["lqr"]
                anchors["lqr"] = [LqrPath(int(lqr[j].attrs["first"]), *(lqr[j][k][()] if k in lqr[j] else None
                                                                         for k in _LQR))
                                  for j in sorted(lqr, key=int)]  # fmt: skip
                anchors["lqr_limit"] = float(lqr.attrs["limit"])
            plans[name] = ClipPlan(targets=g["targets"][()], bounds=bounds, gain=g["gain"][()],
                                   bias=g["bias"][()], **anchors)  # fmt: skip
            info[name] = {"samples": int(g.attrs["samples"]), "seconds": float(g.attrs["seconds"])}
    return plans, info
