"""The trainer shared by the learned simulators: MGN's noisy one-step loss or CloDS' K-step rollout loss.

One optimiser step draws `batch_size` (trajectory, frame) samples uniformly with its own
generator, joins them into one disjoint graph and takes an Adam step at MGN's decayed learning
rate. Noise n ~ N(0, noise_std^2) is added to x_t of NORMAL nodes only (DeepMind `dataset.py`:
x_{t-1} stays clean, so the input velocity carries the noise too) and the target moves by
(1 - gamma) n, so the target acceleration is
a* = (x_{t+1} + (1 - gamma) n) - 2 (x_t + n) + x_{t-1} = a - (1 + gamma) n.

One-step loss (MGN): mean over NORMAL nodes of |normalised a* - network output|^2.
Rollout loss (CloDS eq. 8): the model is unrolled K steps from the noisy state, kinematic nodes
prescribed, and the loss is the mean over the K steps of the same node-mean of squared position
errors, each divided by the output normaliser's std. The first step's target is the noise-corrected
x_{t+1}; with K = 1 the two losses are equal. Dividing by the std keeps the loss scale of the
one-step loss (eq. 8's MSE in metres^2 is ~1e-6); averaging instead of summing over steps only
rescales it.
Targets, integration and position errors are computed in float64: positions are ~1 m while
accelerations can be ~1e-4 m per frame^2, which float32 differences resolve only to ~0.1 %.

Everything random comes from the trainer's generator and all state (parameters, normaliser sums,
Adam moments, generator, step) is in `state_dict`, so a resumed run repeats an uninterrupted one.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Sequence

import torch

from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.config import LearnedConfig
from clods_bench.plugins.simulators.learned.graph import Topology, TopologyCache, build_features
from clods_bench.plugins.simulators.learned.model import LearnedModel, integrate

FINAL_LOSS_WINDOW = 100  # final_loss: mean over the last steps, a single step's loss is noisy
CURVE_POINTS = 200  # the stored loss curve has about this many points


@dataclass(frozen=True)
class Batch:
    """Windows of K+2 frames (K+2, V, 3) of several samples joined as one graph, with its topology."""

    frames: torch.Tensor
    topo: Topology
    key: str


class TrainingData:
    """Training trajectories as tensors, their topology keys, and every (trajectory, start frame) sample."""

    def __init__(self, trajectories: Sequence[Trajectory], cache: TopologyCache, window: int) -> None:
        self.window = window  # predicted steps per sample (1 for the one-step loss)
        self.pos = [torch.as_tensor(t.world_pos, dtype=torch.float32, device=cache.device) for t in trajectories]
        self.keys = [cache.get(t.cells, t.mesh_pos, t.node_type)[0] for t in trajectories]
        self.cache = cache
        index = [(i, t) for i, traj in enumerate(trajectories) for t in range(1, traj.num_steps - window)]
        if not index:
            longest = max(t.num_steps for t in trajectories)
            raise ClodsError(
                f"no training samples: a sample needs {window + 2} frames, the longest trajectory has {longest}",
                where="learned simulator fit",
                hint="use longer trajectories or a shorter rollout_length",
            )
        self.index = torch.tensor(index, dtype=torch.int64)

    def __len__(self) -> int:
        return int(self.index.shape[0])

    def batch(self, rows: torch.Tensor) -> Batch:
        """The samples at `rows` of the index: frames t-1 .. t+window of each, joined along nodes."""
        picks = [(int(i), int(t)) for i, t in self.index[rows].tolist()]
        frames = torch.cat([self.pos[i][t - 1 : t + self.window + 1] for i, t in picks], dim=1)
        keys = tuple(self.keys[i] for i, _ in picks)
        return Batch(frames, self.cache.batch(keys), TopologyCache.batch_key(keys))


class Trainer:
    """Optimiser, schedule, noise and losses for one `LearnedModel` on one `TrainingData`."""

    def __init__(self, model: LearnedModel, config: LearnedConfig, data: TrainingData, seed: int) -> None:
        self.model = model
        self.config = config
        self.data = data
        self.optimizer = torch.optim.Adam(model.parameters(), lr=config.learning_rate, foreach=True)
        self.generator = torch.Generator().manual_seed(int(seed))
        self.step = 0
        self.train_seconds = 0.0
        self.recent: deque[float] = deque(maxlen=FINAL_LOSS_WINDOW)
        self.curve: list[float] = []  # mean loss per block of `curve_block` steps
        self._block: list[float] = []

    @property
    def curve_block(self) -> int:
        """Steps per point of the stored loss curve."""
        return max(1, self.config.train_steps // CURVE_POINTS)

    def sample(self) -> tuple[Batch, torch.Tensor]:
        """A random batch and its noise (V,3), zero on non-NORMAL nodes."""
        rows = torch.randint(len(self.data), (self.config.batch_size,), generator=self.generator)
        batch = self.data.batch(rows)
        noise = torch.randn(batch.frames.shape[1:], generator=self.generator) * self.config.noise_std  # CPU generator
        return batch, noise.to(batch.frames.device) * batch.topo.normal.unsqueeze(1)

    def accumulate_only(self, batch: Batch, noise: torch.Tensor) -> None:
        """Warm-up: feed the sample's statistics to the normalisers without running the network."""
        model, f = self.model, batch.frames
        cur, prev = f[1] + noise, f[0]
        nodes, sets = build_features(batch.topo, cur, prev, model.spec)
        model.node_normalizer(nodes, accumulate=True)
        for name, es in sets.items():
            model.edge_normalizers[name](es.features, accumulate=True)
        model.output_normalizer(self._target_output(batch, noise), accumulate=True)
        model.normalized_positions(batch.topo, cur, accumulate=True)

    def _target_acceleration(self, batch: Batch, noise: torch.Tensor) -> torch.Tensor:
        """a* = (x_{t+1} + (1 - gamma) n) - 2 (x_t + n) + x_{t-1}."""
        f, n = batch.frames[:3].double(), noise.double()  # float64: x ~ 1 m, a ~ 1e-4 m cancels in float32
        return ((f[2] + (1.0 - self.config.noise_gamma) * n) - 2.0 * (f[1] + n) + f[0]).float()

    def _target_output(self, batch: Batch, noise: torch.Tensor) -> torch.Tensor:
        """The decoder's target before normalisation: a* (above), or for a velocity output
        v* = (x_{t+1} + (1 - gamma) n) - (x_t + n)."""
        if self.model.output == "acceleration":
            return self._target_acceleration(batch, noise)
        f, n = batch.frames[:3].double(), noise.double()
        return ((f[2] + (1.0 - self.config.noise_gamma) * n) - (f[1] + n)).float()

    def one_step_loss(self, batch: Batch, noise: torch.Tensor) -> torch.Tensor:
        """MGN loss: mean over NORMAL nodes of the squared error of the normalised acceleration."""
        f, topo = batch.frames, batch.topo
        out = self.model(topo, batch.key, f[1] + noise, f[0], accumulate=True)
        target = self.model.output_normalizer(self._target_output(batch, noise), accumulate=True)
        return ((target - out) ** 2).sum(dim=1)[topo.normal].mean()

    def rollout_loss(self, batch: Batch, noise: torch.Tensor, steps: int | None = None) -> torch.Tensor:
        """CloDS eq. 8: K unrolled steps (`steps`, default all the batch's window), mean of node-mean squared
        position errors over the output std."""
        topo, model = batch.topo, self.model
        f, n = batch.frames.double(), noise.double()  # integrate and compare in float64 (see _target_acceleration)
        prev, cur = f[0], f[1] + n
        model.output_normalizer(self._target_output(batch, noise), accumulate=True)
        scale = model.output_normalizer.std.double()
        total = f.new_zeros(())
        steps = f.shape[0] - 2 if steps is None else min(int(steps), f.shape[0] - 2)
        for k in range(1, steps + 1):
            out = model(topo, batch.key, cur.float(), prev.float(), accumulate=(k == 1))
            nxt = integrate(cur, prev, model.acceleration(out, cur, prev).double(), topo.normal, f[k + 1])
            target = f[k + 1] + (1.0 - self.config.noise_gamma) * n if k == 1 else f[k + 1]
            total = total + (((nxt - target) / scale) ** 2).sum(dim=1)[topo.normal].mean()
            prev, cur = cur, nxt
        return (total / steps).float()

    def train_step(self) -> float | None:
        """One step: accumulate-only during warm-up (returns None), else an Adam step (returns the loss)."""
        cfg = self.config
        self.model.train()
        batch, noise = self.sample()
        if self.step < cfg.warmup_steps:
            with torch.no_grad():
                self.accumulate_only(batch, noise)
            self.step += 1
            return None
        for group in self.optimizer.param_groups:
            group["lr"] = cfg.learning_rate_at(self.step)
        if cfg.loss == "rollout":
            loss = self.rollout_loss(batch, noise, steps=1 if self.step < cfg.rollout_start_step else None)
        else:
            loss = self.one_step_loss(batch, noise)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.step += 1
        value = float(loss.detach())
        self.recent.append(value)
        self._block.append(value)
        if len(self._block) >= self.curve_block:
            self.curve.append(sum(self._block) / len(self._block))
            self._block = []
        return value

    @property
    def final_loss(self) -> float:
        """Mean loss over the last FINAL_LOSS_WINDOW optimiser steps (NaN before any)."""
        return sum(self.recent) / len(self.recent) if self.recent else float("nan")

    def state_dict(self) -> dict:
        """Everything needed to continue exactly: model, Adam, generator, step, time, loss history."""
        return {
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "generator": self.generator.get_state(),
            "step": self.step,
            "train_seconds": self.train_seconds,
            "recent": list(self.recent),
            "curve": list(self.curve),
            "block": list(self._block),
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore what `state_dict` saved."""
        self.model.load_state_dict(state["model"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.generator.set_state(state["generator"])
        self.step = int(state["step"])
        self.train_seconds = float(state["train_seconds"])
        self.recent = deque((float(v) for v in state["recent"]), maxlen=FINAL_LOSS_WINDOW)
        self.curve = [float(v) for v in state["curve"]]
        self._block = [float(v) for v in state["block"]]
