"""Frames rendered on demand from a dataset's stored meshes, for datasets generated with `data.frames=on_demand`.

At paper size the stored frames of one trajectory are 3.6 GB even compressed; its meshes and render setup 9.6 MB. A dataset
generated with `data.frames=on_demand` keeps only the meshes plus `render_setup.npz` (texture coordinates, the
texture exactly as generation used it, supersampling, background and light), and `RenderedFrames` renders what a
task reads with the same rasterizer and the same rounding as generation, so its pixels are byte-identical to the
stored frames (tested). Rendered images are kept in a bounded least-recently-used cache (`cache_mb`).
"""

from __future__ import annotations

import collections
import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from clods_bench.atomic import write_npz
from clods_bench.datasets.cameras import Camera
from clods_bench.datasets.frame_store import FrameArray, Index, indices
from clods_bench.datasets.obstacle_nodes import face_colors, render_uv
from clods_bench.datasets.rasterizer import DirectionalLight, RasterSettings, render_views
from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError

RENDER_SETUP = "render_setup.npz"
DEFAULT_CACHE_MB = 256.0


def write_render_setup(path: Path, uv: np.ndarray, texture: np.ndarray, settings: RasterSettings) -> None:
    """Save what `RenderedFrames` needs besides the meshes and cameras (atomically)."""
    light = json.dumps(asdict(settings.light) if settings.light is not None else None)  # every field, shadows included
    write_npz(path, uv=np.asarray(uv), texture=np.asarray(texture),  # as generation used them: no cast
              supersample=np.int64(settings.supersample), background=np.asarray(settings.background, np.float64),
              near=np.float64(settings.near), light=np.str_(light))  # fmt: skip


def read_render_setup(path: Path) -> tuple[np.ndarray, np.ndarray, RasterSettings]:
    """(uv, texture, raster settings) saved by `write_render_setup`; ClodsError naming the file if unreadable."""
    try:
        with np.load(path, allow_pickle=False) as z:
            fields = json.loads(str(z["light"]))
            light = None if fields is None else DirectionalLight(**{**fields, "direction": tuple(fields["direction"])})
            settings = RasterSettings(supersample=int(z["supersample"]), background=tuple(float(b) for b in z["background"]),
                                      near=float(z["near"]), light=light)  # fmt: skip
            return z["uv"], z["texture"], settings
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ClodsError(f"cannot read the on-demand render setup: {type(exc).__name__}: {exc}", where=str(path),
                         hint="regenerate the dataset (clods-bench data generate --force)") from None  # fmt: skip


class RenderedFrames(FrameArray):
    """Frames (T, N, H, W, 3) uint8 of one trajectory, rendered from its meshes when read (same interface as LazyFrames)."""

    def __init__(self, traj: Trajectory, cameras: list[Camera], setup: tuple[np.ndarray, np.ndarray, RasterSettings], where: Path,
                 cache_mb: float = DEFAULT_CACHE_MB) -> None:  # fmt: skip
        uv, texture, settings = setup
        if uv.shape[0] > traj.num_nodes:
            raise ClodsError(f"render setup has {uv.shape[0]} texture coordinates for {traj.num_nodes} nodes", where=str(where))
        self.path = Path(where)
        self._traj, self._cameras, self._texture, self._settings = traj, list(cameras), texture, settings
        self._uv = render_uv(uv, traj.num_nodes)
        self._colors = face_colors(traj.cells, traj.node_type)
        self.shape = (traj.num_steps, len(cameras), cameras[0].height, cameras[0].width, 3)
        self.dtype = np.dtype(np.uint8)
        self.capacity = max(1, int(cache_mb * 2**20 // int(np.prod(self.shape[2:]))))  # images the cache holds
        self._cache: collections.OrderedDict[tuple[int, int], np.ndarray] = collections.OrderedDict()
        self.images_rendered = 0  # views rendered by this object (what a selection cost; cache hits are free)

    def read(self, times: Index, views: Index) -> np.ndarray:
        """(len(times), len(views), H, W, 3): every selected frame of every selected camera, rendered as needed."""
        t_idx = indices(times, self.shape[0], "time", self.path)
        v_idx = indices(views, self.shape[1], "camera", self.path)
        out = np.empty((len(t_idx), len(v_idx), *self.shape[2:]), np.uint8)
        for a, t in enumerate(t_idx):
            t = int(t)
            fresh: dict[int, np.ndarray] = {}
            missing = [v for v in dict.fromkeys(int(v) for v in v_idx) if (t, v) not in self._cache]
            if missing:  # one rasterizer call for the views of this frame not in the cache
                imgs = render_views(self._traj.world_pos[t], self._traj.cells, self._uv, self._texture,
                                    [self._cameras[v] for v in missing], self._settings, self._colors)  # fmt: skip
                self.images_rendered += len(missing)
                fresh = dict(zip(missing, np.clip(np.rint(imgs * 255.0), 0, 255).astype(np.uint8)))
            for b, v in enumerate(int(v) for v in v_idx):
                if v in fresh:
                    out[a, b] = fresh[v]
                else:
                    self._cache.move_to_end((t, v))
                    out[a, b] = self._cache[(t, v)]
            for v, img in fresh.items():
                self._put((t, v), img)
        return out

    def verify(self) -> None:
        """Nothing is stored to check: the meshes were checked when loaded."""

    def _put(self, key: tuple[int, int], img: np.ndarray) -> None:
        self._cache[key] = img
        self._cache.move_to_end(key)
        while len(self._cache) > self.capacity:
            self._cache.popitem(last=False)
