"""Options shared by every learned simulator (model widths, noise, loss, optimiser, checkpoints).

Defaults are MeshGraphNets' cloth settings (DeepMind `run_model.py`, `dataset.py`), which the
CloDS paper uses for its MGN rows; presets override them for small machines. A simulator's own
config subclasses `LearnedConfig` and adds its processor's options (torch-free, so registering
plugins does not import torch).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import sys
from dataclasses import dataclass
from typing import Literal

from clods_bench.devices import check_device_name
from clods_bench.errors import ClodsError
from clods_bench.typed_config import check_count, check_number


@dataclass(frozen=True)
class LearnedConfig:
    """Encoder/decoder widths, training noise, loss, optimiser schedule and checkpointing."""

    latent_size: int = 128
    """Width of every latent (node and edge) and of the MLPs' hidden layers."""
    hidden_layers: int = 2
    """Hidden layers per MLP (encoders, processor, decoder)."""
    world_radius: float = 0.05
    """Contact radius (m) of world edges; used only when the scene has obstacles."""
    noise_std: float = 0.003
    """Std (m) of Gaussian noise added to x_t of NORMAL nodes during training (MGN cloth: 0.003)."""
    noise_gamma: float = 0.1
    """The target x_{t+1} moves by (1 - gamma) of the noise (MGN cloth: 0.1)."""
    loss: Literal["one_step", "rollout"] = "one_step"
    """'one_step': MGN's normalised-acceleration loss; 'rollout': CloDS eq. 8, `rollout_length` steps backpropagated."""
    rollout_length: int = 8
    """Steps K of the rollout loss (paper: 8)."""
    rollout_start_step: int = 0
    """With loss 'rollout': optimiser steps before this one train on 1-step windows (K = 1, where the two losses
    agree), later ones on K-step rollouts, a curriculum that spends cheap steps first (0: K steps from the start)."""
    batch_size: int = 1
    """Training samples per optimiser step, batched as one disjoint graph (MGN cloth: 1)."""
    train_steps: int = 10_000_000
    """Optimiser steps, warm-up included (MGN: 10M)."""
    warmup_steps: int = 1000
    """First steps only accumulate normaliser statistics, no parameter update (MGN: 1000)."""
    learning_rate: float = 1e-4
    """Initial Adam learning rate (MGN: 1e-4)."""
    lr_decay_rate: float = 0.1
    """lr = learning_rate * lr_decay_rate ** (step / decay horizon) + lr_floor (MGN: 0.1)."""
    lr_decay_fraction: float = 0.5
    """Decay horizon as a fraction of `train_steps` (MGN: 5M of 10M steps)."""
    lr_floor: float = 1e-6
    """Constant added to the decayed learning rate (MGN: 1e-6)."""
    normalizer_accumulations: int = 1_000_000
    """Normalisers accumulate statistics over this many training calls, then freeze (MGN: 1e6)."""
    checkpoint_every: int = 1000
    """Write a resumable checkpoint every this many steps (and at the end)."""
    num_threads: int | None = None
    """torch CPU threads while training and rolling out; None leaves torch's setting."""
    device: str = "cpu"
    """Where the network trains and rolls out: 'cpu', 'cuda' or 'cuda:N' (weights are initialised on the CPU, so
    both start from the same model; the noise and batches come from the same CPU generator)."""

    def validate(self, where: str = "sim_config") -> None:
        """Raise ClodsError naming the first field out of range (step counts at most `MAX_STEPS`, numbers finite)."""
        for name in ("latent_size", "rollout_length", "batch_size"):
            check_count(getattr(self, name), f"{where}.{name}", maximum=sys.maxsize)
        for name in ("train_steps", "normalizer_accumulations", "checkpoint_every"):
            check_count(getattr(self, name), f"{where}.{name}")
        check_count(self.hidden_layers, f"{where}.hidden_layers", minimum=0, maximum=sys.maxsize)
        for name in ("warmup_steps", "rollout_start_step"):
            check_count(getattr(self, name), f"{where}.{name}", minimum=0)
        for name in ("world_radius", "learning_rate", "lr_decay_rate", "lr_decay_fraction"):
            check_number(getattr(self, name), f"{where}.{name}", minimum=0, inclusive=False)
        for name in ("noise_std", "noise_gamma", "lr_floor"):
            check_number(getattr(self, name), f"{where}.{name}", minimum=0)
        if self.num_threads is not None and self.num_threads < 1:
            raise ClodsError(f"must be >= 1 or null, got {self.num_threads!r}", where=f"{where}.num_threads")
        check_device_name(self.device, f"{where}.device")

    def learning_rate_at(self, step: int) -> float:
        """MGN's exponential decay, horizon scaled to `train_steps`: lr0 * rate^(step / horizon) + floor."""
        horizon = max(self.lr_decay_fraction * self.train_steps, 1.0)
        return self.learning_rate * self.lr_decay_rate ** (step / horizon) + self.lr_floor

    def digest(self) -> str:
        """Hash of the options that change the trained model (not checkpoint frequency, threads or device)."""
        values = dataclasses.asdict(self)
        for key in ("checkpoint_every", "num_threads", "device"):
            values.pop(key)
        values["__class__"] = type(self).__name__
        return hashlib.sha256(json.dumps(values, sort_keys=True, default=str).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class MgnConfig(LearnedConfig):
    """MeshGraphNets (Pfaff et al., ICLR 2021) cloth model; defaults are the paper's."""

    message_passing_steps: int = 15
    """Residual message-passing blocks (MGN: 15)."""

    def validate(self, where: str = "sim_config.mgn") -> None:
        """Raise ClodsError naming the first field out of range."""
        super().validate(where)
        if not isinstance(self.message_passing_steps, int) or self.message_passing_steps < 1:
            raise ClodsError(f"must be an integer >= 1, got {self.message_passing_steps!r}", where=f"{where}.message_passing_steps")
