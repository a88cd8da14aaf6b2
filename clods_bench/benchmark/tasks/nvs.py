"""Dynamic-scene novel-view synthesis (NVS): fit a renderer on the training views, drive it by
the true meshes, score the held-out views with PSNR, SSIM and LPIPS (the paper's Table 3).

Protocol (appendix 'Dataset details'): "When assessing the performance of SMGS, we use
multi-view images from the first 200 time steps of 5 trajectories as both training and
testing data. SMGS generates Gaussian component representations of the cloth from the first
frame of each trajectory and then generates multi-view images for 200 time steps by changing
the mesh. The results from the 5 trajectories are averaged." Here: the first
`num_trajectories` trajectories of the dataset (paper: 5 of its training trajectories), the
first half of each (paper: 200 of 400 steps), fitted on the training cameras of frame 0 and
scored on the held-out cameras (`SplitSpec.test_views`: `num_views_test` spread evenly through the rig)
at every scored frame, frame 0 included. "3DGS, trained separately per frame" is a renderer
whose object has `per_frame = True`: it is fitted anew on every scored frame.

On a dataset without meshes (imported from video) only per-frame renderers run: each frame's proxy geometry is the
bounding box of the foreground's visual hull in the training views (`datasets.visual_hull`), in which 3DGS places
its Gaussians (`renderer_config.gs3d.init=random` fills the box; the default 'visible' samples its faces).

Resumable: the scores so far, the timings and the random-number state are written to `nvs_partial.pt` in the seed's
folder after every trajectory (after every frame for a per-frame renderer, whose fits take seconds to minutes each), so
an interrupted seed goes on where it stopped and ends with the numbers of an uninterrupted one.
"""

from __future__ import annotations

import random
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from rich.progress import Progress

from clods_bench import integrity
from clods_bench.benchmark.core import stage_digests
from clods_bench.benchmark.core.builders import as_images, build_renderer, split_spec
from clods_bench.benchmark.core.descriptors import TaskContext, TaskResult
from clods_bench.benchmark.outputs.films import film_cap, film_frame_picks, save_film, to_uint8
from clods_bench.benchmark.core.plugin_calls import plugin_call
from clods_bench.benchmark.outputs.media import write_image_grid
from clods_bench.benchmark.scoring.image_metrics import LpipsMetric, LpipsUnavailable, image_scores, load_lpips, lpips_for
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.visual_hull import box_mesh, hull_box
from clods_bench.errors import ClodsError
from clods_bench.typed_config import dataclass_from_dict

GRID_FILE = "nvs_grid.png"
FILM_FILE = "nvs_frames.npz"
PARTIAL_FILE = "nvs_partial.pt"
PARTIAL_FORMAT = 1
METRICS = ("psnr", "ssim", "lpips")


@dataclass(frozen=True)
class NvsConfig:
    """Options of the NVS task (`task_config.nvs.*`)."""

    num_trajectories: int = 5
    """Trajectories scored, the first ones of the dataset (paper: 5); fewer if the dataset has fewer."""
    num_frames: int | None = None
    """Frames per trajectory from frame 0 (default: the first half, num_steps // 2, as the paper's 200 of 400)."""
    frame_stride: int = 1
    """Score every k-th of those frames (1: all; larger keeps ci fast, above all for per-frame renderers)."""
    lpips: bool = True
    """Compute LPIPS when its weights are installed (never downloaded)."""
    grid_frames: int = 3
    """Frames of the first trajectory shown in the GT-vs-render image grid (0: no grid)."""

    def validate(self, num_steps: int) -> None:
        """Raise ClodsError naming the field when the options cannot work with `num_steps` frames."""
        if self.num_trajectories < 1:
            raise ClodsError(f"must be >= 1, got {self.num_trajectories}", where="task_config.nvs.num_trajectories")
        if self.num_frames is not None and not 1 <= self.num_frames <= num_steps:
            raise ClodsError(f"must be in [1, {num_steps}], got {self.num_frames}", where="task_config.nvs.num_frames")
        if self.frame_stride < 1:
            raise ClodsError(f"must be >= 1, got {self.frame_stride}", where="task_config.nvs.frame_stride")
        if self.grid_frames < 0:
            raise ClodsError(f"must be >= 0, got {self.grid_frames}", where="task_config.nvs.grid_frames")

    def frames(self, num_steps: int) -> list[int]:
        """The scored frame indices."""
        last = self.num_frames if self.num_frames is not None else max(1, num_steps // 2)
        return list(range(0, last, self.frame_stride))


def is_per_frame(renderer: Any) -> bool:
    """True for a renderer fitted independently on every frame (3DGS): its object sets `per_frame = True`."""
    return bool(getattr(renderer, "per_frame", False))


class _Frames:
    """The stored frames `times` x `views` of one trajectory, read once, indexed like the full (T, N, ...) array."""

    def __init__(self, lazy: Any, times: list[int], views: list[int]) -> None:
        self._data = lazy.read(times, views)
        self._t = {t: k for k, t in enumerate(times)}
        self._v = {v: k for k, v in enumerate(views)}

    def __getitem__(self, key: tuple[int, list[int]]) -> np.ndarray:
        t, views = key
        return self._data[self._t[t], [self._v[v] for v in views]]


def _to_float(frames: np.ndarray) -> np.ndarray:
    return np.asarray(frames, dtype=np.float32) / 255.0


def _rng_state() -> dict[str, Any]:
    """Python's, NumPy's and torch's global generators (CUDA's too once used), as tensors and plain values."""
    np_state, (version, internal, gauss) = np.random.get_state(), random.getstate()
    state = {
        "python": [version, list(internal), gauss],
        "numpy": [torch.from_numpy(np.asarray(np_state[1], dtype=np.int64)), int(np_state[2]), int(np_state[3]), float(np_state[4])],
        "torch": torch.get_rng_state(),
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def _set_rng_state(state: dict[str, Any]) -> None:
    version, internal, gauss = state["python"]
    random.setstate((version, tuple(internal), gauss))
    keys, pos, has_gauss, cached = state["numpy"]
    np.random.set_state(("MT19937", keys.numpy().astype(np.uint32), pos, has_gauss, cached))
    torch.set_rng_state(state["torch"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def _save_partial(path: Path, state: dict[str, Any]) -> None:
    """Write the resume state atomically (a kill mid-write leaves the previous one)."""
    integrity.save_torch({**state, "rng": _rng_state()}, path)


def _load_partial(path: Path, key: dict[str, Any]) -> dict[str, Any] | None:
    """The resume state written for this seed with the same trajectories, frames, views and LPIPS, else None (a file
    of an older format or another setting is not used, and is replaced by the next save)."""
    if not path.is_file():
        return None
    integrity.check_zip(path, "delete it to start this seed again")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a truncated or foreign file
        raise ClodsError(f"cannot read the NVS resume file: {type(exc).__name__}: {exc}", where=str(path),
                         hint="delete it to start this seed again") from None  # fmt: skip
    if not isinstance(state, dict) or state.get("format") != PARTIAL_FORMAT or state.get("key") != key:
        return None
    _set_rng_state(state["rng"])
    return state


def run_nvs(ctx: TaskContext) -> TaskResult:
    """One seed of NVS over the configured trajectories and frames; metrics are means over all scored images."""
    cfg = ctx.config
    if not cfg.data.render_frames:
        raise ClodsError("NVS needs rendered frames", where="data.render_frames", hint="set data.render_frames=true")
    opts: NvsConfig = dataclass_from_dict(NvsConfig, dict(cfg.task_config.get("nvs", {})), where="task_config.nvs", prefix="nvs.")
    opts.validate(cfg.data.num_steps)
    splits = split_spec(ctx)
    if splits.num_views_test < 1:
        raise ClodsError("NVS needs held-out cameras", where="data.num_views_test", hint="set it to 1 or more")
    store = DatasetStore.open(cfg.data.dataset_dir())
    proxy = not store.has_meshes
    if proxy and not is_per_frame(build_renderer(ctx)):
        store.require_meshes(f"renderer '{cfg.renderer}' (it anchors to the per-frame ground-truth meshes)")
    cams = store.cameras()
    train_cams = [cams[v] for v in splits.train_views]
    test_cams = [cams[v] for v in splits.test_views]
    train_idx, test_idx = list(splits.train_views), list(splits.test_views)
    traj_ids = list(range(min(opts.num_trajectories, splits.num_trajectories)))
    frames = opts.frames(cfg.data.num_steps)
    h, w = test_cams[0].height, test_cams[0].width
    lpips: LpipsMetric | LpipsUnavailable = load_lpips() if opts.lpips else LpipsUnavailable("LPIPS switched off (task_config.nvs.lpips=false)")
    lpips = lpips_for((h, w), lpips)
    metric = lpips if isinstance(lpips, LpipsMetric) else None
    torch.manual_seed(ctx.seed)

    grid_at = set(np.linspace(0, len(frames) - 1, min(opts.grid_frames, len(frames))).round().astype(int).tolist()) if opts.grid_frames else set()
    partial = ctx.work_dir / PARTIAL_FILE
    key = {"trajectories": traj_ids, "frames": frames, "train_views": train_idx, "test_views": test_idx,
           "lpips": metric.source if metric is not None else None}  # fmt: skip
    state = _load_partial(partial, key) or {
        "format": PARTIAL_FORMAT,
        "key": key,
        "next": [0, 0],  # (position in traj_ids, position in frames) of the next frame to score
        "scores": {k: [] for k in METRICS},  # per (trajectory, frame): (views,) arrays
        "traj_scores": {k: [] for k in METRICS},
        "per_traj": {},
        "fit_seconds": 0.0, "fits": 0, "render_seconds": 0.0, "lpips_seconds": 0.0, "fit_stats": [],
        "grid": ([], []),
        "per_frame": None,
    }  # fmt: skip
    state.setdefault("film", ([], []))  # trajectory 0's truth and renders at `film_at`, uint8 (a resume file from before has none)
    film_at = set(film_frame_picks(len(frames), film_cap(len(test_cams), h, w)))
    done_before = state["next"][0] * len(frames) + state["next"][1]
    lpips_before = state["lpips_seconds"] - (metric.seconds if metric is not None else 0.0)
    per_frame = state["per_frame"]
    with Progress(transient=True, disable=not cfg.progress) as bar:
        job = bar.add_task(f"nvs ({cfg.renderer})", total=len(traj_ids) * len(frames), completed=done_before)
        for pos in range(state["next"][0], len(traj_ids)):
            i = traj_ids[pos]
            traj = None if proxy else store.load_trajectory(i)
            video = _Frames(store.frames(i), sorted({0, *frames}), train_idx + test_idx)  # only the frames and views scored or fitted
            renderer = None
            for n in range(state["next"][1] if pos == state["next"][0] else 0, len(frames)):
                t = frames[n]
                if proxy:  # no meshes: the frame's visual-hull box from the training views
                    verts, cells, mesh_pos = box_mesh(*hull_box(video[t, train_idx], train_cams))
                else:
                    verts, cells, mesh_pos = traj.world_pos[t].astype(np.float32), traj.cells, traj.mesh_pos
                if renderer is None or per_frame:
                    renderer = build_renderer(ctx)
                    per_frame = is_per_frame(renderer)
                    fit_verts = verts if per_frame else traj.world_pos[0].astype(np.float32)
                    t0 = time.perf_counter()
                    with plugin_call("renderer", str(cfg.renderer), "fit", renderer):
                        stats = renderer.fit(fit_verts[None], cells, mesh_pos, _to_float(video[t if per_frame else 0, train_idx])[None], train_cams)
                    stage_digests.record("renderer fit", renderer)
                    state["fit_seconds"] += time.perf_counter() - t0
                    state["fits"] += 1
                    state["fit_stats"].append({k: float(v) for k, v in (stats or {}).items()})
                t0 = time.perf_counter()
                with torch.no_grad(), plugin_call("renderer", str(cfg.renderer), "render", renderer):
                    out = renderer.render(torch.from_numpy(verts), test_cams)
                state["render_seconds"] += time.perf_counter() - t0
                pred = as_images(out, (len(test_cams), h, w, 3), where=f"renderer '{cfg.renderer}', trajectory {i}, frame {t}")
                gt = _to_float(video[t, test_idx])
                for k, v in image_scores(pred, gt, metric).items():
                    state["scores"][k].append(torch.from_numpy(np.asarray(v)))
                    state["traj_scores"][k].append(torch.from_numpy(np.asarray(v)))
                if pos == 0 and n in film_at:
                    state["film"][0].append(torch.from_numpy(to_uint8(gt)))
                    state["film"][1].append(torch.from_numpy(to_uint8(pred)))
                if pos == 0 and n in grid_at:
                    state["grid"][0].append(torch.from_numpy(np.asarray(gt)))
                    state["grid"][1].append(torch.from_numpy(np.asarray(pred)))
                bar.advance(job)
                state["per_frame"] = per_frame
                state["lpips_seconds"] = lpips_before + (metric.seconds if metric is not None else 0.0)
                if n + 1 == len(frames):
                    state["per_traj"][str(i)] = {k: float(np.mean(torch.stack(v).numpy())) for k, v in state["traj_scores"].items() if v}
                    state["traj_scores"] = {k: [] for k in METRICS}
                    state["next"] = [pos + 1, 0]
                    _save_partial(partial, state)
                elif per_frame:
                    state["next"] = [pos, n + 1]
                    _save_partial(partial, state)

    scores = {k: [x.numpy() for x in v] for k, v in state["scores"].items()}
    per_traj, fits, fit_stats = state["per_traj"], state["fits"], state["fit_stats"]
    fit_seconds, render_seconds = state["fit_seconds"], state["render_seconds"]
    grid = ([x.numpy() for x in state["grid"][0]], [x.numpy() for x in state["grid"][1]])
    metrics = {k: float(np.mean(v)) for k, v in scores.items() if v}
    images = len(traj_ids) * len(frames) * len(test_cams)
    timings = {
        "fit_seconds": fit_seconds,
        "fit_seconds_per_fit": fit_seconds / max(fits, 1),
        "render_ms_per_frame": 1000.0 * render_seconds / max(images, 1),
        "render_seconds": render_seconds,
    }
    if metric is not None:
        timings["lpips_seconds"] = state["lpips_seconds"]
    for key in sorted({k for s in fit_stats for k in s}):
        timings[f"fit/{key}"] = float(np.mean([float(s[key]) for s in fit_stats if key in s]))
    shape = (len(traj_ids), len(frames), len(test_cams))  # scores are appended trajectory-major
    curves = {k: np.stack(v).reshape(shape).mean(axis=(0, 2)).tolist() for k, v in scores.items() if v}  # per scored frame
    grid_path = write_image_grid(ctx.work_dir / GRID_FILE, grid[0], grid[1]) if grid[0] else None
    if traj_ids and len(state["film"][0]) == len(film_at):  # complete (a seed resumed from an older file has no film)
        picks = [frames[n] for n in sorted(film_at)]
        film = [torch.stack(x).numpy().transpose(1, 0, 2, 3, 4) for x in state["film"]]  # (views, frames, H, W, 3)
        save_film(ctx.work_dir / FILM_FILE, film[0], film[1], test_idx, picks, f"traj {traj_ids[0]}",
                  f"{cfg.label or cfg.renderer}: held-out views of trajectory {traj_ids[0]}, seed {ctx.seed}")  # fmt: skip
    extra = {
        "trajectories": traj_ids,
        "frames": frames,
        "train_views": train_idx,
        "test_views": test_idx,
        "per_frame": bool(per_frame),
        "geometry": "visual-hull box (dataset without meshes)" if proxy else "ground-truth meshes",
        "fits": fits,
        "images": images,
        "per_trajectory": per_traj,
        "lpips_unavailable": lpips.reason if isinstance(lpips, LpipsUnavailable) else None,
        "lpips_source": metric.source if metric is not None else None,
        "lpips_files": [str(f) for f in metric.files] if metric is not None else [],
        "grid": str(grid_path) if grid_path else None,
    }
    result = TaskResult(metrics=metrics, timings=timings, curves=curves, extra=extra)
    partial.unlink(missing_ok=True)  # the runner writes the seed's result next; a kill in between costs a rerun only
    return result
