"""The predict step of a Cloth-Splatting-style filter: a simulator's one step from the two previous extracted meshes.

Cloth-Splatting (Longhini et al., CoRL 2024) estimates the cloth state by predict-update: a GNN
predicts the next mesh from the previous states, and gradient steps on the rendering loss through
mesh-anchored Gaussians correct it. Here the prediction is the start of stage 2's per-frame fit
(`task_config.clods.start=simulator`), which is the correction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clods_bench.benchmark.core.interfaces import RolloutInput, Simulator, rollout_checked
from clods_bench.datasets.types import NORMAL
from clods_bench.errors import ClodsError


@dataclass(frozen=True)
class OneStepPredictor:
    """Predicts frame t+1 of one trajectory's mesh from frames t-1 and t with `simulator` (already fitted)."""

    simulator: Simulator
    cells: np.ndarray  # (F,3) int
    mesh_pos: np.ndarray  # (V,2) float32
    node_type: np.ndarray  # (V,) int
    dt: float
    name: str = "simulator"

    def __call__(self, done: np.ndarray) -> np.ndarray:
        """The next mesh (V,3) float32 after the last two of `done` (k>=2,V,3); handles stay where the last mesh has them."""
        if done.ndim != 3 or done.shape[0] < 2:
            raise ClodsError(f"the predict step needs the two previous meshes, got an array of shape {done.shape}", where="clods stage 2")
        last = np.asarray(done[-1], np.float32)
        kinematic = np.repeat(last[None], 3, axis=0)
        kinematic[:, np.asarray(self.node_type) == NORMAL] = np.nan
        inp = RolloutInput(self.cells, self.mesh_pos, self.node_type, np.asarray(done[-2:], np.float32), kinematic, float(self.dt))
        nxt = rollout_checked(self.simulator, inp, self.name)[2]
        if not np.isfinite(nxt).all():
            raise ClodsError(
                "the pretrained simulator's one-step prediction is not finite", where="task_config.clods.start",
                hint="the pretrained simulator diverges on the extracted meshes; use start=velocity",
            )  # fmt: skip
        out = np.array(nxt, dtype=np.float32)
        handles = np.asarray(self.node_type) != NORMAL
        out[handles] = last[handles]  # the rollout contract already says so; stage 2 never moves a handle
        return out
