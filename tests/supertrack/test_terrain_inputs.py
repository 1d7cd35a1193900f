"""SuperTrack's terrain inputs (supertrack/terrain.py): the keys, the networks' sizes, what a frame stores (its clip,
the simulated contacts, the reference's contact labels), windows of one clip, the heightmap sampled where W's
prediction puts the root, the policy reading in training what it read in the gym, W's contact loss by hand."""

from __future__ import annotations

import math
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

from common.character.humanoid import BodyGeometry, Humanoid
from common.config import ConfigError, load_config, to_dict
from common.motion.dataset import bundled_motion_dir, load_motions
from common.motion.library import MotionLibrary
from common.motion.terrain import write_sidecar
from common.motion.terrain_generator import slope, stairs
from common.sim.buffer import CyclicBuffer
from common.sim.terrain import contact_labels
from supertrack.config import SuperTrackConfig, TerrainConfig
from supertrack.learner import SuperTrackLearner
from supertrack.losses import contact_loss
from supertrack.rollout import make_steps, policy_rollout, world_model_prediction
from supertrack.state import BodyState, integrate, target_rotations
from supertrack.train import _check_init_fits

ROOT = Path(__file__).resolve().parents[2]
DEBUG = str(ROOT / "configs" / "supertrack" / "debug.yaml")
TERRAIN = ("terrain.heightmap_extent=0.5", "terrain.contact_weight=1.0", "terrain.contact_frames=[1, 4]")
N, J, P, K = 15, 12, 121, 2  # bodies, joints, heightmap points (11 x 11 at 0.1 m out to 0.5 m), contact offsets


@pytest.fixture(scope="module")
def humanoid() -> Humanoid:
    return Humanoid()


@pytest.fixture(scope="module")
def library(humanoid: Humanoid, tmp_path_factory: pytest.TempPathFactory) -> MotionLibrary:
    """walk on a 6 deg slope, walk on the floor, walk up 8 cm stairs."""
    root = tmp_path_factory.mktemp("clips")
    clips = []
    for name, terrain in (("walk_slope", slope(angle_deg=6.0, seed=0)), ("walk_stairs", stairs("up", 6, 0.08))):
        clip = root / f"{name}.txt"
        shutil.copy(bundled_motion_dir() / "humanoid3d_walk.txt", clip)
        write_sidecar(clip, terrain)
        clips.append(str(clip))
    return load_motions([clips[0], "walk", clips[1]], humanoid)


def _learner(humanoid: Humanoid, library: MotionLibrary, *overrides: str) -> SuperTrackLearner:
    # 12-frame episodes: characters restart, on any of the three clips, several times within the buffer.
    cfg = load_config(SuperTrackConfig, DEBUG, ["gym.termination.max_episode_frames=12", *overrides])
    torch.manual_seed(0)
    return SuperTrackLearner(cfg, humanoid, library, np.random.default_rng(0))


@pytest.fixture()
def learner(humanoid: Humanoid, library: MotionLibrary) -> Iterator[SuperTrackLearner]:
    built = _learner(humanoid, library, *TERRAIN)
    yield built
    built.close()


def test_the_keys_are_off_by_default_and_checked() -> None:
    for name in ("default", "paper", "debug"):
        cfg = load_config(SuperTrackConfig, ROOT / "configs" / "supertrack" / f"{name}.yaml")
        assert cfg.terrain == TerrainConfig() and not cfg.terrain.enabled
    for bad in ("terrain.contact_frames=[4, 1]", "terrain.heightmap_extent=0.05", "terrain.contact_weight=-1"):
        with pytest.raises(ConfigError, match="terrain"):
            load_config(SuperTrackConfig, DEBUG, [bad])


def test_network_sizes_with_the_terrain_keys_on(learner: SuperTrackLearner, humanoid: Humanoid,
                                                library: MotionLibrary) -> None:  # fmt: skip
    local = 16 * N + 3
    w_in, w_out = learner.world_model.net[0], learner.world_model.net[-1]
    assert (w_in.in_features, w_out.out_features) == (local + P + 6 * J, 6 * N + N)  # Local, heightmap, targets
    assert learner.policy_net.net[0].in_features == 2 * local + P + K * N  # Local(S), Local(K), heightmap, labels
    flat = _learner(humanoid, library)
    try:
        assert flat.terrain is None and flat.world_model.net[0].in_features == local + 6 * J
        assert flat.world_model.net[-1].out_features == 6 * N and flat.policy_net.net[0].in_features == 2 * local
    finally:
        flat.close()


def test_a_frame_holds_its_clip_the_simulated_contacts_and_the_reference_labels(learner: SuperTrackLearner) -> None:
    learner.collect()
    prev = learner.collector.source.res
    learner.collect()
    n, t = learner.cfg.train_envs, learner.terrain
    row = {k: v[-1] for k, v in learner.train_buffer.latest(1).items()}
    np.testing.assert_array_equal(row["clip"], prev.clip[:n])
    geometry = BodyGeometry(learner.humanoid)
    sim = contact_labels(t.terrains, prev.clip, geometry, prev.sim.body_pos, prev.sim.body_rot, 0.03)
    np.testing.assert_array_equal(row["sim_contacts"], sim[:n] > 0.5)
    for i, k in enumerate((1, 4)):
        ref = learner.library.query(prev.clip, prev.time + k * learner.library.dt)
        labels = contact_labels(t.terrains, prev.clip, geometry, ref.body_pos, ref.body_rot, 0.03)
        np.testing.assert_array_equal(row["kin_contacts"][:, i], labels[:n] > 0.5)
    assert row["sim_contacts"].any() and row["kin_contacts"].any()  # the characters stand: some feet touch


def test_windows_never_mix_clips_and_the_clips_survive_save_and_load(learner: SuperTrackLearner,
                                                                     tmp_path: Path) -> None:  # fmt: skip
    for _ in range(12):
        learner.collect()
    buffer = learner.train_buffer
    clip = buffer.latest(buffer.size)["clip"]  # (T, n)
    assert len(np.unique(clip)) == 3 and (clip[1:] != clip[:-1]).any()  # a character changed clip in the buffer
    windows = buffer.sample_windows(400, 8, np.random.default_rng(0))
    assert (windows["clip"] == windows["clip"][:, :1]).all()
    path = tmp_path / "buffer.h5"
    buffer.save(path)
    loaded = CyclicBuffer.load(path, buffer.user_fields)
    for name, value in buffer.latest(buffer.size).items():
        np.testing.assert_array_equal(loaded.latest(loaded.size)[name], value, err_msg=name)
    again = loaded.sample_windows(400, 8, np.random.default_rng(0))
    for name, value in windows.items():
        np.testing.assert_array_equal(again[name], value, err_msg=name)


def test_a_checkpoint_from_before_the_clip_field_still_loads(humanoid: Humanoid, library: MotionLibrary) -> None:
    flat = _learner(humanoid, library)
    try:
        flat.collect()
        state = flat.state_dict()
        for name in ("train_buffer", "val_buffer"):
            state[name] = {**state[name], "rows": {k: v for k, v in state[name]["rows"].items() if k != "clip"}}
        flat.load_state_dict(state)
        assert flat.train_buffer.size == 34 and not flat.train_buffer.latest(34)["clip"].any()
    finally:
        flat.close()


def _louder(module: torch.nn.Module) -> None:
    """The output layer x 100: an untrained network's outputs (init_scale 0.01) then depend on its inputs by more than
    float32 comparisons can miss."""
    with torch.no_grad():
        module.net[-1].weight.mul_(100.0)


def test_w_samples_the_heightmap_where_its_prediction_puts_the_root(learner: SuperTrackLearner) -> None:
    learner.collect()
    windows = learner.train_buffer.sample_windows(6, 8, np.random.default_rng(1))
    sim = BodyState.unpack(torch.as_tensor(windows["sim"]))
    targets, clip = torch.as_tensor(windows["target_rot"]), torch.as_tensor(windows["clip"][:, 0])
    w, t = learner.world_model, learner.terrain
    _louder(w)

    def by_hand(heightmap_at_start: bool) -> tuple[torch.Tensor, torch.Tensor]:
        """P_{i+1} = W(Local(P_i), heightmap(P_i), T_i) (or, wrongly, heightmap(S_0) throughout)."""
        state, positions, logits = sim.time(0), [], []
        for i in range(7):
            heightmap = t.heightmap(sim.time(0) if heightmap_at_start else state, clip)
            lin, ang, contact = w.predict(state, w.local_norm.normalize(state.local()), targets[:, i], heightmap)
            state = integrate(state, lin, ang, w.dt)
            positions.append(state.pos)
            logits.append(contact)
        return torch.stack(positions, dim=1), torch.stack(logits, dim=1)

    with torch.no_grad():
        rollout = world_model_prediction(w, sim, targets, None, t, clip)
        pos, logits = by_hand(False)
        torch.testing.assert_close(rollout.predicted.pos, pos)
        torch.testing.assert_close(rollout.contacts, logits)
        wrong_pos, wrong_logits = by_hand(True)
    assert not torch.allclose(wrong_logits, logits) and not torch.allclose(wrong_pos, pos)


def test_the_policy_reads_in_training_what_it_read_in_the_gym(learner: SuperTrackLearner) -> None:
    _louder(learner.policy_net)
    learner.collect()
    res, n = learner.collector.source.res, learner.cfg.train_envs
    action = learner.actor(res)  # deterministic, from the state the next frame will hold
    learner.collect()
    windows = {k: v[-1][:, None] for k, v in learner.train_buffer.latest(1).items()}  # (n, 1, ...) windows
    sim0 = BodyState.unpack(torch.as_tensor(windows["sim"][:, 0]))
    kin_next = BodyState.unpack(torch.as_tensor(windows["kin_next"]))
    kin_rot = torch.as_tensor(windows["kin_next_joint_rot"])
    alpha = learner.cfg.policy.alpha

    def trained(clip: np.ndarray, kin_contacts: np.ndarray) -> torch.Tensor:
        with torch.no_grad():
            rollout = policy_rollout(learner.policy_net, learner.world_model, sim0, kin_next, kin_rot,
                                     torch.zeros(n, 1, J, 3), alpha, None, learner.terrain, torch.as_tensor(clip),
                                     torch.as_tensor(kin_contacts))  # fmt: skip
        return target_rotations(rollout.offsets[:, 0], kin_rot[:, 0], alpha)

    torch.testing.assert_close(trained(windows["clip"][:, 0], windows["kin_contacts"]),
                               torch.as_tensor(action.target_rot[:n]), atol=1e-6, rtol=0)  # fmt: skip
    np.testing.assert_array_equal(action.kin_contacts[:n], windows["kin_contacts"][:, 0])
    # Both inputs count: another clip's ground (the flat floor, clip 1), or no contact labels, give other targets.
    for clip, labels in ((np.ones(n, dtype=np.int64), windows["kin_contacts"]),
                         (windows["clip"][:, 0], np.zeros_like(windows["kin_contacts"]))):  # fmt: skip
        assert (trained(clip, labels) - torch.as_tensor(action.target_rot[:n])).abs().max() > 1e-4


def test_traced_steps_with_terrain_give_the_plain_losses(learner: SuperTrackLearner) -> None:
    """torch.compile's graph capture (eager backend) of the rollout steps with the terrain inputs and W's contact
    output gives the plain steps' numbers."""
    learner.collect()
    windows = learner.train_buffer.sample_windows(8, 8, np.random.default_rng(2))
    noise = 0.1 * torch.randn(8, 8, J, 3, generator=torch.Generator().manual_seed(3))
    terms = {}
    for name, steps in (("plain", make_steps()), ("traced", make_steps(True, True, backend="eager"))):
        learner.steps = steps
        (_, w_terms), (_, p_terms) = learner.world_model_loss(windows), learner.policy_loss(windows, noise)
        terms[name] = {k: float(v) for k, v in {**w_terms, **p_terms}.items()}
    assert {"losses/world_model_contact", "losses/world_model_contact_error"} <= terms["plain"].keys()
    assert terms["traced"] == pytest.approx(terms["plain"], rel=1e-6)


def test_the_warm_up_compiles_the_terrain_graphs_training_uses(humanoid: Humanoid, library: MotionLibrary) -> None:
    """The stand-in windows carry the terrain fields in the training dtypes: training recompiles nothing."""
    learner = _learner(humanoid, library, *TERRAIN, "world_model.compile=true", "policy.compile=true",
                       "policy.start_iteration=0")  # fmt: skip
    try:
        learner.steps = make_steps(True, True, backend="eager")  # graph capture without code generation: fast
        torch._dynamo.reset()
        learner.warm_up()
        captured = torch._dynamo.utils.counters["frames"]["ok"]
        assert captured >= 2
        for _ in range(2):
            learner.collect()
            metrics = learner.update()
        assert "losses/policy" in metrics and "losses/world_model_contact" in metrics
        assert torch._dynamo.utils.counters["frames"]["ok"] == captured
    finally:
        learner.close()


def test_contact_loss_by_hand() -> None:
    """Cross-entropy log(1 + e^-z) for a contact, log(1 + e^z) for none: logits (-1, 2, 0.5, -3) against (0, 1, 0, 1)
    give 0.31326, 0.12693, 0.97408, 3.04859, mean 1.11572; the last two have the wrong sign."""
    logits = torch.tensor([[[-1.0, 2.0, 0.5, -3.0]]])
    loss, metrics = contact_loss(logits, torch.tensor([[[False, True, False, True]]]))
    expected = np.mean([math.log1p(math.exp(-1)), math.log1p(math.exp(-2)), math.log1p(math.exp(0.5)),
                        math.log1p(math.exp(3))])  # fmt: skip
    assert float(loss) == pytest.approx(expected, rel=1e-6) and expected == pytest.approx(1.11572, abs=1e-5)
    assert float(metrics["losses/world_model_contact_error"]) == 0.5


def test_init_from_refuses_networks_of_other_terrain_inputs(humanoid: Humanoid) -> None:
    flat = load_config(SuperTrackConfig, DEBUG)
    meta = {"bodies": list(humanoid.body_names), "config": to_dict(flat)}
    del meta["config"]["terrain"]  # a run from before the section: its defaults
    _check_init_fits(Path("old"), {"meta": meta}, flat, humanoid)
    _check_init_fits(Path("old"), {"meta": meta}, load_config(SuperTrackConfig, DEBUG, ["terrain.contact_height=0.05"]),
                     humanoid)  # fmt: skip
    for key in TERRAIN:
        with pytest.raises(ValueError, match=rf"{key.split('=')[0]} is .* there"):
            _check_init_fits(Path("old"), {"meta": meta}, load_config(SuperTrackConfig, DEBUG, [key]), humanoid)
