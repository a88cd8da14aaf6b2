"""`LearnedSimulator`: the Simulator plugin object shared by MGN, BSMS-style and HCMT-style models.

`fit` trains a fresh model (seeded by the FitContext) with the shared trainer, writing a
resumable checkpoint to the work directory every `checkpoint_every` steps; a run interrupted
and started again with the same work directory continues where the checkpoint stopped.
`rollout` integrates the trained model from the two given frames; a diverging rollout is
returned with NaN from the first non-finite frame on (the task records it) rather than raising.

A training set whose meshes have no kinematic (handle) node is an error when the scene says
the cloth is pinned: the node types are then wrong (e.g. a conversion lost them), and a model
trained on them would learn a cloth that never feels its pins. A scene that declares no handles
(a free cloth) trains without complaint: a falling cloth is valid data.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from clods_bench.atomic import write_json
from clods_bench.benchmark.core.interfaces import FitContext, RolloutInput
from clods_bench.datasets.types import NORMAL, Trajectory
from clods_bench.devices import torch_device
from clods_bench.errors import ClodsError
from clods_bench.numerics.thread_limits import torch_threads
from clods_bench.plugins.simulators.learned.checkpoint import (
    list_snapshots,
    load_checkpoint,
    load_snapshot,
    mesh_digest,
    save_checkpoint,
    save_snapshot,
)
from clods_bench.plugins.simulators.learned.config import LearnedConfig
from clods_bench.plugins.simulators.learned.graph import GraphSpec, TopologyCache
from clods_bench.plugins.simulators.learned.model import LearnedModel, ProcessorFactory
from clods_bench.plugins.simulators.learned.trainer import Trainer, TrainingData

DT_RTOL = 1e-6


class LearnedSimulator:
    """A learned cloth simulator: shared encoder/decoder and trainer around the processor `processor_factory` builds."""

    def __init__(
        self, name: str, config: LearnedConfig, scene: object, processor_factory: ProcessorFactory, spec: GraphSpec | None = None
    ) -> None:
        """`spec`: the graph to build (default: the mesh graph the scene needs, `GraphSpec.for_scene`)."""
        config.validate(f"sim_config.{name}")
        self.name = name
        self.config = config
        self.scene_name = str(getattr(scene, "name", "?"))
        self.scene_has_handles = bool(getattr(scene, "has_handles", True))
        self.spec = spec if spec is not None else GraphSpec.for_scene(scene, config.world_radius)
        self.processor_factory = processor_factory
        self.cache = TopologyCache(config.device)
        self.model: LearnedModel | None = None
        self.dt: float | None = None
        self._digests: tuple[str, str] | None = None  # (config, training meshes) of the last fit: snapshots must match

    @property
    def checkpoint_name(self) -> str:
        """File name of this simulator's checkpoint inside the work directory."""
        return f"{self.name}.ckpt"

    def build_model(self, seed: int) -> LearnedModel:
        """A freshly initialised model; the weights depend only on `seed` (torch's global RNG is left as it was)."""
        cfg = self.config
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(seed))
            processor = self.processor_factory(cfg.latent_size, cfg.hidden_layers, list(self.spec.edge_widths))
            output = str(getattr(cfg, "output", "acceleration"))
            return LearnedModel(self.spec, processor, cfg.latent_size, cfg.hidden_layers, cfg.normalizer_accumulations, output)

    def _check_training_data(self, train: Sequence[Trajectory]) -> float:
        """Validate the trajectories; return their common dt."""
        where = f"simulator '{self.name}' fit"
        if len(train) == 0:
            raise ClodsError("no training trajectories", where=where)
        for i, traj in enumerate(train):
            traj.validate(f"{where}: trajectory {i}")
        dts = {float(t.dt) for t in train}
        if max(dts) - min(dts) > DT_RTOL * max(dts):
            raise ClodsError(f"training trajectories have different time steps {sorted(dts)}", where=where, hint="a learned model steps one frame at a time")
        if self.scene_has_handles and not any(np.any(t.node_type != NORMAL) for t in train):
            raise ClodsError(
                f"no kinematic (HANDLE) node in any training trajectory, but scene '{self.scene_name}' pins the cloth",
                where=where,
                hint="node_type must mark the pinned nodes (HANDLE=3); trained without them the model learns a falling cloth",
            )
        return float(train[0].dt)

    def fit(self, train: Sequence[Trajectory], ctx: FitContext) -> dict[str, float]:
        """Train (or resume training) on `train`; return train_seconds, final_loss, train_steps and more."""
        cfg = self.config
        dt = self._check_training_data(train)
        device = torch_device(cfg.device, f"sim_config.{self.name}.device")
        with torch_threads(cfg.num_threads):
            model = self.build_model(ctx.seed).to(device)
            window = cfg.rollout_length if cfg.loss == "rollout" else 1
            data = TrainingData(train, self.cache, window)
            trainer = Trainer(model, cfg, data, ctx.seed)
            path = Path(ctx.work_dir) / self.checkpoint_name
            meshes, digest = mesh_digest(data.keys), cfg.digest()
            resumed_from = 0
            if path.exists():
                trainer.load_state_dict(load_checkpoint(path, self.name, digest, meshes)["trainer"])
                resumed_from = trainer.step

            def checkpoint() -> None:
                save_checkpoint(path, self.name, digest, meshes, trainer.state_dict(), {"dt": dt, "scene": self.scene_name})

            def snapshot() -> None:
                save_snapshot(Path(ctx.work_dir), trainer.step, self.name, digest, meshes, model.state_dict())

            every = int(getattr(ctx, "snapshot_every", 0) or 0)
            self._train_loop(trainer, checkpoint, ctx.progress, snapshot if every > 0 else None, every)
            self.model, self.dt, self._digests = model.eval(), dt, (digest, meshes)
        write_json(Path(ctx.work_dir) / f"{self.name}_train_log.json", {"loss_curve": trainer.curve, "curve_block": trainer.curve_block})
        params = sum(p.numel() for p in model.parameters())
        return {
            "train_seconds": trainer.train_seconds,
            "final_loss": trainer.final_loss,
            "train_steps": float(trainer.step),
            "resumed_from_step": float(resumed_from),
            "train_samples": float(len(data)),
            "parameters": float(params),
        }

    def snapshots(self, work_dir: Path) -> list[tuple[int, Path]]:
        """(step, path) of the weight snapshots a fit with `snapshot_every` left in `work_dir`."""
        return list_snapshots(work_dir)

    def use_snapshot(self, path: Path) -> int:
        """Load a snapshot of the last fit into the model (rollouts then use it); returns its step."""
        if self.model is None or self._digests is None:
            raise ClodsError("snapshot before fit", where=f"simulator '{self.name}'", hint="call fit() first")
        state = load_snapshot(Path(path), self.name, *self._digests)
        self.model.load_state_dict(state)
        self.model.eval()
        return int(Path(path).stem.split("_", 1)[1])

    def _train_loop(self, trainer: Trainer, checkpoint: object, progress: bool, snapshot: object = None, every: int = 0) -> None:
        """Run the trainer to `train_steps`, checkpointing every `checkpoint_every` steps and at the end (and taking a
        weight snapshot every `every` steps and at the end when `snapshot` is given)."""
        cfg = self.config
        if trainer.step >= cfg.train_steps:
            return
        columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("loss {task.fields[loss]}"), TimeRemainingColumn())
        with Progress(*columns, transient=True, disable=not progress) as bar:
            job = bar.add_task(f"training {self.name}", total=cfg.train_steps, completed=trainer.step, loss="-")
            while trainer.step < cfg.train_steps:
                t0 = time.perf_counter()
                loss = trainer.train_step()
                trainer.train_seconds += time.perf_counter() - t0
                last = trainer.step == cfg.train_steps
                if snapshot is not None and trainer.step > cfg.warmup_steps and (trainer.step % every == 0 or last):
                    snapshot()  # type: ignore[operator]  # before the checkpoint: a resume never skips one
                if trainer.step % cfg.checkpoint_every == 0 or last:
                    checkpoint()  # type: ignore[operator]
                bar.update(job, completed=trainer.step, loss="warm-up" if loss is None else f"{trainer.final_loss:.4g}")

    def rollout(self, inp: RolloutInput) -> np.ndarray:
        """(T,V,3) float32 positions from the two given frames; NaN from the first non-finite frame on."""
        if self.model is None or self.dt is None:
            raise ClodsError("rollout before fit", where=f"simulator '{self.name}'", hint="call fit() first")
        where = f"simulator '{self.name}' rollout"
        v = inp.node_type.shape[0]
        if inp.init_pos.shape != (2, v, 3) or inp.kinematic_pos.shape[1:] != (v, 3):
            raise ClodsError(f"init_pos {inp.init_pos.shape} / kinematic_pos {inp.kinematic_pos.shape} do not match {v} nodes", where=where)
        if not math.isclose(float(inp.dt), self.dt, rel_tol=DT_RTOL):
            raise ClodsError(f"dt {inp.dt} differs from the training dt {self.dt}", where=where, hint="a learned model steps one training frame at a time")
        out = np.empty(inp.kinematic_pos.shape, dtype=np.float32)
        out[:2] = inp.init_pos
        key, topo = self.cache.get(inp.cells, inp.mesh_pos, inp.node_type)
        dev = topo.normal.device
        kin = torch.as_tensor(np.asarray(inp.kinematic_pos, dtype=np.float32), device=dev)
        prev = torch.as_tensor(out[0], device=dev)
        cur = torch.as_tensor(out[1], device=dev)
        with torch_threads(self.config.num_threads), torch.no_grad():
            for t in range(2, inp.num_frames):
                nxt = self.model.step(topo, key, cur, prev, kin[t])
                out[t] = nxt.cpu().numpy()
                if not torch.isfinite(nxt).all():
                    free = inp.node_type == NORMAL
                    out[t + 1 :] = inp.kinematic_pos[t + 1 :]
                    out[t + 1 :, free] = np.nan
                    break
                prev, cur = cur, nxt
        return out
