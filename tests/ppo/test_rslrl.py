"""rsl_rl's PPO on the shared gym (ppo/rslrl): the VecEnv adapter against the gym itself, a debug run that resumes
exactly and that compare-trackers, export-policy and watch-policy accept, and the command without rsl-rl-lib."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("rsl_rl")

from common.character.humanoid import Humanoid  # noqa: E402
from common.config import load_config  # noqa: E402
from common.evaluation.evaluate import evaluate  # noqa: E402
from common.motion.dataset import load_motions  # noqa: E402
from common.run.directory import read_checkpoint  # noqa: E402
from common.sim.gym import TrackingGym  # noqa: E402
from common.sim.motion_weights import MotionWeights  # noqa: E402
from common.sim.observation import Observer  # noqa: E402
from common.train.training import gym_config  # noqa: E402
from ppo.rslrl.config import RslRlConfig  # noqa: E402
from ppo.rslrl.env import GymVecEnv  # noqa: E402
from ppo.rslrl.train import main  # noqa: E402
from report.runs import export_module, load_run  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
DEBUG = str(ROOT / "configs" / "rsl_rl" / "debug.yaml")


def _run(out: Path, *extra: str) -> None:
    assert main(["--config", DEBUG, "--out", str(out), *extra]) == 0


def _records(out: Path) -> list[dict]:
    """The metrics log without its clock readings."""
    lines = (out / "metrics.jsonl").read_text().splitlines()
    return [{k: v for k, v in json.loads(line).items() if not k.startswith("perf/") and k != "wall_clock_s"}
            for line in lines]  # fmt: skip


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Two debug runs: 4 iterations straight, and 2 iterations resumed to 4."""
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("rsl_rl")
    out = {"straight": root / "straight", "resumed": root / "resumed"}
    _run(out["straight"], "--max-iterations", "4")
    _run(out["resumed"], "--max-iterations", "2")
    _run(out["resumed"], "--resume", "--max-iterations", "4")
    return out


def test_the_adapter_gives_the_gyms_observations_rewards_and_resets() -> None:
    """The VecEnv and a gym of the same seed, stepped with the same actions: the same numbers, the same resets, and
    the failure rates and RSI weights of the ended episodes (two clips, a fast failure-rate average)."""
    cfg = load_config(RslRlConfig, DEBUG, ["train.motions=[walk, run]", "motion_weights.ema_weight=0.5"])
    humanoid = Humanoid(cfg.gym.physics)
    library = load_motions(list(cfg.train.motions), humanoid)
    observe = Observer(cfg.observation, humanoid, library)
    weights, mine = (
        MotionWeights(library.num_clips, cfg.motion_weights),
        MotionWeights(library.num_clips, cfg.motion_weights),
    )
    env = GymVecEnv(TrackingGym(gym_config(cfg), library, humanoid, weights.gym_weights()), observe, cfg.actions,
                    weights)  # fmt: skip
    gym = TrackingGym(gym_config(cfg), library, humanoid, mine.gym_weights())
    res = gym.reset()
    rng = np.random.default_rng(0)
    n, steps = cfg.gym.num_envs, 40
    ended = {"terminated": 0, "truncated": 0}
    assert env.get_observations()["policy"].dtype == torch.float32
    for t in range(steps):
        if t % cfg.runner.num_steps_per_env == 0:  # a rollout starts: the RSI weights of the rates so far
            env.refresh_clip_weights()
            gym.set_clip_weights(mine.gym_weights())
        obs = env.get_observations()
        np.testing.assert_array_equal(obs["policy"].numpy(), observe(res).astype(np.float32))
        # Half the characters near the reference (time-outs), half far off it (falls; some actions beyond the clip)
        action = np.where(np.arange(n)[:, None] < n // 2, 0.1, 3.0) * rng.standard_normal((n, humanoid.nu))
        action = action.astype(np.float32).astype(np.float64)
        obs, rewards, dones, extras = env.step(torch.as_tensor(action, dtype=torch.float32))
        targets = res.ref_next.qpos[:, humanoid.hinge_qpos] + 0.5 * np.clip(action, -4.0, 4.0)
        prev, res = res, gym.step(targets)
        mine.record(prev.clip, res.terminated, res.truncated)
        np.testing.assert_array_equal(obs["policy"].numpy(), observe(res).astype(np.float32))
        np.testing.assert_array_equal(rewards.numpy(), res.reward.astype(np.float32))
        np.testing.assert_array_equal(dones.numpy(), (res.terminated | res.truncated).astype(np.int64))
        np.testing.assert_array_equal(extras["time_outs"].numpy(), res.truncated)
        np.testing.assert_array_equal(env.episode_length_buf.numpy(), res.episode_frame)
        np.testing.assert_array_equal(env.result.clip, res.clip)
        np.testing.assert_array_equal(env.result.episode_id, res.episode_id)
        ended["terminated"] += int(res.terminated.sum())
        ended["truncated"] += int(res.truncated.sum())
    assert ended["terminated"] > 0 and ended["truncated"] > 0
    np.testing.assert_array_equal(weights.failure_rate, mine.failure_rate)
    assert len(set(mine.gym_weights().tolist())) > 1  # the two clips' RSI weights came apart
    np.testing.assert_array_equal(env.gym.clip_weights, gym.clip_weights)
    env.close()
    gym.close()


def test_debug_run_writes_a_run_directory_with_rsl_rls_update_statistics(runs: dict[str, Path]) -> None:
    run = runs["straight"]
    info = json.loads((run / "run_info.json").read_text())
    assert info["learner"] == "rsl_rl" and (run / "config.yaml").is_file()
    assert (run / "checkpoints" / "ckpt_00000004.pt").is_file()
    records = _records(run)
    assert records[-1]["iteration"] == 4 and records[-1]["samples"] == 4 * 64
    logged = {k for r in records for k in r}
    for key in ("losses/value", "losses/surrogate", "losses/entropy", "losses/kl", "losses/approx_kl",
                "losses/clip_frac", "charts/learning_rate", "charts/explained_variance", "charts/action_std",
                "reward/root_pos", "charts/episode_length", "charts/clip_weight_max", "eval/mpjpe_g"):  # fmt: skip
        assert key in logged, key
    # The adaptive schedule moved the rate from rsl_rl's 1e-3.
    assert records[-1]["charts/learning_rate"] != pytest.approx(1e-3)
    state = read_checkpoint(run)[1]["learner"]
    assert state["alg"]["actor_state_dict"]["obs_normalizer.count"] == 4 * 64  # rsl_rl's normaliser is saved


def test_resume_continues_exactly(runs: dict[str, Path]) -> None:
    straight, resumed = (read_checkpoint(runs[k])[1]["learner"] for k in ("straight", "resumed"))
    for part in ("actor_state_dict", "critic_state_dict"):
        for name, value in straight["alg"][part].items():
            torch.testing.assert_close(resumed["alg"][part][name], value, rtol=0, atol=0, msg=f"{part}.{name}")
    adam_a, adam_b = straight["alg"]["optimizer_state_dict"], resumed["alg"]["optimizer_state_dict"]
    assert adam_a["param_groups"] == adam_b["param_groups"]  # the adapted learning rate too
    for i, moments in adam_a["state"].items():
        for name, value in moments.items():
            torch.testing.assert_close(adam_b["state"][i][name], value, rtol=0, atol=0)
    assert straight["learning_rate"] == resumed["learning_rate"]
    np.testing.assert_array_equal(straight["env"]["gym"]["sim_state"], resumed["env"]["gym"]["sim_state"])
    # The resumed run's log: the first run's lines up to its checkpoint, then the same continuation.
    assert _records(runs["resumed"]) == _records(runs["straight"])


def test_compare_trackers_judges_the_run_with_the_trainers_numbers(runs: dict[str, Path], tmp_path: Path) -> None:
    from report.compare import build_report

    run = load_run(runs["straight"])
    assert run.learner == "rsl_rl" and run.iteration == 4
    humanoid = Humanoid(run.physics())
    library = load_motions(["walk"], humanoid)
    policy = export_module("rsl_rl").load_eval_policy(run.path, run.checkpoint, humanoid, library)
    fresh = evaluate(policy, library, humanoid, run.eval_config())
    # The trainer evaluated the live learner at the end: the policy rebuilt from the checkpoint acts identically.
    assert fresh.overall["mpjpe_g"] == pytest.approx(_records(run.path)[-1]["eval/mpjpe_g"], rel=1e-9)
    report = build_report([run.path], tmp_path / "report", do_render=False, pushes=False)
    assert "rsl_rl:straight" in report.files["markdown"].read_text()
    assert report.results[0].overall["mpjpe_g"] == pytest.approx(fresh.overall["mpjpe_g"], rel=1e-9)


def test_export_policy_writes_the_eval_policy_as_onnx(runs: dict[str, Path], tmp_path: Path) -> None:
    onnxruntime = pytest.importorskip("onnxruntime")
    from report.export_policy import main as export_main

    out = tmp_path / "rsl.onnx"
    assert export_main([str(runs["straight"]), "--onnx", str(out)]) == 0
    sidecar = json.loads(out.with_suffix(".onnx.json").read_text())
    assert sidecar["learner"] == "rsl_rl" and sidecar["policy"]["action_scale_rad"] == 0.5
    run = load_run(runs["straight"])
    humanoid = Humanoid(run.physics())
    library = load_motions(["walk"], humanoid)
    cfg = load_config(RslRlConfig, run.path / "config.yaml")
    policy = export_module("rsl_rl").load_eval_policy(run.path, run.checkpoint, humanoid, library)
    gym = TrackingGym(replace(cfg.gym, num_envs=4, threads=1), library, humanoid)
    res = gym.reset()
    for _ in range(3):
        res = gym.step(policy(res))
    gym.close()
    session = onnxruntime.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    obs = Observer(cfg.observation, humanoid, library)(res).astype(np.float32)
    hinges = res.ref_next.qpos[:, humanoid.hinge_qpos].astype(np.float32)
    _, targets = session.run(None, {"observation": obs, "ref_next_hinges": hinges})
    np.testing.assert_allclose(targets, policy(res), atol=1e-5)


def test_watch_policy_plays_the_run(runs: dict[str, Path], tmp_path: Path) -> None:
    from common.tools import render
    from report import watch

    if render.find_backend()[0] is None:
        pytest.skip(render.find_backend()[1])
    video = tmp_path / "watch.mp4"
    assert watch.main([str(runs["straight"]), "--frames", "6", "--size", "64", "48", "--out", str(video)]) == 0
    assert video.read_bytes()[4:8] == b"ftyp"  # an MP4 container


def test_without_rsl_rl_the_project_imports_and_the_command_says_how_to_install_it(tmp_path: Path) -> None:
    out = str(tmp_path / "run")
    code = f"""
import sys
sys.modules["rsl_rl"] = sys.modules["tensordict"] = None  # as if rsl-rl-lib were not installed
import report.compare, report.export_policy, report.watch, ppo.rslrl.export, ppo.rslrl.train
from report.runs import ReportError, export_module
try:
    export_module("rsl_rl")
except ReportError as e:
    print(e)
from ppo.rslrl.train import main
main(["--config", {DEBUG!r}, "--out", {out!r}])
"""
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip() == 'error: rsl_rl\'s PPO needs rsl-rl-lib: pip install -e ".[rsl_rl]"'
    assert done.stdout.strip() == 'rsl_rl PPO runs need rsl_rl, tensordict: pip install -e ".[rsl_rl]"'
    assert not (tmp_path / "run").exists()


def test_a_bundled_policy_acts_as_the_run(runs: dict[str, Path], tmp_path: Path) -> None:
    from common.run.checkpoint import load_checkpoint_file
    from report.bundle_policy import bundle

    out = bundle(runs["straight"], tmp_path / "bundle")
    assert set(load_checkpoint_file(out / "policy.pt")["learner"]) == {"sizes", "actor"}  # no critic, no Adam
    run, packed = load_run(runs["straight"]), load_run(out)
    humanoid = Humanoid(run.physics())
    library = load_motions(["walk"], humanoid)
    gym = TrackingGym(replace(load_config(RslRlConfig, run.path / "config.yaml").gym, num_envs=4, threads=1),
                      library, humanoid)  # fmt: skip
    res = gym.reset()
    gym.close()
    a, b = (export_module("rsl_rl").load_eval_policy(r.path, r.checkpoint, humanoid, library) for r in (run, packed))
    np.testing.assert_array_equal(a(res), b(res))


@pytest.mark.parametrize(("setting", "message"), [
    ("algorithm.num_mini_batches=3", r"num_mini_batches \(3\) must divide .* = 64 samples"),
    ("algorithm.schedule=cosine", r"algorithm\.schedule"),
    ("actions.scale=0", r"actions\.scale must be positive"),
])  # fmt: skip
def test_a_bad_setting_is_refused_in_one_line_before_anything_is_written(tmp_path: Path, setting: str,
                                                                        message: str) -> None:  # fmt: skip
    with pytest.raises(SystemExit, match=message):
        _run(tmp_path / "x", "--set", setting)
    assert not (tmp_path / "x").exists()


def test_more_than_one_rank_is_refused() -> None:
    from types import SimpleNamespace

    from ppo.rslrl.learner import RslRlLearner

    cfg = load_config(RslRlConfig, DEBUG)
    with pytest.raises(ValueError, match="runs in one process"):
        RslRlLearner(cfg, None, None, np.random.default_rng(0), SimpleNamespace(distributed=True))  # type: ignore[arg-type]


def test_the_default_config_is_rsl_rls_defaults_but_the_listed_differences() -> None:
    """Every rsl_rl setting of configs/rsl_rl/default.yaml against rsl_rl's own signatures: only those marked
    "differs" (docs/rsl-rl.md) differ."""
    import inspect

    from rsl_rl.algorithms import PPO
    from rsl_rl.models import MLPModel
    from rsl_rl.modules import GaussianDistribution

    from common.config import to_dict

    def defaults(f: object) -> dict:
        return {k: p.default for k, p in inspect.signature(f).parameters.items() if p.default is not p.empty}

    cfg = load_config(RslRlConfig, ROOT / "configs" / "rsl_rl" / "default.yaml")
    ppo, mlp, gauss = defaults(PPO.__init__), defaults(MLPModel.__init__), defaults(GaussianDistribution.__init__)
    assert {k: v for k, v in to_dict(cfg.algorithm).items() if ppo[k] != v} == {}
    differs = {"hidden_dims": [256, 256], "obs_normalization": True}
    for section in (cfg.actor, cfg.critic):
        plain = {k: v for k, v in to_dict(section).items() if k != "distribution"}
        assert {k: v for k, v in plain.items() if list(np.atleast_1d(mlp[k])) != list(np.atleast_1d(v))} == differs
    assert {k: v for k, v in to_dict(cfg.actor.distribution).items() if gauss[k] != v} == {}
    assert cfg.batch_size // cfg.algorithm.num_mini_batches == 2048  # our PPO's minibatch, by rsl_rl's 4 minibatches


def test_the_default_trains_on_our_ppos_task_with_its_samples_per_update() -> None:
    """configs/rsl_rl/default.yaml against configs/ppo/default.yaml: one gym, observation, PD targets, adaptive clip
    weights and rollout; if our PPO's default moves, this arm's must follow (docs/rsl-rl.md)."""
    from ppo.config import PPOTrackerConfig

    ours = load_config(PPOTrackerConfig, ROOT / "configs" / "ppo" / "default.yaml")
    cfg = load_config(RslRlConfig, ROOT / "configs" / "rsl_rl" / "default.yaml")
    assert (cfg.gym, cfg.observation, cfg.motion_weights) == (ours.gym, ours.observation, ours.motion_weights)
    assert (cfg.actions.scale, cfg.actions.clip) == (ours.network.action_scale, ours.network.action_clip)
    assert cfg.runner.num_steps_per_env == ours.ppo.rollout_length and cfg.batch_size == ours.batch_size
    assert cfg.actor.hidden_dims == ours.network.actor_hidden and cfg.critic.hidden_dims == ours.network.critic_hidden


def test_the_update_statistics_watch_rsl_rl_without_changing_it() -> None:
    """A learner with the statistics' taps and rsl_rl untouched, from one seed: the same weights; and the recorded KL
    of every minibatch, put through rsl_rl's adaptive rule, gives the learning rate rsl_rl ended with."""
    from ppo.rslrl.learner import RslRlLearner

    torch.set_num_threads(1)
    cfg = load_config(RslRlConfig, DEBUG)
    humanoid = Humanoid(cfg.gym.physics)
    library = load_motions(list(cfg.train.motions), humanoid)
    a, lr = cfg.algorithm, cfg.algorithm.learning_rate
    learners = []
    for tapped in (True, False):
        torch.manual_seed(0)
        learner = RslRlLearner(cfg, library, humanoid, np.random.default_rng(0))
        if not tapped:  # the instance attributes gone, rsl_rl's own methods answer
            del learner.alg.storage.mini_batch_generator, learner.alg.actor.get_output_log_prob
        for _ in range(3):
            learner.collect()
            if tapped:
                learner.update()
                assert len(learner.stats.rows) == a.num_learning_epochs * a.num_mini_batches
                for kl, _, _ in learner.stats.rows:
                    if kl > 2 * a.desired_kl:
                        lr = max(1e-5, lr / 1.5)
                    elif 0 < kl < a.desired_kl / 2:
                        lr = min(1e-2, lr * 1.5)
                assert learner.alg.learning_rate == lr
            else:
                learner.alg.update()
        learners.append(learner)
    saved = [learner.alg.save() for learner in learners]
    for part in ("actor_state_dict", "critic_state_dict"):
        for name, value in saved[0][part].items():
            torch.testing.assert_close(saved[1][part][name], value, rtol=0, atol=0, msg=f"{part}.{name}")
    assert learners[0].alg.learning_rate == learners[1].alg.learning_rate != cfg.algorithm.learning_rate
    for learner in learners:
        learner.close()
