"""Trivial baselines every learned simulator must beat: constant velocity and a frozen cloth."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from clods_bench.benchmark.core.interfaces import FitContext, RolloutInput
from clods_bench.datasets.types import Trajectory


class ConstantVelocity:
    """x_{t+1} = 2 x_t - x_{t-1} for NORMAL nodes; kinematic nodes follow their prescribed positions."""

    def fit(self, train: Sequence[Trajectory], ctx: FitContext) -> dict[str, float]:
        return {}

    def rollout(self, inp: RolloutInput) -> np.ndarray:
        frames = np.empty(inp.kinematic_pos.shape, dtype=np.float64)
        frames[:2] = inp.init_pos
        free = ~inp.kinematic_mask
        for t in range(2, inp.num_frames):
            frames[t] = inp.kinematic_pos[t]
            frames[t, free] = 2.0 * frames[t - 1, free] - frames[t - 2, free]
        return frames.astype(np.float32)


class Frozen:
    """x_t = x_1 for NORMAL nodes: the cloth stops moving; kinematic nodes follow their prescribed positions."""

    def fit(self, train: Sequence[Trajectory], ctx: FitContext) -> dict[str, float]:
        return {}

    def rollout(self, inp: RolloutInput) -> np.ndarray:
        frames = inp.kinematic_pos.astype(np.float32).copy()
        free = ~inp.kinematic_mask
        frames[:2] = inp.init_pos
        frames[2:, free] = inp.init_pos[1, free]
        return frames
