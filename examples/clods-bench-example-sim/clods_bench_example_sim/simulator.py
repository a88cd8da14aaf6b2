"""The simulator itself: free nodes keep a fraction of their velocity each step; handles follow their script."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from clods_bench.api import ClodsError, FitContext, RolloutInput


@dataclass(frozen=True)
class DampedVelocityConfig:
    """Options of `damped-velocity` (`sim_config.damped-velocity.*` in a config, or `--set`)."""

    damping: float = 0.9
    """Fraction of the velocity kept per step, in [0, 1]: 1 is constant velocity, 0 freezes the cloth at frame 1."""


class DampedVelocity:
    """x[t] = x[t-1] + damping * (x[t-1] - x[t-2]) for free nodes; kinematic nodes take their prescribed positions."""

    def __init__(self, cfg: DampedVelocityConfig) -> None:
        if not 0.0 <= cfg.damping <= 1.0:
            raise ClodsError(f"must be in [0, 1], got {cfg.damping}", where="sim_config.damped-velocity.damping")
        self.cfg = cfg

    def fit(self, train: Sequence[object], ctx: FitContext) -> dict[str, float]:
        """Nothing to learn; report how many trajectories were offered (shows up as a `fit/...` timing column)."""
        return {"num_train": float(len(train))}

    def rollout(self, inp: RolloutInput) -> np.ndarray:
        """(T, V, 3) float32 positions; frames 0 and 1 are the given ones."""
        x = np.empty(inp.kinematic_pos.shape, np.float64)
        x[:2] = inp.init_pos
        free = ~inp.kinematic_mask
        for t in range(2, inp.num_frames):
            x[t] = inp.kinematic_pos[t]
            x[t, free] = x[t - 1, free] + self.cfg.damping * (x[t - 1, free] - x[t - 2, free])
        return x.astype(np.float32)
