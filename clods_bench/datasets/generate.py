"""Dataset generation: simulate each trajectory of a scene, render its multi-view frames, store it.

Resumable and atomic: each trajectory's files are written whole and only then listed in
the manifest, so an interrupted generation resumes at the first unlisted trajectory.
Trajectories are independent (trajectory i is drawn from seed `data.seed + i`), so they can be
generated in parallel through an executor (`--jobs N` processes or Ray tasks): each worker writes
its own trajectory's files and adds its manifest entry under the manifest's file lock; the bytes
written do not depend on the number of workers. Frames are rendered and stored a time chunk at
a time, so a paper-size trajectory (23 GB of raw frames) never has to fit in memory.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from clods_bench.atomic import file_lock
from clods_bench.datasets.cameras import Camera, camera_rig
from clods_bench.datasets.cloths import canonical
from clods_bench.datasets.data_checks import check_data, check_memory, check_resolution
from clods_bench.datasets.data_config import DataConfig
from clods_bench.datasets.obstacle_nodes import face_colors, render_uv
from clods_bench.datasets.rasterizer import DirectionalLight, RasterSettings, render_views
from clods_bench.datasets.scenes import SceneSpec, simulate_scene
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.textures import make_named_texture, save_texture
from clods_bench.datasets.types import ClothMesh, Trajectory
from clods_bench.errors import ClodsError
from clods_bench.typed_config import dataclass_from_dict

TEXTURE_FILE = "texture.png"
LIGHT = DirectionalLight(direction=(-0.3, 0.8, -0.5), ambient=0.3, diffuse=0.7)  # lights the hanging flag (normal ~ y) well


def scene_raster_settings(d: DataConfig, scene: SceneSpec) -> RasterSettings:
    """The ground-truth renderer's settings for `scene`: the config's supersampling, the scene's light (or LIGHT) if it has lighting."""
    light = (scene.light or LIGHT) if scene.has_lighting else None
    return RasterSettings(supersample=d.supersample, light=light)


def resolution_of(d: DataConfig) -> tuple[int, int] | str:
    """The mesh resolution from the config: (nx, ny) or 'flagsimple'."""
    check_resolution(d.resolution, "data.resolution")
    return d.resolution if isinstance(d.resolution, str) else (int(d.resolution[0]), int(d.resolution[1]))


def make_cameras(d: DataConfig, mesh: ClothMesh) -> list[Camera]:
    """The fixed camera rig of a dataset: `num_cameras` views around the cloth's rest centre."""
    if not 0 <= d.num_views_test < d.num_cameras:
        raise ClodsError(
            f"num_views_test={d.num_views_test} must be in [0, num_cameras={d.num_cameras})", where="data.num_views_test"
        )
    lo, hi = mesh.rest_pos.min(axis=0), mesh.rest_pos.max(axis=0)
    return camera_rig(d.num_cameras, 0.5 * (lo + hi), d.camera_radius, d.image_size, d.image_size, d.fov_deg)


def make_texture(d: DataConfig) -> np.ndarray:
    """The cloth texture `data.texture` names: a seeded named pattern or an image file's pixels."""
    return make_named_texture(d.texture, seed=d.seed)


def render_steps(
    traj: Trajectory, uv: np.ndarray, texture: np.ndarray, cameras: list[Camera], settings: RasterSettings,
    times: Sequence[int] | None = None,
) -> Iterator[np.ndarray]:  # fmt: skip
    """The (N, H, W, 3) uint8 images of each step (or of the steps `times`) from every camera, one step at a time.

    `uv` holds the cloth's texture coordinates; the trajectory's obstacle nodes (after the cloth's) are drawn in
    `OBSTACLE_COLOR`."""
    colors = face_colors(traj.cells, traj.node_type)
    uv = render_uv(uv, traj.num_nodes)
    for t in range(traj.num_steps) if times is None else times:
        imgs = render_views(traj.world_pos[t], traj.cells, uv, texture, cameras, settings, colors)
        yield np.clip(np.rint(imgs * 255.0), 0, 255).astype(np.uint8)


def render_trajectory(
    traj: Trajectory, uv: np.ndarray, texture: np.ndarray, cameras: list[Camera], settings: RasterSettings
) -> np.ndarray:
    """(T, N, H, W, 3) uint8 frames of every step from every camera."""
    frames = np.empty((traj.num_steps, len(cameras), cameras[0].height, cameras[0].width, 3), dtype=np.uint8)
    for t, step in enumerate(render_steps(traj, uv, texture, cameras, settings)):
        frames[t] = step
    return frames


def scene_fingerprint(scene: SceneSpec) -> str:
    """Hash of everything a scene defines (cloth, physics, ranges, warm-up): a dataset made from an edited scene
    definition is reported as made with a different config instead of being reused."""
    fields: object = repr(scene)
    if dataclasses.is_dataclass(scene):
        fields = scene_identity(scene)
    return hashlib.sha256(json.dumps(fields, sort_keys=True, default=repr).encode()).hexdigest()[:16]


def scene_identity(scene: SceneSpec) -> dict[str, Any]:
    """The scene's fields (not its prose) with its cloth's identity merged in at the top level.

    Flat, so the built-in flag and cylinder (whose cloths contribute kind, size and default_resolution)
    keep the fingerprints they had when those were scene fields: their datasets stay valid.
    """
    out: dict[str, Any] = {}
    for f in dataclasses.fields(scene):
        if f.name in ("description", "cloth"):  # prose changes no data; the cloth is merged below
            continue
        if f.name == "light" and scene.light is None:  # unset: scenes from before lights existed keep their fingerprints
            continue
        if f.name == "obstacles" and not scene.obstacles:  # likewise for scenes without obstacles
            continue
        value = getattr(scene, f.name)
        if f.name == "params" and not scene.obstacles:  # contact fields at their defaults change nothing without obstacles
            out[f.name] = value.identity()
        elif f.name == "obstacles":
            out[f.name] = canonical(value)
        else:
            out[f.name] = dataclasses.asdict(value) if dataclasses.is_dataclass(value) else value
    cloth = scene.cloth.identity()
    clash = sorted(set(cloth) & set(out))
    if clash:
        raise ClodsError(f"cloth fields {clash} have the names of scene fields", where=f"scene {scene.name}", hint="rename them")
    return {**out, **cloth}


@dataclass(frozen=True)
class TrajectoryJob:
    """One trajectory to generate: the data config (a dict, absolute root), the scene, the index."""

    data: dict[str, Any]
    scene: SceneSpec
    index: int


@dataclass
class _Setup:
    """What every trajectory of a dataset shares: mesh, cameras, texture, raster settings (built once per process)."""

    mesh: ClothMesh
    cameras: list[Camera]
    texture: np.ndarray
    settings: RasterSettings


_SETUPS: dict[str, _Setup] = {}


def _setup(d: DataConfig, scene: SceneSpec) -> _Setup:
    key = json.dumps([d.identity(), scene_fingerprint(scene)], sort_keys=True, default=repr)
    if key not in _SETUPS:
        mesh = scene.build_mesh(resolution_of(d))
        settings = scene_raster_settings(d, scene)
        _SETUPS.clear()  # one dataset at a time: keep memory flat
        _SETUPS[key] = _Setup(mesh, make_cameras(d, mesh), make_texture(d), settings)
    return _SETUPS[key]


def generate_trajectory(job: TrajectoryJob) -> int:
    """Simulate, render and store trajectory `job.index` (in whatever process runs it); return the index."""
    d = dataclass_from_dict(DataConfig, dict(job.data), where="data", prefix="data.")
    s = _setup(d, job.scene)
    i = job.index
    seed = d.seed + i
    traj = simulate_scene(job.scene, s.mesh, d.num_steps, seed)
    stored = d.render_frames and d.frames == "stored"  # on demand: the store renders them when read
    frames = render_steps(traj, s.mesh.texture_uv(), s.texture, s.cameras, s.settings) if stored else None
    DatasetStore.open(d.dataset_dir()).write_trajectory(i, "train" if i < d.num_train else "test", seed, traj, frames)
    return i


def generate(d: DataConfig, scene: SceneSpec, progress: bool = True, force: bool = False, executor: Any = None) -> DatasetStore:
    """Generate (or finish generating) the dataset described by `d` in `d.dataset_dir()`.

    `executor` (an object with `map(fn, items, describe, progress)`, see `benchmark.running.executors`) generates the
    missing trajectories in parallel; None generates them here, one after another.
    """
    if d.path:
        raise ClodsError("data.path names an existing dataset: there is nothing to generate", where=f"data.path={d.path}",
                         hint="leave data.path unset to generate the dataset the other data.* fields describe")  # fmt: skip
    check_data(d)  # before anything is simulated or any folder created
    check_memory(d, scene)
    d = dataclasses.replace(d, root=str(Path(d.root).resolve()))  # workers may start in another directory
    root = d.dataset_dir()
    with file_lock(root.parent / f".{root.name}.lock"):  # another generation of the same dataset: wait for it
        if force and root.exists():
            import shutil

            shutil.rmtree(root)
        setup = _setup(d, scene)
        store = DatasetStore.create(root, d.scene, {**d.identity(), "scene_spec": scene_fingerprint(scene)}, setup.cameras)
        if d.render_frames and not (root / TEXTURE_FILE).exists():
            save_texture(root / TEXTURE_FILE, setup.texture)
        if d.frames == "on_demand" and not store.frames_on_demand:
            store.write_render_setup(setup.mesh.texture_uv(), setup.texture, setup.settings)
        total = d.num_train + d.num_test
        jobs = [TrajectoryJob(dataclasses.asdict(d), scene, i) for i in range(total) if i not in store.completed_indices()]
        if not jobs:
            return store
        if executor is not None:
            executor.map(generate_trajectory, jobs, describe=lambda j: f"{d.scene} trajectory {j.index}", progress=progress)
            return DatasetStore.open(root)
        columns = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn())
        with Progress(*columns, disable=not progress) as bar:
            task = bar.add_task(f"generating {d.scene} -> {root}", total=total, completed=total - len(jobs))
            for job in jobs:
                generate_trajectory(job)
                bar.advance(task)
        return DatasetStore.open(root)


def open_existing(path: str | Path, num_trajectories: int) -> DatasetStore:
    """The dataset at `path` (`data.path`), checked to hold trajectories 0..num_trajectories-1 complete; never generated."""
    store = DatasetStore.open(Path(path))
    missing = sorted(set(range(num_trajectories)) - store.completed_indices())
    if missing:
        raise ClodsError(f"trajectories {missing} are missing or incomplete", where=str(Path(path) / "manifest.json"),
                         hint="re-import the dataset")  # fmt: skip
    return store
