"""Named cloth scenes (flag, stiff, storm, large time step, lit with shadows, cylinder, two with obstacles) and their simulation.

A scene is its cloth (a `Cloth` from `cloths`: the built-in flag and cylinder, or any triangle
mesh a scene plugin brings), the physics (the environment) and the ranges its trajectories are drawn from;
`simulate_scene` draws one trajectory's initial pose, initial velocity and turbulence from a seed,
so a dataset is reproducible trajectory by trajectory. As in FLAGSIMPLE ("the same shaped cloth in
the same environment", a unique initial state per trajectory), the flag scenes blow one mean wind
on every trajectory: a simulator that sees only meshes can learn it, which it could not if each
trajectory drew its own unobservable mean wind. The recorded frames start after `warmup_time`
seconds of simulation, so frame 0 is a flag already flying and the extrapolation frames come from
the same regime as the interpolation frames, even for the short trajectories of small presets.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import sys
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from clods_bench.datasets.cloth_solver import ClothSolver, SolverParams
from clods_bench.datasets.cloths import (
    Cloth,
    CylinderCloth,
    FlagCloth,
    Resolution,
    SheetCloth,
    validate_cloth_mesh,
    validate_handle_motion,
)
from clods_bench.datasets.fixed_order import apply3
from clods_bench.datasets.legacy_scenes import (
    adopt_build_mesh_override,
    bind_legacy_cloth,
    is_legacy_call,
    legacy_size,
    old_base_mesh,
    translate_legacy_call,
)
from clods_bench.datasets.lighting import DirectionalLight
from clods_bench.datasets.obstacle_nodes import append_obstacles
from clods_bench.datasets.obstacles import Obstacle, ObstaclePath, Sphere, overlap
from clods_bench.datasets.types import NORMAL, ClothMesh, Trajectory
from clods_bench.errors import ClodsError, unknown_name


class _SceneSpecType(type):
    """Accepts the deprecated pre-1.0 call `SceneSpec(kind=...)` (`legacy_scenes`), for subclasses whose own
    dataclass `__init__` would refuse it too, and ties a deprecated `build_mesh` override's cloth to its scene."""

    def __call__(cls, *args: Any, **kwargs: Any) -> Any:
        if is_legacy_call(args, kwargs):
            args, kwargs = (), translate_legacy_call(cls, args, kwargs, stacklevel=2)
        scene = super().__call__(*args, **kwargs)
        bind_legacy_cloth(scene)
        return scene

    @property
    def __signature__(cls) -> inspect.Signature:
        """The dataclass's own signature (help() and the docs would otherwise show this `__call__`'s)."""
        sig = inspect.signature(cls.__init__)  # type: ignore[misc]
        return sig.replace(parameters=list(sig.parameters.values())[1:])


@dataclass(frozen=True)
class SceneSpec(metaclass=_SceneSpecType):
    """A named scene: its cloth (a `Cloth` plugin), physics, time step, what it contains, and per-trajectory random ranges."""

    name: str
    description: str  # one line
    cloth: Cloth
    """The cloth: mesh, rest coordinates, handles and their motion (`clods_bench.datasets.cloths`)."""
    params: SolverParams
    dt: float = 0.02
    substeps: int = 1
    has_obstacles: bool = False
    has_wind: bool = True
    has_lighting: bool = False
    has_handles: bool = True
    rotation_range: tuple[float, float] = (-0.6, 0.6)  # initial rotation about the vertical axis through the handles, rad
    init_speed_range: tuple[float, float] = (0.0, 1.0)  # initial velocity of the free end, m/s
    perturb_amplitude: float = 0.05  # largest smooth out-of-plane initial displacement, m
    wind_speed_range: tuple[float, float] = (8.0, 8.0)  # mean wind speed, m/s (one value: the same environment)
    wind_direction_spread: float = 0.0  # azimuth of the wind is +x +- this, rad
    warmup_time: float = 1.0  # seconds simulated before frame 0 is recorded (frame 0 = the cloth already in motion)
    light: DirectionalLight | None = None
    """The ground-truth renderer's light and shadows when `has_lighting` (None: the generator's default light, no
    shadows). Only the ground-truth frames see it; the Gaussian renderers are not given it."""
    obstacles: tuple[Obstacle, ...] = ()
    """Rigid obstacles (`clods_bench.datasets.obstacles`), static or on a path; set exactly when `has_obstacles`.
    The solver collides the cloth with them; each trajectory stores them as OBSTACLE nodes after the cloth's."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        adopt_build_mesh_override(cls)  # deprecated extension point: the override becomes the cloth's mesh

    def __post_init__(self) -> None:
        where = f"scene {self.name}"
        if not isinstance(self.cloth, Cloth):
            raise ClodsError(f"cloth is a {type(self.cloth).__name__}, expected a clods_bench.datasets.cloths.Cloth", where=where)
        if not isinstance(self.obstacles, tuple):
            raise ClodsError(f"obstacles is a {type(self.obstacles).__name__}, expected a tuple of Obstacle", where=where)
        for k, obstacle in enumerate(self.obstacles):
            if not isinstance(obstacle, Obstacle):
                raise ClodsError(f"is a {type(obstacle).__name__}, expected a clods_bench.datasets.obstacles.Obstacle",
                                 where=f"{where}.obstacles[{k}]")  # fmt: skip
            obstacle.validate(where=f"{where}.obstacles[{k}]")
        if bool(self.obstacles) != self.has_obstacles:
            raise ClodsError(f"has_obstacles is {self.has_obstacles} but the scene has {len(self.obstacles)} obstacles",
                             where=where, hint="has_obstacles must be True exactly when obstacles are given")  # fmt: skip
        if self.light is not None:
            if not isinstance(self.light, DirectionalLight):
                raise ClodsError(f"light is a {type(self.light).__name__}, expected a DirectionalLight", where=f"scene {self.name}")
            if not self.has_lighting:
                raise ClodsError("light is set but has_lighting is False", where=f"scene {self.name}", hint="set has_lighting=True")
            self.light.validate(where=f"scene {self.name}")

    @property
    def kind(self) -> str:
        """The cloth's kind (flag, cylinder, mesh, or the plugin's own), written into each trajectory's meta."""
        return self.cloth.kind

    @property
    def default_resolution(self) -> Resolution | None:
        """The cloth's resolution when the config names none."""
        return self.cloth.default_resolution

    def __getattr__(self, name: str) -> Any:
        """`size`, the cloth's size, read by `build_mesh` overrides of the pre-1.0 form (deprecated; not in the API)."""
        size = legacy_size(self.__dict__["cloth"]) if name == "size" and "cloth" in self.__dict__ else None
        if size is None:
            raise AttributeError(f"'{type(self).__name__}' object has no attribute '{name}'")
        return size

    def build_mesh(self, resolution: Resolution | None = None) -> ClothMesh:
        """The scene's validated cloth mesh at `resolution` (None: the cloth's default); one ClodsError naming the scene if bad.

        Flag: (nx, ny) | "flagsimple"; cylinder: (n_around, n_along) | "flagsimple" (a tube of about the
        FLAGSIMPLE size, 48 x 33 = 1584 nodes); a `MeshCloth` has one resolution.
        """
        where = f"scene {self.name}"
        old = old_base_mesh(self, resolution)  # `super().build_mesh()` inside a deprecated override
        if old is not None:
            return old
        try:
            mesh = self.cloth.build(resolution)
        except ClodsError as exc:
            raise ClodsError(exc.what if exc.where is None else f"{exc.where}: {exc.what}", where=where, hint=exc.hint) from exc
        if not isinstance(mesh, ClothMesh):
            raise ClodsError(f"{type(self.cloth).__name__}.build returned a {type(mesh).__name__}, expected a ClothMesh", where=where)
        validate_cloth_mesh(mesh, where, self.has_handles)
        validate_handle_motion(self.cloth, np.asarray(mesh.rest_pos[mesh.node_type != NORMAL], np.float64), self.dt, where)
        check_clear_of_obstacles(self, np.asarray(mesh.rest_pos, np.float64), 0.0, "rest shape")
        return mesh


def check_clear_of_obstacles(scene: SceneSpec, x: np.ndarray, t: float, what: str) -> None:
    """Raise one ClodsError naming the scene and the obstacle if a cloth node at `x` (V,3) is inside one (or within
    the contact thickness of it) at time t."""
    margin = float(scene.params.contact_thickness)
    for k, obstacle in enumerate(scene.obstacles):
        inside = overlap([obstacle], x, t, margin=margin)
        if inside.any():
            raise ClodsError(
                f"the cloth's {what} has {int(inside.sum())} nodes inside obstacle {type(obstacle).__name__} or within "
                f"{margin:g} m of it at t = {t:g} s, first is node {int(np.argmax(inside))}",
                where=f"scene {scene.name}.obstacles[{k}]",
                hint="move the obstacle or the cloth apart (or narrow the scene's rotation/perturbation ranges)",
            )


def _rotation_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _vertex_normals(x: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals."""
    fn = np.cross(x[cells[:, 1]] - x[cells[:, 0]], x[cells[:, 2]] - x[cells[:, 0]])
    vn = np.zeros_like(x)
    for k in range(3):
        np.add.at(vn, cells[:, k], fn)
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-12)


def initial_state(scene: SceneSpec, mesh: ClothMesh, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict]:
    """Random initial positions and velocities: rotation about the axis, smooth bend, free-end velocity.

    This is the state at the start of the warm-up; frame 0 is recorded `scene.warmup_time` later."""
    rest = np.asarray(mesh.rest_pos, dtype=np.float64)
    handles = mesh.node_type != NORMAL
    anchor = rest[handles] if handles.any() else rest
    axis_xy = np.array([*anchor[:, :2].mean(axis=0), 0.0])
    angle = float(rng.uniform(*scene.rotation_range))
    x0 = apply3(_rotation_z(angle), rest - axis_xy) + axis_xy
    # weight 0 at the handles growing to 1 at the farthest node (in rest space)
    if handles.any():
        dist = np.min(np.linalg.norm(rest[:, None, :] - anchor[None, :, :], axis=2), axis=1)
    else:
        dist = np.ones(rest.shape[0])
    w = dist / max(float(dist.max()), 1e-12)
    span = float(np.ptp(mesh.mesh_pos, axis=0).max())
    k = rng.uniform(0.5, 1.5, 2) * 2.0 * math.pi / span
    phase = rng.uniform(0.0, 2.0 * math.pi, 2)
    amp = float(rng.uniform(0.0, scene.perturb_amplitude))
    bump = np.sin(mesh.mesh_pos[:, 0] * k[0] + phase[0]) * np.cos(mesh.mesh_pos[:, 1] * k[1] + phase[1])
    x0 += (amp * w * bump)[:, None] * _vertex_normals(x0, mesh.cells)
    speed = float(rng.uniform(*scene.init_speed_range))
    direction = rng.standard_normal(3)
    vel = speed * direction / max(float(np.linalg.norm(direction)), 1e-12)
    v0 = w[:, None] * vel[None, :]
    v0[handles] = 0.0
    meta = {"rotation": angle, "perturb_amplitude": amp, "initial_velocity": vel.tolist()}
    return x0, v0, meta


def draw_wind(scene: SceneSpec, rng: np.random.Generator) -> tuple[SolverParams, dict]:
    """The scene's params with this trajectory's mean wind (speed and azimuth drawn from the ranges)."""
    if not scene.has_wind:
        return scene.params, {"wind_velocity": list(scene.params.wind_velocity), "wind_speed": 0.0, "wind_azimuth": 0.0}
    speed = float(rng.uniform(*scene.wind_speed_range))
    azimuth = float(rng.uniform(-scene.wind_direction_spread, scene.wind_direction_spread))
    wind = (speed * math.cos(azimuth), speed * math.sin(azimuth), 0.0)
    meta = {"wind_velocity": list(wind), "wind_speed": speed, "wind_azimuth": azimuth}
    return dataclasses.replace(scene.params, wind_velocity=wind), meta


def simulate_scene(scene: SceneSpec, mesh: ClothMesh, num_steps: int, seed: int, progress: bool = False) -> Trajectory:
    """Simulate one trajectory of `num_steps` frames (frame 0 = initial state) drawn from `seed`."""
    if int(num_steps) < 2:
        raise ClodsError(f"num_steps must be >= 2, got {num_steps}", where=f"scene {scene.name}")
    rng = np.random.default_rng(seed)
    x0, v0, meta_init = initial_state(scene, mesh, rng)
    params, meta_wind = draw_wind(scene, rng)
    solver_seed = int(rng.integers(0, 2**31 - 1))
    start_handles = x0[mesh.node_type != NORMAL].copy()
    moving = validate_handle_motion(scene.cloth, start_handles, scene.dt, f"scene {scene.name}")
    handle_fn = (lambda t: scene.cloth.handle_positions(t, start_handles)) if moving else None
    check_clear_of_obstacles(scene, x0, 0.0, f"initial pose (seed {seed})")
    solver = ClothSolver(mesh, params, scene.dt, seed=solver_seed, handle_fn=handle_fn, obstacles=scene.obstacles)

    def report(frame: int, total: int) -> None:
        if frame == total - 1 or frame % max(total // 10, 1) == 0:
            print(f"scene {scene.name} seed {seed}: frame {frame + 1}/{total}", file=sys.stderr, flush=True)

    start = time.perf_counter()
    warm = int(round(scene.warmup_time / scene.dt))
    world_pos = solver.simulate(x0, v0, warm + int(num_steps), scene.substeps, progress=report if progress else None)[warm:]
    seconds = time.perf_counter() - start
    steps = max(int(solver.stats["steps"]), 1)
    meta = {
        "scene": scene.name,
        "kind": scene.kind,
        "seed": int(seed),
        "solver_seed": solver_seed,
        "dt": scene.dt,
        "substeps": scene.substeps,
        "warmup_time": warm * scene.dt,
        **meta_init,
        **meta_wind,
        "turbulence_amplitude": params.turbulence_amplitude,
        "turbulence_time_scale": params.turbulence_time_scale,
        "sim_seconds": seconds,
        "cg_iterations_per_step": float(solver.stats["cg_iterations"]) / steps,
    }
    if scene.obstacles:
        meta["contacts_per_step"] = float(solver.stats.get("contacts", 0)) / steps
    traj = Trajectory(mesh.cells, mesh.mesh_pos, mesh.node_type, world_pos, scene.dt, meta)
    times = [(warm + k) * scene.dt for k in range(int(num_steps))]
    traj = append_obstacles(traj, scene.obstacles, times)
    traj.validate(f"scene {scene.name} seed {seed}")
    return traj


_FLAG = SolverParams(
    turbulence_amplitude=0.5, turbulence_time_scale=1.0, wind_ramp_time=0.0, air_drag=0.02, damping_stiffness=1e-3
)

# From the pole side, above and slightly in front of the flag: the light grazes the cloth, so its folds shadow
# the cloth behind them (at ci 2-32% of the flag's pixels per frame, 13-16% on average; see README "Lighting").
FLAG_LIGHT = DirectionalLight(direction=(1.0, 0.35, -0.5), ambient=0.3, diffuse=0.7, shadow_map_size=512, shadow_bias=0.01)

BUILTIN_SCENES: tuple[SceneSpec, ...] = (
    SceneSpec("flag", "FLAGSIMPLE-like flag pinned on its pole, flying in one 8 m/s wind with light turbulence (the same for every trajectory)", FlagCloth(), _FLAG),
    SceneSpec(
        "flag-stiff", "the flag with membrane and bending 50x stiffer (stiff implicit system)", FlagCloth(), _FLAG.scaled(50.0, 50.0)
    ),
    SceneSpec(
        "flag-storm",
        "the flag in extreme gusty wind: large deformation and self-occlusion",
        FlagCloth(),
        dataclasses.replace(_FLAG, turbulence_amplitude=5.0, turbulence_time_scale=0.5),
        wind_speed_range=(14.0, 20.0),
        wind_direction_spread=0.8,
        init_speed_range=(0.0, 3.0),
    ),
    SceneSpec("flag-large-dt", "the flag integrated with a 0.05 s time step", FlagCloth(), _FLAG, dt=0.05),
    SceneSpec(
        "flag-lit",
        "the flag (same physics and trajectories) rendered under a grazing directional light with cast shadows",
        FlagCloth(),
        _FLAG,
        has_lighting=True,
        light=FLAG_LIGHT,
    ),
    SceneSpec(
        "cylinder",
        "an open tube of cloth hanging from its pinned top ring, swaying in wind (shape generalisation)",
        CylinderCloth(size=(0.3, 1.0), default_resolution=(32, 16)),
        dataclasses.replace(_FLAG, turbulence_amplitude=0.5),
        perturb_amplitude=0.005,
        wind_speed_range=(0.5, 2.0),
        wind_direction_spread=math.pi,
    ),
)


CONTACT_SUBSTEPS = 2
"""Solver sub-steps per frame of the collision scenes. At ci size (16 x 8 nodes, seeds 0-3, 81 frames) one step per
frame stretches the cloth by up to 3.3-37% (sheet) and 4.6-28% (ball); two keep it within 2.1-2.6% and 1.6-4.5% (README)."""

BALL_PATH = ObstaclePath(times=(0.0, 0.8, 1.73, 2.67), offsets=((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 1.5, 0.0), (0.0, 0.0, 0.0)))
"""The flag-ball's ball waits beside the flag until 0.8 s (during the 1 s warm-up), sweeps through the flag's plane by
1.73 s (inside the ci trajectory, frames 0-40 = 1.0-1.8 s) and back by 2.67 s (inside the stability task's 2x horizon)."""

BUILTIN_SCENES += (
    SceneSpec(
        "sphere-drop",
        "a free sheet dropped onto a sphere, draping over it (cloth-obstacle contact with friction, no wind)",
        SheetCloth(size=(1.2, 0.6), height=0.45),
        SolverParams(air_density=0.0, air_drag=0.0, damping_stiffness=1e-3, friction=0.5),
        substeps=CONTACT_SUBSTEPS,
        has_obstacles=True,
        has_wind=False,
        has_handles=False,
        rotation_range=(-math.pi, math.pi),
        init_speed_range=(0.0, 0.3),
        perturb_amplitude=0.02,
        warmup_time=0.0,
        obstacles=(Sphere(center=(0.0, 0.0, 0.0), radius=0.25),),
    ),
    SceneSpec(
        "flag-ball",
        "the flag hit by a ball that sweeps through it and back (a moving obstacle)",
        FlagCloth(),
        _FLAG,
        substeps=CONTACT_SUBSTEPS,
        has_obstacles=True,
        rotation_range=(-0.3, 0.3),
        obstacles=(Sphere(center=(1.4, -1.5, 0.5), radius=0.3, path=BALL_PATH),),
    ),
)


def get_scene(name: str) -> SceneSpec:
    """The built-in scene called `name` (ClodsError with a suggestion if unknown)."""
    for scene in BUILTIN_SCENES:
        if scene.name == name:
            return scene
    raise unknown_name("scene", name, [s.name for s in BUILTIN_SCENES])
