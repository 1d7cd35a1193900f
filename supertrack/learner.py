"""The SuperTrack learner (Fussell et al. 2021): gym -> cyclic buffer -> one W step and one policy step.

Implements :class:`common.train.training.Learner`; :class:`common.train.training.Trainer` drives it. Each iteration the
gym's characters act with the policy plus noise in the real simulator and a block of their frames goes into the buffer
(:mod:`common.sim.collect`: in this process with the newest weights, or with ``collect.processes >= 1`` by worker
processes that collect the next block with the weights of the running update's start); then W takes one step on
8-frame windows (Algorithm 1) and the policy one step on 32-frame windows rolled out through W (Algorithm 2).

What a buffer frame holds: :mod:`supertrack.frames`. On terrain (the ``terrain`` config, :mod:`supertrack.terrain`)
both rollouts sample the heightmap on each window's clip's terrain and W's contact logits join its loss.
"""

from __future__ import annotations

import copy
import functools
import math
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import torch

from common.character.humanoid import Humanoid
from common.evaluation.evaluate import Policy as EvalPolicy
from common.motion.library import MotionLibrary
from common.sim.buffer import CyclicBuffer
from common.sim.collect import Block, CollectorSpec, chart_metrics, make_collector
from common.sim.motion_weights import MotionWeights
from common.train.averaging import WeightAverage
from common.train.distributed import World
from common.train.training import NanGuard, gym_config
from supertrack.actor import Actor, GymActor
from supertrack.config import SuperTrackConfig
from supertrack.diagnostics import open_loop_errors
from supertrack.frames import buffer_fields, gym_fields, upgrade_rows
from supertrack.losses import contact_loss, policy_loss, world_model_loss
from supertrack.models import Policy, WorldModel
from supertrack.normalizer import (
    acceleration_normalizer,
    local_normalizer,
    target_normalizer,
)
from supertrack.rollout import configured_steps, native_bf16, policy_rollout, world_model_prediction
from supertrack.state import BodyState
from supertrack.terrain import TerrainInputs

# Floor of the acceleration normaliser's std (m/s^2, rad/s^2): reference clips hold some bodies nearly still.
ACCEL_MIN_STD = 1.0


def clip_weights(cfg: SuperTrackConfig, library: MotionLibrary) -> np.ndarray | None:
    """The gym's RSI weight per clip from ``collect.clip_weights`` (None: uniform); ValueError names the key."""
    try:
        return library.clip_weights(cfg.collect.clip_weights)
    except ValueError as e:
        raise ValueError(f"collect.clip_weights: {e}") from e


class SuperTrackLearner:
    """World model, policy, their optimisers, the gym and the buffers.

    Args:
        cfg: The config.
        humanoid: The model.
        library: The motions to track (normaliser statistics and the gym's references).
        rng: The learner's generator (exploration noise in the gym, window draws); the Trainer saves it.
        world: This process's rank in a data-parallel run (:mod:`common.train.distributed`); default: a single
            process. Each rank has its own gym, collector and buffers; the gradients of both networks are averaged
            over the ranks and the finished episodes of all ranks update the adaptive clip weights.
    """

    def __init__(self, cfg: SuperTrackConfig, humanoid: Humanoid, library: MotionLibrary,
                 rng: np.random.Generator, world: World | None = None) -> None:  # fmt: skip
        self.cfg, self.humanoid, self.library, self.rng = cfg, humanoid, library, rng
        self.world = World() if world is None else world
        self.device = torch.device(cfg.train.device)
        n_bodies, n_joints = humanoid.num_bodies, len(humanoid.joint_groups)
        min_std = cfg.buffer.normalizer_min_std
        local_norm = local_normalizer(library, min_std)
        revolute = torch.tensor([g.kind == "revolute" for g in humanoid.joint_groups])
        t = cfg.terrain
        self.terrain = TerrainInputs(t, humanoid, library).to(self.device) if t.enabled else None
        heightmap_size, terrain_size = (0, 0) if self.terrain is None else \
            (self.terrain.heightmap_size, self.terrain.policy_size)  # fmt: skip
        self.world_model = WorldModel(
            n_bodies, revolute, cfg.world_model.hidden, local_norm, target_normalizer(library, humanoid, min_std),
            acceleration_normalizer(library, ACCEL_MIN_STD), humanoid.physics.control_dt, cfg.world_model.init_scale,
            heightmap_size, t.contact_weight > 0,
        ).to(self.device)  # fmt: skip
        self.policy_net = Policy(n_joints, cfg.policy.hidden, local_norm, cfg.policy.init_scale,
                                 root_offset=cfg.policy.root_offset, revolute=revolute,
                                 terrain_size=terrain_size).to(self.device)  # fmt: skip
        self.world.broadcast_modules(self.world_model, self.policy_net)
        self.steps = configured_steps(cfg)
        # The W the policy learns through. With policy.concurrent it is a copy of W taken at the start of every
        # update (sharing the Local() normaliser, which never changes), so that the policy step can run in a second
        # thread while W's steps change W itself; otherwise W itself.
        self.policy_world = self.world_model
        self._world_thread: ThreadPoolExecutor | None = None
        if cfg.policy.concurrent:
            self.policy_world = copy.deepcopy(self.world_model, memo={id(local_norm): local_norm})
            self.policy_world.requires_grad_(False)
            self._world_thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="world-model-steps")
        self.world_optimizer = torch.optim.RAdam(self.world_model.parameters(), lr=cfg.world_model.lr)
        self.policy_optimizer = torch.optim.RAdam(self.policy_net.parameters(), lr=cfg.policy.lr)
        self._new_guards()
        fields = buffer_fields(n_bodies, n_joints, t)
        self.train_buffer = CyclicBuffer(cfg.buffer.capacity, cfg.train_envs, fields)
        self.val_buffer = CyclicBuffer(cfg.buffer.val_capacity, cfg.buffer.val_envs, fields)
        self.actor = Actor(humanoid, self.policy_net, cfg.policy.alpha, terrain=self.terrain)
        # The evaluated policy: the live network, or its weight average when policy.average_decay > 0.
        self.policy_average = (
            WeightAverage(self.policy_net, cfg.policy.average_decay) if cfg.policy.average_decay else None
        )
        self.eval_actor = (
            self.actor
            if self.policy_average is None
            else Actor(humanoid, self.policy_average.module, cfg.policy.alpha, terrain=self.terrain)
        )
        self._charts: dict[str, float] = {}
        self._rates: dict[str, float] = {}
        self.fixed_clip_weights = clip_weights(cfg, library)
        self.motion_weights = MotionWeights(library.num_clips, cfg.motion_weights)
        self.updates = 0
        c = cfg.collect
        # The gym's own actor: a CPU copy of the policy (in a worker process when collect.processes >= 1), in bf16
        # only where the CPU has it natively (a GPU run's CPU may emulate it, far slower than float32).
        factory = functools.partial(GymActor, policy=copy.deepcopy(self.policy_net).cpu(), alpha=cfg.policy.alpha,
                                    sigma=cfg.policy.sigma, bf16=cfg.policy.bf16 and native_bf16(),
                                    terrain=TerrainInputs(t, humanoid, library) if t.enabled else None)  # fmt: skip
        spec = CollectorSpec(gym=gym_config(cfg), library=library, humanoid=humanoid, actor_factory=factory,
                             fields=gym_fields(n_bodies, n_joints, t), noise_seed=cfg.train.seed,
                             max_steps=max(c.steps_per_iteration, c.warmup_steps),
                             clip_weights=self._clip_weights(), torch_threads=cfg.train.torch_threads,
                             first_source=self.world.first_source(c.processes))  # fmt: skip
        self.collector = make_collector(spec, c.processes, self.policy_net.state_dict())

    def _new_guards(self) -> None:
        # Rebuilt after loading a checkpoint so that a restore never goes back to the freshly initialised weights.
        self.world_guard = NanGuard({"world_model": self.world_model, "optimizer": self.world_optimizer})
        self.policy_guard = NanGuard({"policy": self.policy_net, "optimizer": self.policy_optimizer})

    # Learner protocol ------------------------------------------------------------------------------------------

    def collect(self) -> int:
        """Puts the collector's next block of frames into the buffers. Returns the samples added."""
        c = self.cfg.collect
        steps = max(c.steps_per_iteration, c.warmup_steps - self.train_buffer.total_pushed)
        next_steps = max(c.steps_per_iteration, c.warmup_steps - self.train_buffer.total_pushed - steps)
        block = self.collector.next_block(self.policy_net.state_dict(), self.updates, steps, next_steps,
                                          clip_weights=self._clip_weights())  # fmt: skip
        self.motion_weights.record_block(
            self.world.concat_characters({k: block.frames[k] for k in ("clip", "terminated", "truncated")})
        )
        self._push(block)
        for k, v in block.charts.items():
            self._charts[k] = self._charts.get(k, 0.0) + v
        self._rates["new"] = self._rates.get("new", 0.0) + block.steps * self.cfg.train_envs
        return block.steps * self.gym_envs

    def _clip_weights(self) -> np.ndarray | None:
        return self.motion_weights.gym_weights(self.fixed_clip_weights)

    @property
    def gym_envs(self) -> int:
        """Characters in the gym (training plus held back)."""
        return self.cfg.gym.num_envs

    def _push(self, block: Block) -> None:
        """Block rows into the buffers: the first ``train_envs`` characters train, the others are held back."""
        n_train = self.cfg.train_envs
        collected_at = np.full(self.gym_envs, block.version, dtype=np.int64)
        for t in range(block.steps):
            frame = {**{k: v[t] for k, v in block.frames.items()}, "collected_at": collected_at}
            self.train_buffer.push(**{k: v[:n_train] for k, v in frame.items()})
            self.val_buffer.push(**{k: v[n_train:] for k, v in frame.items()})

    def update(self) -> dict[str, float]:
        """World-model step(s) then one policy step: the policy trains through the just-updated W, or with
        ``policy.concurrent`` through W as it was before this update's W steps, in a second thread beside them.

        Every window and the noise are drawn first, in the same order either way, so that the two modes read the
        same data and the serial mode is the plain sequence of steps."""
        c = self.cfg
        w_windows = [self._sample_windows("w", c.world_model.batch, c.world_model.window)
                     for _ in range(c.world_model.steps_per_iteration)]  # fmt: skip
        policy_input = None
        if self.updates >= c.policy.start_iteration:
            windows = self._sample_windows("policy", c.policy.batch, c.policy.window)
            noise = c.policy.sigma * torch.randn(windows["kin_next_joint_rot"].shape[:-1] + (3,), device=self.device)
            policy_input = (windows, noise)
        if self._world_thread is None:
            metrics = self._world_model_steps(w_windows)
            metrics.update(self._timed_policy_step(policy_input))
        else:
            self.policy_world.load_state_dict(self.world_model.state_dict())  # copies into the same tensors
            world = self._world_thread.submit(self._world_model_steps, w_windows)
            try:
                policy_metrics = self._timed_policy_step(policy_input)
            finally:
                metrics = world.result()  # W's thread finishes before anything else happens (or re-raises here)
            metrics.update(policy_metrics)
        self.updates += 1
        metrics.update(self._pop_charts())
        if self.updates % self.cfg.train.log_every == 0:
            metrics.update(self._pop_rates())
        return metrics

    def _world_model_steps(self, windows: list[dict[str, np.ndarray]]) -> dict[str, float]:
        start = time.perf_counter()
        metrics: dict[str, float] = {}
        for w in windows:
            metrics = self._world_model_step(w)
        metrics["perf/world_model_step_s"] = time.perf_counter() - start
        return metrics

    def _timed_policy_step(self, policy_input: tuple[dict[str, np.ndarray], torch.Tensor] | None) -> dict[str, float]:
        start = time.perf_counter()
        metrics = {} if policy_input is None else self._policy_step(*policy_input)
        metrics["perf/policy_step_s"] = time.perf_counter() - start
        return metrics

    def policy(self) -> EvalPolicy:
        return self.eval_actor.deterministic

    def diagnostics(self) -> dict[str, float]:
        d = self.cfg.diagnostics
        # Fresh generators with a fixed seed: the same windows every time, and the training RNG is not touched.
        out = open_loop_errors(self.world_model, self.val_buffer, d.horizons, d.batch, np.random.default_rng(d.seed),
                               prefix="world_model/val_", terrain=self.terrain)  # fmt: skip
        out.update(open_loop_errors(self.world_model, self.train_buffer, d.horizons, d.batch,
                                    np.random.default_rng(d.seed), prefix="world_model/train_",
                                    terrain=self.terrain))  # fmt: skip
        out.update(self.motion_weights.clip_charts(self.library.names))
        return out

    def state_dict(self) -> dict[str, Any]:
        return {
            "world_model": self.world_model.state_dict(), "policy": self.policy_net.state_dict(),
            "world_optimizer": self.world_optimizer.state_dict(),
            "policy_optimizer": self.policy_optimizer.state_dict(), "collector": self.collector.state_dict(),
            "train_buffer": self.train_buffer.state_dict(), "val_buffer": self.val_buffer.state_dict(),
            "updates": self.updates, "motion_weights": self.motion_weights.state_dict(),
            **({} if self.policy_average is None else {"policy_average": self.policy_average.state_dict()}),
        }  # fmt: skip

    def load_state_dict(self, state: dict[str, Any]) -> None:
        state = self._upgrade(state)
        self.world_model.load_state_dict(state["world_model"])
        self.policy_net.load_state_dict(state["policy"])
        self.world_optimizer.load_state_dict(state["world_optimizer"])
        self.policy_optimizer.load_state_dict(state["policy_optimizer"])
        self.train_buffer.load_state_dict(state["train_buffer"])
        self.val_buffer.load_state_dict(state["val_buffer"])
        self.collector.load_state_dict(state["collector"])
        self.updates = int(state["updates"])
        if "motion_weights" in state:  # runs from before the adaptive weights keep their initial rates
            self.motion_weights.load_state_dict(state["motion_weights"])
        if self.policy_average is not None:
            self.policy_average.load_state_dict(state["policy_average"])
        self._new_guards()

    def _upgrade(self, state: dict[str, Any]) -> dict[str, Any]:
        """A state of an older run in today's form, for ``--resume`` and the tools that read old runs (e.g.
        ``benchmarks/world_model_bodies.py``): buffer rows as :func:`supertrack.frames.upgrade_rows` gives them; a
        state from before :mod:`common.sim.collect` (a ``gym`` entry) gets the in-process collector's, with this
        collector's noise generator (the noise came from the learner's then)."""
        upgraded = {**state, **{name: {**state[name], "rows": upgrade_rows(state[name]["rows"])}
                                for name in ("train_buffer", "val_buffer")}}  # fmt: skip
        if "collector" in state or "gym" not in state:
            return upgraded
        if self.cfg.collect.processes != 0:
            raise ValueError("a checkpoint from before collect.processes existed loads with collect.processes=0 only")
        rng = self.collector.state_dict()["sources"][0]["rng"]
        upgraded["collector"] = {"sources": [{"gym": upgraded.pop("gym"), "rng": rng}], "pending": None}
        return upgraded

    def init_networks(self, learner_state: dict[str, Any]) -> None:
        """Starts from another run's world model and policy (with the normalisers they were trained with).

        Optimisers, buffers, gym and the iteration count stay fresh: this is fine-tuning (e.g. a walk policy as the
        start for run), not a resume. The weight average, if any, restarts from the loaded policy.

        Raises:
            ValueError: If the state lacks the networks or their sizes differ from this config's.
        """
        missing = [k for k in ("world_model", "policy") if k not in learner_state]
        if missing:
            raise ValueError(f"no {' or '.join(missing)} in the learner state (not a SuperTrack checkpoint)")
        try:
            self.world_model.load_state_dict(learner_state["world_model"])
            self.policy_net.load_state_dict(learner_state["policy"])
        except RuntimeError as e:  # the message lists every mismatched tensor
            raise ValueError(f"the networks do not fit this config (world_model.hidden / policy.hidden?): {e}") from e
        if self.policy_average is not None:  # the average restarts from the loaded policy
            self.policy_average.module.load_state_dict(self.policy_net.state_dict())
            self.policy_average.updates = 0
        self._new_guards()

    def close(self) -> None:
        self.collector.close()
        if self._world_thread is not None:
            self._world_thread.shutdown()

    # Training steps -----------------------------------------------------------------------------------------

    def _tensor(self, x: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(x, device=self.device)

    def world_model_loss(self, windows: dict[str, np.ndarray]) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """W's loss (Algorithm 1) on buffer windows, fields (B, L, ...), through the configured step functions; with
        ``terrain.contact_weight`` its contact term joins it."""
        sim = BodyState.unpack(self._tensor(windows["sim"]))
        rollout = world_model_prediction(self.world_model, sim, self._tensor(windows["target_rot"]), self.steps,
                                         self.terrain, self._window_clip(windows))  # fmt: skip
        loss, metrics = world_model_loss(rollout.predicted, sim.map(lambda x: x[:, 1:]), self.cfg.world_model.weights)
        if rollout.contacts is not None:
            contact, contact_metrics = contact_loss(rollout.contacts, self._tensor(windows["sim_contacts"][:, 1:]))
            loss = loss + self.cfg.terrain.contact_weight * contact
            metrics = {**metrics, **contact_metrics, "losses/world_model": loss.detach()}
        return loss, metrics

    def policy_loss(self, windows: dict[str, np.ndarray],
                    noise: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:  # fmt: skip
        """The policy's loss (Algorithm 2) on buffer windows (B, L, ...) with exploration noise (B, L, J, 3)."""
        c = self.cfg.policy
        sim0 = BodyState.unpack(self._tensor(windows["sim"][:, 0]))
        kin_next = BodyState.unpack(self._tensor(windows["kin_next"]))
        kin_rot = self._tensor(windows["kin_next_joint_rot"])
        kin_contacts = self._tensor(windows["kin_contacts"]) if "kin_contacts" in windows else None
        rollout = policy_rollout(self.policy_net, self.policy_world, sim0, kin_next, kin_rot, noise, c.alpha,
                                 self.steps, self.terrain, self._window_clip(windows), kin_contacts)  # fmt: skip
        return policy_loss(rollout.predicted, kin_next, rollout.offsets, c.weights, c.step_decay)

    def _window_clip(self, windows: dict[str, np.ndarray]) -> torch.Tensor | None:
        """Each window's clip (B,), whose terrain its rollout samples; None without terrain inputs."""
        return None if self.terrain is None else self._tensor(windows["clip"][:, 0])

    def warm_up(self) -> None:
        """Runs both losses forward and backward once on stand-in windows of the training shapes, so that
        ``torch.compile`` compiles before the training clock starts. Weights, optimisers, buffers and every RNG are
        left as they were (the gradients are dropped)."""
        w, p = self.cfg.world_model, self.cfg.policy
        if not (w.compile or p.compile):
            return
        rng_state = torch.get_rng_state()
        fields = self.train_buffer.fields

        def stand_in(batch: int, window: int) -> dict[str, np.ndarray]:
            # Zeros in the shapes and memory layout sample_windows gives (the compiled graphs guard on both).
            return {k: np.zeros((batch, window, *shape), dtype) for k, (shape, dtype) in fields.items()}

        self.world_model_loss(stand_in(w.batch, w.window))[0].backward()
        windows = stand_in(p.batch, p.window)
        noise = torch.zeros(windows["kin_next_joint_rot"].shape[:-1] + (3,), device=self.device)
        self.policy_loss(windows, noise)[0].backward()
        for module in (self.world_model, self.policy_net):
            module.zero_grad(set_to_none=True)
        torch.set_rng_state(rng_state)

    def _sample_windows(self, reader: str, batch: int, window: int) -> dict[str, np.ndarray]:
        """``batch`` training windows of ``window`` frames, counted as read by ``reader`` (w or policy)."""
        windows = self.train_buffer.sample_windows(batch, window, self.rng)
        self._count_reads(reader, windows["collected_at"])
        return windows

    def _world_model_step(self, windows: dict[str, np.ndarray] | None = None) -> dict[str, float]:
        """One W step on ``windows`` (default: drawn here)."""
        c = self.cfg.world_model
        if windows is None:
            windows = self._sample_windows("w", c.batch, c.window)
        loss, metrics = self.world_model_loss(windows)
        return self._optimize("world_model", loss, metrics, self.world_model, self.world_optimizer,
                              self.world_guard, c.grad_clip, _batch_stats(windows["sim"]))  # fmt: skip

    def _policy_step(self, windows: dict[str, np.ndarray], noise: torch.Tensor) -> dict[str, float]:
        """One policy step on ``windows`` with exploration ``noise`` (B, L, J, 3)."""
        c = self.cfg.policy
        loss, metrics = self.policy_loss(windows, noise)
        out = self._optimize("policy", loss, metrics, self.policy_net, self.policy_optimizer,
                             self.policy_guard, c.grad_clip, _batch_stats(windows["sim"][:, 0]))  # fmt: skip
        if self.policy_average is not None:
            self.policy_average.update(self.policy_net)
        return out

    def _optimize(self, name: str, loss: torch.Tensor, metrics: dict[str, torch.Tensor], module: torch.nn.Module,
                  optimizer: torch.optim.Optimizer, guard: NanGuard, grad_clip: float | None,
                  stats: dict[str, float]) -> dict[str, float]:  # fmt: skip
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        # Data-parallel: the gradients and the loss averaged over the ranks (a single process: unchanged), so that
        # every rank clips, checks and steps alike.
        mean_loss = self.world.average_gradients(module.parameters(), loss, stream=name)
        grad_norm = torch.nn.utils.clip_grad_norm_(module.parameters(), math.inf if grad_clip is None else grad_clip)
        # A finite loss can still give non-finite gradients (e.g. through a degenerate rotation): check both.
        if guard.check({name: mean_loss, f"{name}_grad_norm": grad_norm}, stats):
            optimizer.step()
        metrics[f"losses/{name}_grad_norm"] = grad_norm.detach()
        values = torch.stack(list(metrics.values())).cpu().tolist()
        return dict(zip(metrics.keys(), values, strict=True))

    def _count_reads(self, name: str, collected_at: np.ndarray) -> None:
        """Frames an update read (B x L windows) and the updates since each was collected (before this update)."""
        r = self._rates
        r[f"read_{name}"] = r.get(f"read_{name}", 0.0) + collected_at.size
        r["age_sum"] = r.get("age_sum", 0.0) + float((self.updates - collected_at).sum())
        r["age_count"] = r.get("age_count", 0.0) + collected_at.size

    def _pop_rates(self) -> dict[str, float]:
        """The data rate since the last log line (every ``train.log_every`` updates): frames read per new training
        frame by W and by the policy, and the mean age in updates of the frames read."""
        r, self._rates = self._rates, {}
        if not r.get("new"):
            return {}
        out = {"charts/replay_ratio_w": r.get("read_w", 0.0) / r["new"],
               "charts/replay_ratio_policy": r.get("read_policy", 0.0) / r["new"]}  # fmt: skip
        if r.get("age_count"):
            out["charts/buffer_age"] = r["age_sum"] / r["age_count"]
        return out

    def _pop_charts(self) -> dict[str, float]:
        """What the gym's characters did since the last update (the keys both learners log, see
        :func:`common.sim.collect.chart_metrics`), and the buffer's size."""
        c, self._charts = self._charts, {}
        if not c:
            return {}
        charts = {**chart_metrics(c), **self.motion_weights.charts()}
        return {**charts, "charts/buffer_frames": float(len(self.train_buffer))}


def _batch_stats(packed_sim: np.ndarray) -> dict[str, float]:
    """What the NaN guard reports about a batch of packed states (..., N, 13)."""
    s = BodyState.unpack(torch.as_tensor(packed_sim))
    return {
        "max_abs_pos": float(s.pos.abs().max()),
        "min_height": float(s.pos[..., 2].min()),
        "max_speed": float(s.vel.norm(dim=-1).max()),
        "max_angular_speed": float(s.angvel.norm(dim=-1).max()),
        "max_quat_norm_error": float((s.rot.norm(dim=-1) - 1.0).abs().max()),
    }
