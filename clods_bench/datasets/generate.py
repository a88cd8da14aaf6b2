"""Dataset generation: simulate each trajectory of a scene, render its multi-view frames, store it.

Resumable and atomic: each trajectory's files are written whole and only then listed in
the manifest, so an interrupted generation resumes at the first unlisted trajectory.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from clods_bench.benchmark.config import DataConfig
from clods_bench.datasets.cameras import Camera, camera_rig
from clods_bench.datasets.rasterizer import DirectionalLight, RasterSettings, render_views
from clods_bench.datasets.scenes import SceneSpec, simulate_scene
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.textures import load_texture, procedural_texture, save_texture
from clods_bench.datasets.types import ClothMesh, Trajectory
from clods_bench.errors import ClodsError

if TYPE_CHECKING:
    from clods_bench.benchmark.config import RunConfig
    from clods_bench.benchmark.registry import Registry

TEXTURE_FILE = "texture.png"
LIGHT = DirectionalLight(direction=(-0.3, 0.8, -0.5), ambient=0.3, diffuse=0.7)  # lights the hanging flag (normal ~ y) well


def resolution_of(d: DataConfig) -> tuple[int, int] | str:
    """The mesh resolution from the config: (nx, ny) or 'flagsimple'."""
    if isinstance(d.resolution, str):
        if d.resolution != "flagsimple":
            raise ClodsError(f"resolution must be [nx, ny] or 'flagsimple', got '{d.resolution}'", where="data.resolution")
        return d.resolution
    if len(d.resolution) != 2 or min(d.resolution) < 2:
        raise ClodsError(f"resolution must be two integers >= 2, got {d.resolution}", where="data.resolution")
    return int(d.resolution[0]), int(d.resolution[1])


def make_cameras(d: DataConfig, mesh: ClothMesh) -> list[Camera]:
    """The fixed camera rig of a dataset: `num_cameras` views around the cloth's rest centre."""
    if not 0 <= d.num_views_test < d.num_cameras:
        raise ClodsError(
            f"num_views_test={d.num_views_test} must be in [0, num_cameras={d.num_cameras})", where="data.num_views_test"
        )
    lo, hi = mesh.rest_pos.min(axis=0), mesh.rest_pos.max(axis=0)
    return camera_rig(d.num_cameras, 0.5 * (lo + hi), d.camera_radius, d.image_size, d.image_size, d.fov_deg)


def make_texture(d: DataConfig) -> np.ndarray:
    """The cloth texture: procedural (seeded) or loaded from an image file."""
    if d.texture == "procedural":
        return procedural_texture(512, seed=d.seed)
    return load_texture(Path(d.texture))


def render_trajectory(
    traj: Trajectory, uv: np.ndarray, texture: np.ndarray, cameras: list[Camera], settings: RasterSettings
) -> np.ndarray:
    """(T, N, H, W, 3) uint8 frames of every step from every camera."""
    frames = np.empty((traj.num_steps, len(cameras), cameras[0].height, cameras[0].width, 3), dtype=np.uint8)
    for t in range(traj.num_steps):
        imgs = render_views(traj.world_pos[t], traj.cells, uv, texture, cameras, settings)
        frames[t] = np.clip(np.rint(imgs * 255.0), 0, 255).astype(np.uint8)
    return frames


def scene_fingerprint(scene: SceneSpec) -> str:
    """Hash of everything a scene defines (physics, ranges, warm-up): a dataset made from an edited scene
    definition is reported as made with a different config instead of being reused."""
    fields: object = repr(scene)
    if dataclasses.is_dataclass(scene):
        fields = {k: v for k, v in dataclasses.asdict(scene).items() if k != "description"}  # prose changes no data
    return hashlib.sha256(json.dumps(fields, sort_keys=True, default=repr).encode()).hexdigest()[:16]


def generate(d: DataConfig, scene: SceneSpec, progress: bool = True, force: bool = False) -> DatasetStore:
    """Generate (or finish generating) the dataset described by `d` in `d.dataset_dir()`."""
    for name in ("num_train", "num_test"):
        if getattr(d, name) < (2 if name == "num_train" else 1):
            raise ClodsError(f"{name} is {getattr(d, name)}, too small", where=f"data.{name}")
    if not 2 <= d.interp_steps < d.num_steps - 1:
        raise ClodsError(
            f"interp_steps={d.interp_steps} must satisfy 2 <= interp_steps < num_steps - 1 = {d.num_steps - 1}",
            where="data.interp_steps",
        )
    root = d.dataset_dir()
    mesh = scene.build_mesh(resolution_of(d))
    cameras = make_cameras(d, mesh)
    if force and root.exists():
        import shutil

        shutil.rmtree(root)
    store = DatasetStore.create(root, d.scene, {**d.identity(), "scene_spec": scene_fingerprint(scene)}, cameras)
    texture = make_texture(d)
    if d.render_frames and not (root / TEXTURE_FILE).exists():
        save_texture(root / TEXTURE_FILE, texture)
    settings = RasterSettings(supersample=d.supersample, light=LIGHT if scene.has_lighting else None)
    uv = mesh.texture_uv()
    total = d.num_train + d.num_test
    todo = [i for i in range(total) if i not in store.completed_indices()]
    if not todo:
        return store
    columns = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn())
    with Progress(*columns, disable=not progress) as bar:
        job = bar.add_task(f"generating {d.scene} -> {root}", total=total, completed=total - len(todo))
        for i in todo:
            seed = d.seed + i
            traj = simulate_scene(scene, mesh, d.num_steps, seed)
            frames = render_trajectory(traj, uv, texture, cameras, settings) if d.render_frames else None
            store.write_trajectory(i, "train" if i < d.num_train else "test", seed, traj, frames)
            bar.advance(job)
    return store


def ensure_dataset(cfg: "RunConfig", registry: "Registry", progress: bool = True) -> Any:
    """Open the run's dataset, generating whatever part of it is missing."""
    scene = registry.get("scene", cfg.data.scene)
    return generate(cfg.data, scene, progress=progress)
