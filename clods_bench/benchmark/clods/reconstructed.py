"""Stages 1-2 from a reconstructed initial mesh (`task_config.clods.initial_mesh=reconstructed`): nothing but video.

Each training video's frame 0 gives its own mesh (stage 0, `stage0.reconstruct_initial_mesh`; cached), so each
video has its own topology: its renderer is fitted on that mesh alone (stage 1) and stage 2 tracks it through the
video with every node free. The pinned edge is then found from that motion (the side of the sheet that moves least,
`detect_handles`) and marked HANDLE in the meshes stage 3 learns from, whose material coordinates are turned into
one convention (`orient_material_coords`). The extraction error against the truth is measured across topologies: each true
node is attached at frame 0 to the extracted mesh and carried by it (`cross_topology`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from typing import Any, Sequence

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from clods_bench import integrity
from clods_bench.atomic import file_lock
from clods_bench.benchmark.clods.cache import ExtractionCache
from clods_bench.benchmark.clods.config import ClodsConfig
from clods_bench.benchmark.clods.extract import extract_trajectory, stage2_stats
from clods_bench.benchmark.clods.stage0 import Stage0Config, reconstruct_initial_mesh
from clods_bench.benchmark.clods.stage1 import cache_root, fit_stage1_keyed
from clods_bench.benchmark.core.cache_keys import digest
from clods_bench.benchmark.core.descriptors import TaskContext
from clods_bench.benchmark.scoring.cross_topology import attach, attached_rmse
from clods_bench.datasets.cameras import Camera
from clods_bench.datasets.types import HANDLE, NORMAL, ClothMesh, Trajectory
from clods_bench.errors import ClodsError
from clods_bench.typed_config import dataclass_from_dict


def stage0_config(opts: ClodsConfig, seed: int) -> Stage0Config:
    """`task_config.clods.stage0` as a checked Stage0Config seeded by the extraction seed unless it sets one."""
    raw = dict(opts.stage0)
    cfg: Stage0Config = dataclass_from_dict(Stage0Config, raw, where="task_config.clods.stage0", prefix="clods.stage0.")
    if "seed" not in raw:
        cfg = dataclasses.replace(cfg, seed=int(seed))
    cfg.validate()
    return cfg


def stage0_mesh(ctx: TaskContext, opts: ClodsConfig, cfg: Stage0Config, index: int, images: np.ndarray, cameras: Sequence[Camera],
                num_nodes: int) -> tuple[ClothMesh, dict[str, float]]:  # fmt: skip
    """Stage 0 of trajectory `index` (cached next to the stage 1-2 caches, keyed by the images, cameras and options:
    the initial-mesh table and the rows learned from a reconstructed mesh share it); its statistics, the cost of a
    cached mesh as `stage0_cost_seconds`."""
    pixels = hashlib.sha256(np.ascontiguousarray(images).tobytes()).hexdigest()[:16]
    key = digest({"stage0": dataclasses.asdict(cfg), "images": pixels, "cameras": [c.to_dict() for c in cameras], "num_nodes": int(num_nodes)})
    path = cache_root(ctx, opts) / f"stage0-{key}.npz"
    with file_lock(path.with_suffix(".lock")):
        if path.is_file():
            integrity.check_zip(path, "delete it to reconstruct it again")
            try:
                with np.load(path) as z:
                    mesh = ClothMesh(z["cells"], z["mesh_pos"], z["node_type"], z["rest_pos"])
                    saved = json.loads(str(z["stats"])) if "stats" in z.files else {}
                    return mesh, {**saved, "stage0_seconds": 0.0, "stage0_cost_seconds": float(z["seconds"])}
            except (OSError, KeyError, ValueError) as exc:
                raise ClodsError(f"unreadable stage-0 cache file ({type(exc).__name__}: {exc})", where=str(path), hint="delete it") from None
        mesh, stats = reconstruct_initial_mesh(images, cameras, cfg, num_nodes)
        integrity.write_npz(path, cells=mesh.cells, mesh_pos=mesh.mesh_pos, node_type=mesh.node_type, rest_pos=mesh.rest_pos,
                  seconds=np.float64(stats["stage0_seconds"]), stats=np.array(json.dumps(stats, sort_keys=True)))  # fmt: skip
    return mesh, {**stats, "stage0_cost_seconds": stats["stage0_seconds"]}


SIDE_BAND = 1.5  # edge lengths: boundary nodes this close to an extreme of the material box make a candidate side
LINE_BAND = 0.5  # edge lengths: nodes of the chosen side this close to its fitted line are the handles


def detect_handles(frames: np.ndarray, mesh_pos: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Indices of the pinned edge, seen only through the extracted motion `frames` (T,V,3): a cloth pinned along one
    straight edge, as the flag and the banner are.

    Candidates are the four sides of the sheet's material-coordinate box (its longest extent and the one across):
    the boundary nodes within SIDE_BAND edge lengths of each extreme, so that a ragged or slightly turned side still
    counts. The side whose nodes move least on average is the pinned one; its handles are the rim's nodes within
    LINE_BAND edge lengths of the straight line through it (fitted twice: the neighbouring sides' corner nodes drop
    out, and the nodes of a slanted side that leave the box's band come back). A per-node
    motion threshold does not work here: at `ci` the extracted pole nodes drift 2-7 cm over 31 frames and nodes next
    to the pole as little (see the README)."""
    from clods_bench.datasets.types import boundary_nodes, edges_from_cells

    tracks = np.asarray(frames, np.float64)
    moved = np.linalg.norm(tracks - tracks[:1], axis=2).max(axis=0)
    if not float(np.median(moved)) > 0:
        raise ClodsError("the extracted cloth does not move: no pinned edge to find", where="task_config.clods.initial_mesh")
    mp = np.asarray(mesh_pos, np.float64)
    centred = mp - mp.mean(axis=0)
    uv = centred @ np.linalg.eigh(centred.T @ centred)[1]
    tri = np.asarray(cells)
    e = edges_from_cells(tri)
    spacing = float(np.median(np.linalg.norm(mp[e[:, 0]] - mp[e[:, 1]], axis=1)))
    boundary = boundary_nodes(tri)
    sides = []
    for a in (0, 1):
        band = SIDE_BAND * spacing
        for near in (uv[boundary, a] <= uv[:, a].min() + band, uv[boundary, a] >= uv[:, a].max() - band):
            if int(near.sum()) >= 2:
                sides.append(boundary[near])
    if not sides:
        raise ClodsError("the reconstructed sheet has no straight side to pin", where="task_config.clods.initial_mesh")
    side = min(sides, key=lambda nodes: float(moved[nodes].mean()))
    on_line = side
    for _ in range(2):  # fit the side's line, drop the neighbouring sides' corner nodes, refit on what is left
        origin = mp[on_line].mean(axis=0)
        pts = mp[on_line] - origin
        direction = np.linalg.eigh(pts.T @ pts)[1][:, -1]
        off = np.abs((mp[boundary] - origin) @ np.array([-direction[1], direction[0]]))
        found = boundary[off <= LINE_BAND * spacing]  # along the whole rim: a slanted side leaves the box's band
        if found.size < 2:
            return side
        on_line = found
    return on_line


def orient_material_coords(mesh_pos: np.ndarray, handles: np.ndarray, world0: np.ndarray) -> np.ndarray:
    """`mesh_pos` (V,2) turned and mirrored into one convention for every video (a flattening's orientation is
    arbitrary, and a learned simulator reads mesh-space edge directions): u along the sheet's longest extent,
    growing away from the handles, v growing upwards (world z at frame 0), the lowest corner at 0."""
    mp = np.asarray(mesh_pos, np.float64)
    centred = mp - mp.mean(axis=0)
    axes = np.linalg.eigh(centred.T @ centred)[1][:, ::-1]  # columns: longest extent first
    uv = centred @ axes
    if handles.size and uv[handles, 0].mean() > uv[:, 0].mean():
        uv[:, 0] = -uv[:, 0]
    z = np.asarray(world0, np.float64)[:, 2]
    if np.cov(uv[:, 1], z)[0, 1] < 0:
        uv[:, 1] = -uv[:, 1]
    return (uv - uv.min(axis=0)).astype(np.float32)


def extract_reconstructed(
    ctx: TaskContext, opts: ClodsConfig, train_ids: Sequence[int], gts: Sequence[Trajectory], videos: Sequence[Any],
    cams: Sequence[Camera], identity: dict[str, Any], seed: int, dt_meta: Sequence[tuple[float, dict[str, Any]]],
) -> tuple[list[Trajectory], dict[str, float], np.ndarray | None, str, list[Any]]:  # fmt: skip
    """(meshes with handles, statistics, per-frame attached E-GT (B, frames), cache key, the per-video stage-1
    renderers) of stages 0-2 on `videos` ((T,N,H,W,3) uint8 frame arrays, read frame by frame). `dt_meta` is each
    video's (dt, meta); `gts` its true meshes, or empty for a dataset without meshes: nothing here needs them but the
    E-GT (then None) and the default node count."""
    cfg = ctx.config
    s0 = stage0_config(opts, seed)
    if not gts and s0.num_nodes is None:
        raise ClodsError("the dataset has no meshes to take the node count of the reconstructed mesh from",
                         where="task_config.clods.stage0.num_nodes", hint="set it, e.g. task_config.clods.stage0.num_nodes=300")  # fmt: skip
    cache = ExtractionCache(cache_root(ctx, opts), digest({**identity, "stage0": dataclasses.asdict(s0)}), identity)
    stats: dict[str, float] = {"stage0_seconds": 0.0, "stage0_cost_seconds": 0.0, "stage1_seconds": 0.0, "stage1_cost_seconds": 0.0}
    meshes, egt, extracted, renderers, cached = [], [], [], [], 0
    t0 = time.perf_counter()
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TextColumn("{task.fields[info]}"))
    with Progress(*columns, transient=True, disable=not cfg.progress) as bar:
        for k, (video, i, (dt, meta)) in enumerate(zip(videos, train_ids, dt_meta)):
            g = gts[k] if gts else None
            mesh, st0 = stage0_mesh(ctx, opts, s0, i, np.asarray(video[0]), cams, s0.num_nodes or g.num_nodes)
            renderer, st1, _ = fit_stage1_keyed(ctx, mesh.rest_pos[None].astype(np.float32), mesh.cells, mesh.mesh_pos, np.asarray(video[0])[None], cams)
            renderers.append(renderer)
            for key in ("stage0_seconds", "stage0_cost_seconds"):
                stats[key] += st0[key]
            for key in ("stage1_seconds", "stage1_cost_seconds"):
                stats[key] += float(st1.get(key, 0.0)) if np.isfinite(st1.get(key, 0.0)) else 0.0
            with file_lock(cache.path(i).with_suffix(".lock")):
                cached += cache.load(i) is not None
                ext = extract_trajectory(renderer, cams, video, mesh.rest_pos, mesh.cells, mesh.node_type, opts, cache, i, bar)
            extracted.append(ext)
            node_type = np.full(mesh.num_nodes, NORMAL, np.int32)
            handles = detect_handles(ext.world_pos, mesh.mesh_pos, mesh.cells)
            node_type[handles] = HANDLE
            mesh_pos = orient_material_coords(mesh.mesh_pos, handles, ext.world_pos[0])
            meta = {**meta, "source": "clods stages 0-2 (reconstructed initial mesh)", "cache": cache.key}
            meshes.append(Trajectory(mesh.cells, mesh_pos, node_type, ext.world_pos.astype(np.float32), float(dt), meta))
            if g is not None:
                att = attach(np.asarray(g.world_pos[0], np.float64), ext.world_pos[0].astype(np.float64), mesh.cells)
                egt.append(attached_rmse(ext.world_pos, mesh.cells, att, g.world_pos))
    curves = np.stack(egt) if egt else None
    stats.update(stage2_stats(extracted, curves, cached))
    stats.update({
        "stage2_wall_seconds": time.perf_counter() - t0,
        "stage0_nodes": float(np.mean([m.num_nodes for m in meshes])),
        "stage0_handles": float(np.mean([int(np.sum(m.node_type == HANDLE)) for m in meshes])),
    })  # fmt: skip
    stats["stage1_cost_seconds"] += stats["stage0_cost_seconds"]  # stage 0 is part of the renderer's set-up cost
    # what stage 3 learns from: the cached motion and the handles found in it (a change of `detect_handles` is a new fit)
    handles = [np.flatnonzero(m.node_type == HANDLE).tolist() for m in meshes]
    return meshes, stats, curves, f"{cache.key}-{digest(handles)[:8]}", renderers
