"""Per-body diagnosis of a SuperTrack run: where the world model is wrong, and whether the policy exploits it.

For a run directory's latest (or chosen) checkpoint:
1. W's one-frame prediction error per body on held-back buffer windows, next to the error of predicting zero
   acceleration (v' = v). A body where W is no better than that baseline is one W has not learnt.
2. The trained policy (deterministic) driving the real simulator from reference state initialisation: mean angular
   speed per body against the reference's and against open-loop playback of the reference (PD targets = the
   reference), which separates what the policy does from what the PD controller and contacts do on their own. A
   policy that exploits W's blind spots shows bodies spinning or shaking far faster than both (often the feet).

    .venv/bin/python benchmarks/world_model_bodies.py runs/st-walk-60

With ``--motions``, (1) is measured per clip instead, on fresh frames: the policy with its training noise
(``policy.sigma``) plays each named clip in the simulator (reference state initialisation, the gym's rules), and W
predicts each frame's successor from the frame and the applied targets. That is W's error on the distribution the
policy makes on that clip, which the held-back buffer (all clips mixed, no clip stored) cannot separate. A clip
outside the run's library (a held-out clip of the generalisation split, an imported take) is loaded by name and
marked ``*`` in the table: W's error there says whether the world model generalises where the policy must:

    .venv/bin/python benchmarks/world_model_bodies.py runs/st-all20 --motions walk backflip sideflip
"""

from __future__ import annotations

import argparse
import copy
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common.character.humanoid import Humanoid  # noqa: E402
from common.config import load_config  # noqa: E402
from common.evaluation.evaluate import reference_policy  # noqa: E402
from common.motion.dataset import load_motions  # noqa: E402
from common.motion.errors import MotionFormatError  # noqa: E402
from common.motion.library import MotionLibrary  # noqa: E402
from common.run.checkpoint import CheckpointError  # noqa: E402
from common.run.directory import read_checkpoint  # noqa: E402
from common.sim.gym import TrackingGym  # noqa: E402
from common.train.training import gym_config  # noqa: E402
from supertrack.actor import GymActor  # noqa: E402
from supertrack.config import SuperTrackConfig  # noqa: E402
from supertrack.learner import SuperTrackLearner  # noqa: E402
from supertrack.rollout import world_model_rollout  # noqa: E402
from supertrack.state import BodyState, pack_character_state  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", help="a train-supertrack run directory")
    parser.add_argument("--checkpoint", default=None, help="checkpoint file (default: the run's latest)")
    parser.add_argument("--windows", type=int, default=512, help="held-back windows for W's error")
    parser.add_argument("--frames", type=int, default=120, help="control steps of the policy in the simulator")
    parser.add_argument("--motions", nargs="+", default=None,
                        help="clips to measure W on one by one (the run's or any other bundled clip or file), on "
                             "frames of the noisy policy (prints a body x clip table of W's angular-velocity error "
                             "over the w=const guess's)")  # fmt: skip
    args = parser.parse_args()
    run = Path(args.run_dir)
    if not (run / "config.yaml").is_file():
        raise SystemExit(f"{run}: not a run directory (no config.yaml)")
    overrides = ["world_model.compile=false", "policy.compile=false"]
    cfg = load_config(SuperTrackConfig, run / "config.yaml", overrides)
    try:
        checkpoint, state = read_checkpoint(args.checkpoint or run)
    except CheckpointError as e:
        raise SystemExit(str(e)) from e
    humanoid = Humanoid(cfg.gym.physics)
    library = load_motions(list(cfg.train.motions), humanoid)
    learner = SuperTrackLearner(cfg, humanoid, library, np.random.default_rng(0))
    if args.motions:
        try:
            learner.load_state_dict(state["learner"])
            per_clip(cfg, learner, humanoid, library, args.motions, args.frames)
        finally:
            learner.close()
        return
    # A gym of the run's settings plays the policy (the learner's own may live in a collector process).
    gym = TrackingGym(gym_config(cfg), library, humanoid)
    try:
        learner.load_state_dict(state["learner"])
        windows = learner.val_buffer.sample_windows(args.windows, 2, np.random.default_rng(1))
        sim = BodyState.unpack(torch.as_tensor(windows["sim"]))
        with torch.no_grad():
            pred = world_model_rollout(learner.world_model, sim, torch.as_tensor(windows["target_rot"])).time(0)
        now, nxt = sim.time(0), sim.time(1)

        def err(a: torch.Tensor, b: torch.Tensor) -> np.ndarray:
            return (a - b).norm(dim=-1).mean(0).numpy()

        w_vel, base_vel = err(pred.vel, nxt.vel), err(now.vel, nxt.vel)
        w_ang, base_ang = err(pred.angvel, nxt.angvel), err(now.angvel, nxt.angvel)

        policy = learner.policy()

        def speeds(act) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
            """Mean body angular speeds (sim, ref) and mean |PD target change| per frame per hinge (act, ref)."""
            res = gym.reset()
            sim_speed, ref_speed, targets, ref_targets = [], [], [], []
            for _ in range(args.frames):
                targets.append(act(res))
                ref_targets.append(reference_policy(res, humanoid))
                res = gym.step(targets[-1])
                sim_speed.append(np.linalg.norm(res.sim.body_angvel, axis=-1).mean(0))
                ref_speed.append(np.linalg.norm(res.ref_next.body_angvel, axis=-1).mean(0))
            # Episode resets inside the window make a few large jumps; they count the same for both columns.
            rate = np.abs(np.diff(targets, axis=0)).mean((0, 1))
            ref_rate = np.abs(np.diff(ref_targets, axis=0)).mean((0, 1))
            return np.mean(sim_speed, axis=0), np.mean(ref_speed, axis=0), rate, ref_rate

        s, r, rate, ref_rate = speeds(policy)
        s_open = speeds(lambda res: reference_policy(res, humanoid))[0]
    finally:
        gym.close()
        learner.close()
    print(f"{checkpoint}: W one-frame error on {args.windows} held-back windows; policy over {args.frames} frames")
    header = f"{'body':<18}{'W vel':>8}{'v=const':>9}{'W angvel':>10}{'w=const':>9}"
    print(header + f"{'|w| sim':>9}{'|w| open':>10}{'|w| ref':>9}")
    for i, name in enumerate(humanoid.body_names):
        flag = "  <- W no better than w=const" if w_ang[i] >= base_ang[i] else ""
        row = f"{name:<18}{w_vel[i]:>8.3f}{base_vel[i]:>9.3f}{w_ang[i]:>10.3f}{base_ang[i]:>9.3f}"
        print(row + f"{s[i]:>9.2f}{s_open[i]:>10.2f}{r[i]:>9.2f}" + flag)
    print("units: m/s and rad/s; |w|: mean angular speed of the body in the simulator under the policy (sim) and under")
    print("open-loop playback of the reference (open), and in the reference (ref)")
    names = [humanoid.model.joint(j).name for j in range(humanoid.model.njnt)]
    by_qpos = dict(zip(humanoid.model.jnt_qposadr.tolist(), names, strict=True))
    print(f"\n{'hinge':<18}{'policy':>8}{'ref':>8}   mean |PD target change| per frame (deg)")
    for k, q in enumerate(humanoid.hinge_qpos):
        flag = "  <- chatter (> 3x the reference + 0.5 deg)" if rate[k] > 3 * ref_rate[k] + np.radians(0.5) else ""
        print(f"{by_qpos[int(q)]:<18}{np.degrees(rate[k]):>8.2f}{np.degrees(ref_rate[k]):>8.2f}" + flag)


def one_frame_errors(learner: SuperTrackLearner, sim: np.ndarray, target_rot: np.ndarray,
                     sim_next: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """W's and the constant-velocity guess's mean one-frame errors per body: (W vel, v=const, W angvel, w=const).

    Args:
        learner: The run's learner (its W).
        sim: Packed states S_t. Shape: (B, N, 13).
        target_rot: The targets T_t applied at S_t. Shape: (B, J, 4).
        sim_next: Packed states S_{t+1} the simulator reached. Shape: (B, N, 13).
    """
    states = BodyState.unpack(torch.as_tensor(np.stack([sim, sim_next], axis=1)))
    targets = torch.as_tensor(np.stack([target_rot, target_rot], axis=1))
    with torch.no_grad():
        pred = world_model_rollout(learner.world_model, states, targets).time(0)
    now, nxt = states.time(0), states.time(1)

    def err(a: torch.Tensor, b: torch.Tensor) -> np.ndarray:
        return (a - b).norm(dim=-1).mean(0).numpy()

    return err(pred.vel, nxt.vel), err(now.vel, nxt.vel), err(pred.angvel, nxt.angvel), err(now.angvel, nxt.angvel)


def per_clip(cfg: SuperTrackConfig, learner: SuperTrackLearner, humanoid: Humanoid, library: MotionLibrary,
             clips: list[str], frames: int) -> None:  # fmt: skip
    """Prints W's one-frame angular-velocity error over the w=const guess's, per body and clip, on frames of the
    noisy policy playing each clip (a frame whose step ended the episode has no successor and is left out)."""
    held_out = [c for c in clips if c not in library.names]
    try:  # before any work, so that a wrong name fails at once with the loader's message
        other = {c: load_motions([c], humanoid) for c in held_out}
    except MotionFormatError as e:
        raise SystemExit(f"--motions: {e}") from e
    actor = GymActor(humanoid, copy.deepcopy(learner.eval_actor.policy), cfg.policy.alpha, cfg.policy.sigma)
    rng = np.random.default_rng(2)
    table, summary = {}, []
    for clip in clips:
        one = other[clip] if clip in other else MotionLibrary([library.clips[library.clip_index(clip)]], library.dt)
        gym = TrackingGym(gym_config(cfg), one, humanoid)
        try:
            res = gym.reset()
            sims, targets, nexts = [], [], []
            for _ in range(frames):
                hinges, fields = actor(res, rng)
                step = gym.step(hinges)
                kept = ~(step.terminated | step.truncated)
                sims.append(fields["sim"][kept])
                targets.append(fields["target_rot"][kept])
                nexts.append(pack_character_state(step.final_sim)[kept])
                res = step
        finally:
            gym.close()
        sims = np.concatenate(sims)
        w_vel, base_vel, w_ang, base_ang = one_frame_errors(learner, sims, np.concatenate(targets),
                                                            np.concatenate(nexts))  # fmt: skip
        table[clip] = w_ang / base_ang
        summary.append((clip, len(sims), w_ang.mean(), base_ang.mean(), w_vel.mean(), base_vel.mean()))
    print(f"W's one-frame angular-velocity error / the w=const guess's, per body, on {frames} frames x "
          f"{cfg.gym.num_envs} characters of the noisy policy (sigma {cfg.policy.sigma}) per clip; > 1: W is worse")
    labels = {c: c + "*" if c in held_out else c for c in clips}
    width = max(9, *(len(c) + 2 for c in clips))
    print(f"{'body':<18}" + "".join(f"{labels[c]:>{width}}" for c in clips))
    for i, name in enumerate(humanoid.body_names):
        print(f"{name:<18}" + "".join(f"{table[c][i]:>{width}.2f}" for c in clips))
    print(f"\n{'clip':<16}{'frames':>8}{'W angvel':>10}{'w=const':>9}{'W vel':>8}{'v=const':>9}   (means over bodies)")
    for clip, n, wa, ba, wv, bv in summary:
        print(f"{labels[clip]:<16}{n:>8}{wa:>10.3f}{ba:>9.3f}{wv:>8.3f}{bv:>9.3f}")
    if held_out:
        print("* not among the run's training clips")


if __name__ == "__main__":
    main()
