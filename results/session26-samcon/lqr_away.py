"""Probe (session 26, #17): can joint feedback stand in for the last root couple? A path polished with a couple as a
control (``samcon.assist --then-couple``, stage ``then_couple_<i>``) is replayed with its couple held; its states are
linearised with that couple held (``samcon.lqr.linearise``) and a time-varying LQR on the targets alone is computed
(``samcon.lqr.riccati``, the ``lqr:`` weights of ``polish.yaml``, overridden by KEY=VALUE). Then from the clip's start,
without the couple, the LQR tracks those states: ``u*_t + clip(K_t dx)``. The targets it applied are an open-loop path
(checked: replayed plainly they give the same states bit for bit), judged as ``samcon.assist`` judges.

    python results/session26-samcon/lqr_away.py results/session25-samcon/couple2-cartwheel.npz then_couple_1 \
        [KEY=VALUE ...]
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from common.character.humanoid import Humanoid  # noqa: E402
from common.motion.dataset import load_motions  # noqa: E402
from common.train.config import load_config  # noqa: E402
from samcon.assist import judge  # noqa: E402
from samcon.config import SamconConfig  # noqa: E402
from samcon.lqr import linearise, nominal_states, riccati, state_weights  # noqa: E402
from samcon.polish import Couple, forward_pass  # noqa: E402
from samcon.search import reference_frames, replay  # noqa: E402


def main(argv: list[str]) -> None:
    path, stage, overrides = argv[0], argv[1], dict(a.split("=") for a in argv[2:])
    saved = np.load(path)
    clip = saved.files[0].split("/")[0]
    cfg = load_config(SamconConfig, "configs/samcon/polish.yaml")
    lqr = replace(cfg.lqr, **{k: float(v) for k, v in overrides.items()})
    humanoid = Humanoid(cfg.gym.physics)
    library = load_motions([clip], humanoid)
    start, targets, couple = saved[f"{clip}/start_state"], saved[f"{clip}/{stage}"], saved[f"{clip}/{stage}_couple"]
    frames = len(targets)
    ref = reference_frames(library, 0, frames)
    law = Couple(couple, 1.0).law(humanoid.nv)
    states = nominal_states(humanoid, start, targets, law)
    shown = ("mpjpe_g", "mpjpe_l", "fell_at")
    with_couple = judge(humanoid, states[1:], ref[1:], cfg.train.eval)
    a, b = linearise(humanoid, states, targets, lqr.eps, law)
    q = np.diag(state_weights(humanoid, lqr))
    gain = riccati(a, b, q, lqr.control * np.eye(humanoid.nu), q)[0]
    out, applied, _ = forward_pass(humanoid, start, states, targets, np.zeros((frames, humanoid.nu)), gain,
                                   np.zeros(1), lqr.limit)  # fmt: skip
    again = replay(humanoid, start, applied[0], cfg.gym.max_speed)
    assert np.array_equal(again, out[0, 1:]), "the applied targets do not replay to the LQR's states"
    without = judge(humanoid, again, ref[1:], cfg.train.eval)
    fig = lambda j: [round(j[k] or -1, 1) for k in shown]  # noqa: E731
    print(f"{clip} {stage} {overrides or 'polish.yaml lqr'}: with the couple {fig(with_couple)}; LQR without it "
          f"{fig(without)} (MPJPE-g, -l mm, fell at; -1: no fall)")


if __name__ == "__main__":
    main(sys.argv[1:])
