"""Ground-truth multi-view renderer: textured triangle meshes rasterised with a z-buffer.

This is the independent reference the Gaussian-splatting renderers are graded against, so
it shares no code with them. Conventions (see `cameras.py` for the camera ones):
- two-sided faces, no back-face culling; camera-z z-buffer; a sample exactly on an edge
  shared by two triangles is drawn exactly once (top-left rule, see `raster_kernels`);
- anti-aliasing: supersample s renders s*W x s*H samples (centres at ((C+0.5)/s, (R+0.5)/s)
  in image coordinates) and averages each s x s block, so pixel centres stay at (c+0.5, r+0.5);
- UVs are interpolated perspective-correctly; texel (row i, col j) of an (Ht,Wt,3) texture has
  its centre at uv = ((j+0.5)/Wt, (i+0.5)/Ht), i.e. v grows downwards along rows; bilinear
  lookup WRAPS around (UVs outside [0,1] tile the texture; suits the tiling procedural one);
- triangles crossing the near plane z = near are clipped against it (parts behind dropped);
- optional two-sided Lambertian light ambient + diffuse*|n . -d| with smooth (area-weighted,
  interpolated, renormalised) vertex normals, and optional cast shadows from a shadow map of the
  frame's triangles (a shadowed point gets only the ambient term; see `lighting`); output is
  clipped to [0, 1];
- optional per-face flat colours (`face_colors`, NaN rows: textured) for untextured surfaces such
  as obstacles; they are lit and shadowed like the cloth.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from clods_bench.datasets import raster_kernels as rk
from clods_bench.datasets.cameras import Camera
from clods_bench.datasets.lighting import DirectionalLight
from clods_bench.errors import ClodsError
from clods_bench.numerics.thread_limits import thread_cap

__all__ = ["DirectionalLight", "RasterSettings", "render", "render_views", "render_depth"]


@dataclass(frozen=True)
class RasterSettings:
    """Anti-aliasing factor, background colour, near plane and optional light."""

    supersample: int = 2
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    near: float = 1e-3
    light: DirectionalLight | None = None

    def validate(self) -> None:
        """Raise ClodsError naming the bad field."""
        if int(self.supersample) != self.supersample or not 1 <= self.supersample <= 16:
            raise ClodsError(f"supersample must be an integer in [1, 16], got {self.supersample}", where="settings.supersample")
        bg = np.asarray(self.background, dtype=np.float64)
        if bg.shape != (3,) or not np.isfinite(bg).all():
            raise ClodsError(f"background must be an RGB triple, got {self.background!r}", where="settings.background")
        if not (np.isfinite(self.near) and self.near > 0):
            raise ClodsError(f"near must be a positive number, got {self.near}", where="settings.near")
        if self.light is not None:
            if not isinstance(self.light, DirectionalLight):
                raise ClodsError(f"light is a {type(self.light).__name__}, expected a DirectionalLight or None", where="settings.light")
            self.light.validate(where="settings")


def _check_mesh(verts: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validated float64 (V,3) vertices and int64 (F,3) cells."""
    verts = np.asarray(verts)
    if verts.ndim != 2 or verts.shape[1] != 3:
        raise ClodsError(f"shape {tuple(verts.shape)}, expected (V, 3)", where="verts")
    verts = np.ascontiguousarray(verts, dtype=np.float64)
    bad = ~np.isfinite(verts)
    if bad.any():
        first = int(np.argwhere(bad)[0][0])
        raise ClodsError(f"{int(bad.any(axis=1).sum())} vertices are NaN/Inf, first at index {first}", where="verts")
    cells = np.asarray(cells)
    if cells.ndim != 2 or cells.shape[1] != 3:
        raise ClodsError(f"shape {tuple(cells.shape)}, expected (F, 3)", where="cells")
    if cells.size and not np.issubdtype(cells.dtype, np.integer):
        raise ClodsError(f"dtype {cells.dtype}, expected integers", where="cells")
    cells = np.ascontiguousarray(cells, dtype=np.int64)
    if cells.size and (cells.min() < 0 or cells.max() >= verts.shape[0]):
        raise ClodsError(f"indices in [{cells.min()}, {cells.max()}] but there are {verts.shape[0]} vertices", where="cells")
    return verts, cells


def _check_texturing(uv: np.ndarray, texture: np.ndarray, num_verts: int) -> tuple[np.ndarray, np.ndarray]:
    """Validated float64 (V,2) uv and float32 (Ht,Wt,3) texture."""
    uv = np.asarray(uv)
    if uv.shape != (num_verts, 2):
        raise ClodsError(f"shape {tuple(uv.shape)}, expected ({num_verts}, 2)", where="uv")
    uv = np.ascontiguousarray(uv, dtype=np.float64)
    if not np.isfinite(uv).all():
        raise ClodsError(f"NaN/Inf at vertex {int(np.argwhere(~np.isfinite(uv))[0][0])}", where="uv")
    texture = np.asarray(texture)
    if texture.ndim != 3 or texture.shape[2] != 3 or texture.shape[0] < 1 or texture.shape[1] < 1:
        raise ClodsError(f"shape {tuple(texture.shape)}, expected (Ht, Wt, 3)", where="texture")
    texture = np.ascontiguousarray(texture, dtype=np.float32)
    if not np.isfinite(texture).all():
        raise ClodsError("texture has NaN/Inf values", where="texture")
    return uv, texture


def _stack_cameras(cameras: list[Camera]) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """Validate cameras (all one image size) and stack K, R, t."""
    if len(cameras) == 0:
        raise ClodsError("need at least one camera", where="cameras")
    for i, cam in enumerate(cameras):
        cam.validate(where=f"cameras[{i}]")
        if (cam.width, cam.height) != (cameras[0].width, cameras[0].height):
            raise ClodsError(
                f"image size {cam.width}x{cam.height} differs from cameras[0]'s {cameras[0].width}x{cameras[0].height}",
                where=f"cameras[{i}]",
            )
    Ks = np.stack([np.asarray(c.K, dtype=np.float64) for c in cameras])
    Rs = np.stack([np.asarray(c.R, dtype=np.float64) for c in cameras])
    ts = np.stack([np.asarray(c.t, dtype=np.float64).reshape(3) for c in cameras])
    return Ks, Rs, ts, int(cameras[0].height), int(cameras[0].width)


def _check_face_colors(face_colors: np.ndarray | None, num_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """(F,) bool flat-coloured faces and (F,3) float64 colours; rows of NaN (or no array) are textured faces."""
    if face_colors is None:
        return np.zeros(num_faces, dtype=np.bool_), np.zeros((num_faces, 3))
    col = np.asarray(face_colors, dtype=np.float64)
    if col.shape != (num_faces, 3):
        raise ClodsError(f"shape {tuple(col.shape)}, expected ({num_faces}, 3)", where="face_colors")
    flat = ~np.isnan(col).any(axis=1)
    if not np.isfinite(col[flat]).all() or ((col[flat] < 0) | (col[flat] > 1)).any():
        raise ClodsError("colours must be in [0, 1] (NaN rows mark textured faces)", where="face_colors")
    return np.ascontiguousarray(flat), np.ascontiguousarray(np.where(flat[:, None], col, 0.0))


def render_views(
    verts: np.ndarray,
    cells: np.ndarray,
    uv: np.ndarray,
    texture: np.ndarray,
    cameras: list[Camera],
    settings: RasterSettings = RasterSettings(),
    face_colors: np.ndarray | None = None,
    threads: int | None = None,
) -> np.ndarray:
    """(N,H,W,3) float32 images in [0,1] of the textured mesh seen from every camera.

    `face_colors` (F,3) in [0,1] gives faces a flat colour instead of the texture; NaN rows stay textured.
    `threads` renders the views in that many threads (None: numba's thread count, under the workers' cap); each view
    is drawn by the same serial kernel, so the images do not depend on it."""
    settings.validate()
    verts, cells = _check_mesh(verts, cells)
    uv, texture = _check_texturing(uv, texture, verts.shape[0])
    flat, face_col = _check_face_colors(face_colors, cells.shape[0])
    Ks, Rs, ts, h, w = _stack_cameras(list(cameras))
    light = settings.light
    light_dir = light.unit_direction() if light is not None else np.zeros(3)
    ambient = float(light.ambient) if light is not None else 1.0
    diffuse = float(light.diffuse) if light is not None else 0.0
    shadow_size = int(light.shadow_map_size) if light is not None else 0
    basis = light.basis() if shadow_size > 0 else np.eye(3)
    out = np.empty((Ks.shape[0], h, w, 3), dtype=np.float32)
    bg = np.asarray(settings.background, dtype=np.float64)
    u0, v0, texel, smap = rk.frame_shadow(
        verts, cells, light is not None, shadow_size, float(light.shadow_bias) if light is not None else 0.0,
        float(light.shadow_slope_bias) if light is not None else 0.0, basis,
    )  # fmt: skip

    def draw(a: int, b: int) -> None:  # views a..b-1 into out[a:b] (the kernel releases the GIL; smap is only read)
        rk.render_views_kernel(
            verts, cells, uv, texture, flat, face_col, Ks[a:b], Rs[a:b], ts[a:b], h, w, int(settings.supersample),
            float(settings.near), light is not None, light_dir, ambient, diffuse, shadow_size, basis, u0, v0, texel, smap,
            bg, out[a:b],
        )  # fmt: skip

    n = Ks.shape[0]
    k = min(render_threads(threads), n)
    if k <= 1:
        draw(0, n)
        return out
    bounds = np.linspace(0, n, k + 1).round().astype(int)  # k contiguous runs of views, sizes differing by at most 1
    with ThreadPoolExecutor(k) as pool:
        for job in [pool.submit(draw, int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]:
            job.result()  # re-raises a kernel's error here
    return out


def render_threads(threads: int | None = None) -> int:
    """Threads `render_views` draws with: `threads`, or numba's thread count; never above `CLODS_BENCH_MAX_THREADS`.

    Each thread holds its own supersampled z-buffer (36 bytes a sample: 92 MB at 800 px with supersample 2)."""
    if threads is None:
        import numba

        threads = int(numba.get_num_threads())
    if int(threads) < 1:
        raise ClodsError(f"threads must be >= 1, got {threads}", where="render_views")
    cap = thread_cap()
    return int(threads) if cap is None else min(int(threads), cap)


def render(
    verts: np.ndarray,
    cells: np.ndarray,
    uv: np.ndarray,
    texture: np.ndarray,
    camera: Camera,
    settings: RasterSettings = RasterSettings(),
    face_colors: np.ndarray | None = None,
) -> np.ndarray:
    """(H,W,3) float32 image in [0,1] of the textured mesh seen from one camera (flat `face_colors` as in `render_views`)."""
    return render_views(verts, cells, uv, texture, [camera], settings, face_colors)[0]


def render_depth(verts: np.ndarray, cells: np.ndarray, camera: Camera, near: float = 1e-3) -> np.ndarray:
    """(H,W) float64 camera-z depth of the nearest surface at each pixel centre; inf on background."""
    RasterSettings(supersample=1, near=near).validate()
    verts, cells = _check_mesh(verts, cells)
    Ks, Rs, ts, h, w = _stack_cameras([camera])
    return rk.depth_kernel(verts, cells, Ks[0], Rs[0], ts[0], h, w, float(near)).reshape(h, w)
