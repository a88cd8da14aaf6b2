"""The 'traditional pipeline' simulator: the ground-truth implicit cloth solver with the scene's known physics.

It knows the scene's material, gravity, damping and aerodynamic coefficients, but not the
trajectory's random wind (mean speed/direction and turbulence are drawn per trajectory from
a seed it never sees). With `wind = "expected"` it blows the wind's expected value over the
scene's draw (mean speed times E[cos(azimuth)] = sin(s)/s along +x, no turbulence, the
scene's ramp); with `"still"` the air is at rest (drag still acts on the moving cloth). This
is why its error is nonzero even at the data's time step; on a windless scene at the data's
time step it reproduces the ground truth up to float32 rounding.

Time stepping: one solver macro step covers `dt_factor` frames in `substeps` sub-steps (step
h = dt * dt_factor / substeps); frames inside a macro step are linearly interpolated. The
state at frame 1 is x1 and v1 = (x1 - x0)/dt, exactly the backward-Euler velocity of the data.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np

from clods_bench.benchmark.core.interfaces import FitContext, RolloutInput
from clods_bench.benchmark.scoring.monitors import flat_rest_pos, scene_rest_mesh
from clods_bench.datasets.cloth_solver import ClothSolver, SolverParams
from clods_bench.datasets.obstacle_nodes import split_cloth
from clods_bench.datasets.obstacles import TriangleMeshObstacle
from clods_bench.datasets.types import ClothMesh, Trajectory
from clods_bench.errors import ClodsError


@dataclass(frozen=True)
class PhysicsConfig:
    """Options of the physics simulator: time step relative to the data, and what wind it assumes."""

    dt_factor: int = 1
    """Frames per solver macro step (2: one step per 2 frames, the frame between interpolated); >= 1."""
    substeps: int | None = None
    """Solver sub-steps per macro step; None: the scene's own substeps (what generated the data)."""
    wind: Literal["expected", "still"] = "expected"
    """'expected': the expected mean wind of the scene's random draw, no turbulence; 'still': no wind."""
    newton_iterations: int | None = None
    """Newton iterations per step; None: the scene's."""

    def validate(self, where: str = "sim_config.physics") -> None:
        """Raise ClodsError naming the field that is out of range."""
        if self.dt_factor < 1:
            raise ClodsError(f"must be >= 1, got {self.dt_factor}", where=f"{where}.dt_factor")
        if self.substeps is not None and self.substeps < 1:
            raise ClodsError(f"must be >= 1, got {self.substeps}", where=f"{where}.substeps")
        if self.newton_iterations is not None and self.newton_iterations < 1:
            raise ClodsError(f"must be >= 1, got {self.newton_iterations}", where=f"{where}.newton_iterations")


def expected_wind(scene: object) -> tuple[float, float, float]:
    """E[wind velocity] over the scene's per-trajectory draw: speed uniform in its range, azimuth uniform in +-spread."""
    params: SolverParams = scene.params  # type: ignore[attr-defined]
    if not getattr(scene, "has_wind", False):
        return tuple(float(w) for w in params.wind_velocity)  # type: ignore[return-value]
    lo, hi = scene.wind_speed_range  # type: ignore[attr-defined]
    spread = float(scene.wind_direction_spread)  # type: ignore[attr-defined]
    along = math.sin(spread) / spread if spread > 0 else 1.0
    return (0.5 * (lo + hi) * along, 0.0, 0.0)


def solver_params(scene: object, cfg: PhysicsConfig) -> SolverParams:
    """The scene's solver parameters with the wind this simulator can know (no turbulence)."""
    wind = expected_wind(scene) if cfg.wind == "expected" else (0.0, 0.0, 0.0)
    params = dataclasses.replace(scene.params, wind_velocity=wind, turbulence_amplitude=0.0)  # type: ignore[attr-defined]
    if cfg.newton_iterations is not None:
        params = dataclasses.replace(params, newton_iterations=cfg.newton_iterations)
    return params


def _handle_interpolator(kin: np.ndarray, dt: float):
    """handle_fn(t): kinematic positions (H,3) linearly interpolated between frames, held after the last."""
    last = kin.shape[0] - 1

    def handle_fn(t: float) -> np.ndarray:
        s = min(max(t / dt, 0.0), float(last))
        i = min(int(math.floor(s)), last - 1) if last > 0 else 0
        w = s - i
        return kin[i] if last == 0 else (1.0 - w) * kin[i] + w * kin[i + 1]

    return handle_fn


class PhysicsSimulator:
    """Rolls out the implicit cloth solver with the scene's physics; nothing to train."""

    def __init__(self, scene: object, config: PhysicsConfig) -> None:
        config.validate()
        self.scene, self.config = scene, config
        self.params = solver_params(scene, config)
        self.params.validate("sim_config.physics (scene params)")
        self.last_stats: dict[str, float] = {}
        self._solvers: dict[tuple, ClothSolver] = {}  # per (topology, step): rest geometry and sparsity built once

    def fit(self, train: Sequence[Trajectory], ctx: FitContext) -> dict[str, float]:
        """Nothing to learn; one throw-away step loads the compiled kernels so inference timing excludes it."""
        if train:
            self.rollout(RolloutInput.from_trajectory(train[0], 3))
        return {}

    def rest_mesh(self, inp: RolloutInput) -> ClothMesh:
        """The rollout's cloth mesh (obstacle nodes left out) with its 3D rest shape: the scene's if it matches, else the flat flag (u, 0, v)."""
        part = split_cloth(inp.cells, inp.mesh_pos, inp.node_type)
        mesh = scene_rest_mesh(self.scene, part.cells, part.mesh_pos)
        rest = mesh.rest_pos if mesh is not None else flat_rest_pos(part.mesh_pos)
        return ClothMesh(part.cells, np.asarray(part.mesh_pos, np.float32), np.asarray(part.node_type, np.int32), rest)

    def _solver(self, inp: RolloutInput, h: float) -> ClothSolver:
        key = tuple(hash(np.ascontiguousarray(a).tobytes()) for a in (inp.cells, inp.mesh_pos, inp.node_type)) + (h,)
        if key not in self._solvers:
            self._solvers[key] = ClothSolver(self.rest_mesh(inp), self.params, h)
        return self._solvers[key]

    def rollout(self, inp: RolloutInput) -> np.ndarray:
        """(T,V,3) float32 frames from frames 0 and 1, kinematic nodes as prescribed.

        Obstacle nodes (a scene with obstacles) are not simulated: their recorded surface, interpolated between
        frames, is the solver's obstacle (`TriangleMeshObstacle.from_frames`), so contact is the ground truth's."""
        cfg = self.config
        substeps = cfg.substeps if cfg.substeps is not None else int(getattr(self.scene, "substeps", 1))
        dt, k = float(inp.dt), cfg.dt_factor
        part = split_cloth(inp.cells, inp.mesh_pos, inp.node_type)
        cloth = part.nodes
        kin_all = np.asarray(inp.kinematic_pos, np.float64)
        handle_mask = inp.kinematic_mask[cloth]
        kin = kin_all[:, cloth][:, handle_mask]
        solver = self._solver(inp, dt * k / substeps)
        solver.handle_fn = _handle_interpolator(kin, dt) if handle_mask.any() else None
        solver.obstacles = (
            [TriangleMeshObstacle.from_frames(kin_all[:, part.obstacle_nodes], part.obstacle_faces, dt)] if part.obstacle_nodes.size else []
        )
        solver.stats.update(cg_iterations=0, cg_residual_max=0.0, steps=0)
        x0 = np.asarray(inp.init_pos[0], np.float64)[cloth]
        x = np.asarray(inp.init_pos[1], np.float64)[cloth]
        v = (x - x0) / dt
        out = np.empty((inp.num_frames, inp.init_pos.shape[1], 3), np.float64)
        out[:2] = inp.init_pos
        frame = 1
        h = dt * k / substeps
        with np.errstate(all="ignore"):
            while frame < inp.num_frames - 1:
                x_prev = x
                for s in range(substeps):
                    x, v = solver.step(x, v, frame * dt + s * h)
                for j in range(1, k + 1):
                    if frame + j < inp.num_frames:
                        out[frame + j, cloth] = x_prev + (j / k) * (x - x_prev)
                frame += k
        kin_mask = inp.kinematic_mask
        out[2:, kin_mask] = inp.kinematic_pos[2:, kin_mask]
        self.last_stats = {k2: float(v2) for k2, v2 in solver.stats.items()}
        return out.astype(np.float32)
