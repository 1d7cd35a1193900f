"""Which of the AMP discriminator's features tell a trained policy's motion from the reference's, feature by feature.

A run's deterministic policy plays its clip in the gym (RSI, the gym's rules) and every simulated state is paired
with the reference at the same clip time. Per feature group it prints the mean absolute paired difference over the
reference's own standard deviation across time (about 1 or more: the group alone tells them apart), and it names the
dimensions the reference holds still (std < 1e-3) while the simulation moves them: a discriminator separates those
perfectly, whatever the policy learns.

Then it trains a small discriminator (an MLP, 2 x 128 ELU, binary cross-entropy, the same for every input) on the
policy's transitions [s, s'] against expert transitions drawn as training draws them (:class:`ppo.amp_data.
ExpertSampler`: random clips and times), once per feature group alone and once on everything but that group, with the
still features zeroed as ``amp.still_std`` zeroes them, and prints the held-out accuracy of each. A group whose
"alone" accuracy is near 1 separates the two by itself; one whose removal drops the "all but" accuracy is what the
discriminator leans on.

    python benchmarks/amp_separability.py runs/ppo-walk --motions walk --steps 300
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import mujoco
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.character.humanoid import Humanoid  # noqa: E402
from common.motion.dataset import load_motions  # noqa: E402
from common.sim.gym import GymConfig, TrackingGym  # noqa: E402
from ppo.amp_data import AMPFeatures, ExpertSampler  # noqa: E402
from report.runs import export_module, load_run  # noqa: E402

STILL_STD = 1e-3


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", help="a SuperTrack or PPO run directory")
    parser.add_argument("--motions", nargs="+", default=["walk"], help="clips to play (default: walk)")
    parser.add_argument("--steps", type=int, default=300, help="control steps played (default: 300)")
    parser.add_argument("--envs", type=int, default=16, help="characters (default: 16)")
    parser.add_argument("--classifier-steps", type=int, default=400,
                        help="Adam steps of each per-group discriminator; 0 skips them (default: 400)")  # fmt: skip
    args = parser.parse_args(argv)
    run = load_run(args.run)
    humanoid = Humanoid(run.physics())
    library = load_motions(args.motions, humanoid)
    policy = export_module(run.learner).load_eval_policy(run.path, run.checkpoint, humanoid, library)
    gym = TrackingGym(GymConfig(num_envs=args.envs, threads=1, seed=3), library, humanoid)
    features = AMPFeatures(humanoid)
    res = gym.reset()
    sim: dict[str, list[np.ndarray]] = {}
    ref: dict[str, list[np.ndarray]] = {}
    now, nxt, ref_now, ref_nxt = [], [], [], []
    for _ in range(args.steps):
        now.append(features(res.sim))
        ref_now.append(features(res.ref))
        res = gym.step(policy(res))
        nxt.append(features(res.final_sim))
        ref_nxt.append(features(res.final_ref))
        for store, state in ((sim, res.sim), (ref, res.ref)):
            for name, value in features.named(state).items():
                store.setdefault(name, []).append(value.reshape(len(value), -1))
    actuators = [mujoco.mj_id2name(humanoid.model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(humanoid.nu)]
    print(f"{run.label} on {', '.join(args.motions)}: {args.steps} steps x {args.envs} characters")
    print(f"{'group':14s} {'dims':>4s} {'|sim - ref| / ref std (mean, max)':>34s} {'still in ref':>13s}")
    for name in sim:
        s, r = np.concatenate(sim[name]), np.concatenate(ref[name])
        ref_std = r.std(0)
        still = np.flatnonzero((ref_std < STILL_STD) & (s.std(0) >= STILL_STD))
        ratio = np.abs(s - r).mean(0) / np.maximum(ref_std, STILL_STD)
        print(f"{name:14s} {s.shape[1]:4d} {ratio.mean():17.2f} {ratio.max():16.2f} {len(still):13d}")
        if name == "joint_vel" and len(still):
            print("    hinges the reference holds still: " + ", ".join(
                f"{actuators[i]} (sim std {s[:, i].std():.2f} rad/s)" for i in still))  # fmt: skip

    if args.classifier_steps:
        policy_rows = np.concatenate([np.concatenate(now), np.concatenate(nxt)], axis=-1)
        expert = ExpertSampler(library, features).sample(len(policy_rows), np.random.default_rng(4))
        expert_rows = np.concatenate(expert, axis=-1)
        control_rows = np.concatenate([np.concatenate(ref_now), np.concatenate(ref_nxt)], axis=-1)
        group_accuracies(features, library, policy_rows, expert_rows, control_rows, args.classifier_steps)


def group_accuracies(features: AMPFeatures, library, policy_rows: np.ndarray, expert_rows: np.ndarray,
                     control_rows: np.ndarray, steps: int) -> None:  # fmt: skip
    """Prints the held-out accuracy of a discriminator trained on each feature group alone and on all but it, after a
    control: the same discriminator on the reference at the policy's own clip times against the expert sampler's
    transitions, which must stay near 0.5 (both are the reference; only their clip times' distribution differs)."""
    d = features.size
    every = np.concatenate(ExpertSampler(library, features).at(*_all_frames(library)))
    active = every.std(0) >= STILL_STD
    print(f"\ndiscriminators on [s, s'] ({len(policy_rows)} policy and as many expert transitions, a quarter held "
          f"out; still features zeroed), held-out accuracy:")  # fmt: skip
    control = _accuracy(control_rows, expert_rows, np.tile(active, 2), steps)
    print(f"control, the reference at the policy's clip times against the expert's draws: {control:.3f}")
    print(f"{'group':14s} {'alone':>7s} {'all but it':>11s}")
    groups = dict(features.layout)
    print(f"{'(all)':14s} {_accuracy(policy_rows, expert_rows, np.tile(active, 2), steps):7.3f}")
    for name, sl in groups.items():
        alone = np.zeros(d, dtype=bool)
        alone[sl] = True
        a = _accuracy(policy_rows, expert_rows, np.tile(alone & active, 2), steps)
        b = _accuracy(policy_rows, expert_rows, np.tile(~alone & active, 2), steps)
        print(f"{name:14s} {a:7.3f} {b:11.3f}")


def _all_frames(library) -> tuple[np.ndarray, np.ndarray]:
    """Every (clip, time) of the library with a step to play after it."""
    clips = np.concatenate([np.full(n - 1, c) for c, n in enumerate(library.num_frames)])
    times = np.concatenate([np.arange(n - 1) * library.dt for n in library.num_frames])
    return clips, times


def _accuracy(policy_rows: np.ndarray, expert_rows: np.ndarray, keep: np.ndarray, steps: int) -> float:
    """Held-out accuracy of a 2 x 128 ELU MLP trained with BCE on the kept columns (standardised on the training
    part); 0.5 when no column is kept."""
    if not keep.any():
        return 0.5
    x = np.concatenate([policy_rows, expert_rows])[:, keep].astype(np.float32)
    y = np.concatenate([np.zeros(len(policy_rows)), np.ones(len(expert_rows))]).astype(np.float32)
    order = np.random.default_rng(0).permutation(len(x))
    train, test = order[: 3 * len(x) // 4], order[3 * len(x) // 4 :]
    mean, std = x[train].mean(0), x[train].std(0) + 1e-6
    x = torch.as_tensor((x - mean) / std)
    y = torch.as_tensor(y)
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(x.shape[1], 128), torch.nn.ELU(), torch.nn.Linear(128, 128),
                              torch.nn.ELU(), torch.nn.Linear(128, 1))  # fmt: skip
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    gen = torch.Generator().manual_seed(1)
    for _ in range(steps):
        batch = torch.as_tensor(train)[torch.randint(len(train), (512,), generator=gen)]
        loss = torch.nn.functional.binary_cross_entropy_with_logits(net(x[batch]).squeeze(-1), y[batch])
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        return float(((net(x[test]).squeeze(-1) > 0).float() == y[test]).float().mean())


if __name__ == "__main__":
    main()
