"""Per-frame 3D Gaussian splatting (Kerbl et al. 2023): free Gaussians fitted to one frame at a time.

The upper-bound row of the NVS table ("3DGS, trained separately per frame"). Free means, rotations
(quaternions), log scales, opacity logits and colours, no densification (a fixed budget of
`num_gaussians`), initialised on the frame's visible surface (points sampled on the mesh faces that
some training camera sees, flat and oriented like the face: 'visible'), on every face ('surface') or
uniformly in the mesh's bounding box ('random').

Per-frame API: `fit(verts (B,V,3), ..., images (B,N,H,W,3), cameras)` fits B independent
representations, one per frame, and caches each under its mesh; `render(verts, cameras)` renders
the representation fitted on the frame whose mesh is `verts` (matched to within `match_tol` times
the mesh size) and raises ClodsError for a mesh it was never fitted on. Repeated `fit` calls add
frames to the cache (a frame fitted again is replaced). `per_frame = True` tells the NVS task to
call `fit` on every scored frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import torch
from torch import Tensor

from clods_bench.datasets.cameras import Camera
from clods_bench.errors import ClodsError
from clods_bench.plugins.renderers.checks import check_fit_inputs, check_render_cameras, check_render_verts
from clods_bench.plugins.renderers.device import check_device_config, fit_device, leaf_to
from clods_bench.plugins.renderers.fitting import ParamGroup, check_positive, fit_adam
from clods_bench.plugins.renderers.games import Backend, colors_of, init_colors, logit
from clods_bench.plugins.renderers.losses import render_loss
from clods_bench.plugins.renderers.mesh_gaussians import face_frames, mean_face_size
from clods_bench.splatting import render_gaussians
from clods_bench.typed_config import check_count


@dataclass(frozen=True)
class Gs3dConfig:
    """Options of per-frame 3DGS (`renderer_config.gs3d.*`); defaults fit one ci frame in a few seconds."""

    num_gaussians: int = 2000
    """Gaussians per frame (fixed: no densification or pruning)."""
    init: Literal["visible", "surface", "random"] = "visible"
    """'visible': on the frame's mesh faces seen by a training camera (area-weighted), flat and face-aligned;
    'surface': the same on every face; 'random': uniform in the mesh's bounding box."""
    iterations: int = 250
    """Adam steps per frame (each renders every training camera)."""
    sh_degree: int = 0
    """Colour model: 0 = RGB, 1-3 = view-dependent SH."""
    init_opacity: float = 0.1
    """Initial opacity (3DGS: 0.1)."""
    box_padding: float = 0.1
    """'random' init: the bounding box grows by this fraction of its largest side on every side."""
    lr_means: float = 1.6e-4
    """Adam learning rate of the centres, in units of the mesh's bounding-box diagonal (3DGS: 1.6e-4 of the scene extent).
    Larger rates fit the training views better and the held-out ones worse: at ci (4 training cameras, 64 px)
    0.002 gave 17.3 dB held-out PSNR, 1.6e-4 19.2 dB, frozen centres and rotations 21.9 dB."""
    lr_quats: float = 0.001
    """Adam learning rate of the quaternions (3DGS: 0.001)."""
    lr_scale: float = 0.005
    """Adam learning rate of the log scales (3DGS: 0.005)."""
    lr_opacity: float = 0.05
    """Adam learning rate of the opacity logits (3DGS: 0.05)."""
    lr_color: float = 0.05
    """Adam learning rate of the colours (SH degree >= 1 terms at 1/20 of it)."""
    lr_final_factor: float = 0.1
    """Every learning rate decays exponentially to this fraction of itself over a fit."""
    lambda_dssim: float = 0.2
    """Weight of D-SSIM = 1 - SSIM in the loss (paper eq. 5)."""
    match_tol: float = 1e-4
    """`render` uses the cached frame whose vertices differ by at most this times the mesh's bounding-box diagonal."""
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Colour behind the Gaussians (the ground truth's is white)."""
    backend: Backend = "cpu"
    """Splatting backend: 'cpu' (numba), 'reference' (plain torch) or 'gsplat' (CUDA)."""
    device: str = "cpu"
    """Where parameters, targets and loss live during fit: 'cpu', or 'cuda[:N]' with backend gsplat."""

    def validate(self, where: str) -> None:
        """Raise ClodsError naming the first field that is out of range."""
        if self.num_gaussians < 1:
            raise ClodsError(f"must be >= 1, got {self.num_gaussians}", where=f"{where}.num_gaussians")
        if self.init not in ("visible", "surface", "random"):
            raise ClodsError(f"unknown init '{self.init}'; known: visible, surface, random", where=f"{where}.init")
        check_count(self.iterations, f"{where}.iterations", minimum=0)
        if not 0 <= self.sh_degree <= 3:
            raise ClodsError(f"must be in 0..3, got {self.sh_degree}", where=f"{where}.sh_degree")
        if not 0.0 < self.init_opacity < 1.0:
            raise ClodsError(f"must be in (0, 1), got {self.init_opacity}", where=f"{where}.init_opacity")
        if not 0.0 <= self.lambda_dssim <= 1.0:
            raise ClodsError(f"must be in [0, 1], got {self.lambda_dssim}", where=f"{where}.lambda_dssim")
        for name in ("lr_final_factor", "match_tol"):
            check_positive(getattr(self, name), f"{where}.{name}")
        for name in ("box_padding", "lr_means", "lr_quats", "lr_scale", "lr_opacity", "lr_color"):
            check_positive(getattr(self, name), f"{where}.{name}", allow_zero=True)
        if len(self.background) != 3 or not all(math.isfinite(b) for b in self.background):
            raise ClodsError(f"must be 3 finite numbers, got {self.background!r}", where=f"{where}.background")
        if self.backend not in ("cpu", "reference", "gsplat"):
            raise ClodsError(f"unknown backend '{self.backend}'; known: cpu, reference, gsplat", where=f"{where}.backend")
        check_device_config(self.device, self.backend, where)


def rotmat_to_quat(R: Tensor) -> Tensor:
    """(...,4) unit quaternions (w,x,y,z) of proper rotations (...,3,3) (Shepperd's method: stable for all angles)."""
    m = R.reshape(-1, 3, 3)
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    cands = torch.stack([  # 4 * (w,x,y,z) * (the chosen large component), one row per choice
        torch.stack([1 + tr, m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], -1),
        torch.stack([m[:, 2, 1] - m[:, 1, 2], 1 + 2 * m[:, 0, 0] - tr, m[:, 0, 1] + m[:, 1, 0], m[:, 0, 2] + m[:, 2, 0]], -1),
        torch.stack([m[:, 0, 2] - m[:, 2, 0], m[:, 0, 1] + m[:, 1, 0], 1 + 2 * m[:, 1, 1] - tr, m[:, 1, 2] + m[:, 2, 1]], -1),
        torch.stack([m[:, 1, 0] - m[:, 0, 1], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1], 1 + 2 * m[:, 2, 2] - tr], -1),
    ], dim=1)  # fmt: skip
    best = torch.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], -1).argmax(-1)
    q = cands[torch.arange(m.shape[0]), best]
    q = q / q.norm(dim=-1, keepdim=True)
    return (q * torch.where(q[:, :1] < 0, -1.0, 1.0)).reshape(R.shape[:-2] + (4,))


def _barycentric_grid(level: int) -> np.ndarray:
    """(P,3) barycentric points of a triangle subdivided `level` times per edge (vertices, edge and inner points)."""
    return np.array([(i, j, level - i - j) for i in range(level + 1) for j in range(level + 1 - i)], np.float64) / level


def visible_faces(verts: np.ndarray, cells: np.ndarray, cameras: Sequence[Camera], level: int = 4) -> np.ndarray:
    """(F,) bool: faces of which some point is seen by some camera (a point z-buffer, not a rasterizer).

    Every face is sampled on a barycentric grid; each camera keeps, per pixel, the nearest sample depth
    (min-filtered over 3x3 pixels so that gaps between samples do not let hidden points through); a
    sample is visible when it is in front of the camera, inside the image and within three pixel
    footprints of that nearest depth.
    """
    from scipy.ndimage import minimum_filter

    grid = _barycentric_grid(level)
    pts = np.einsum("pc,fcx->fpx", grid, verts[cells]).reshape(-1, 3)
    seen = np.zeros(len(pts), bool)
    for cam in cameras:
        uv, z = cam.project(pts)
        with np.errstate(invalid="ignore"):
            col, row = np.floor(uv[:, 0]), np.floor(uv[:, 1])
            inside = (z > 1e-6) & (col >= 0) & (col < cam.width) & (row >= 0) & (row < cam.height)
        if not inside.any():
            continue
        pix = row[inside].astype(np.int64) * cam.width + col[inside].astype(np.int64)
        zbuf = np.full(cam.width * cam.height, np.inf)
        np.minimum.at(zbuf, pix, z[inside])
        near = minimum_filter(zbuf.reshape(cam.height, cam.width), size=3, mode="constant", cval=np.inf).reshape(-1)
        footprint = z[inside] / float(cam.K[0, 0])  # one pixel's width in world units at that depth
        idx = np.flatnonzero(inside)
        seen[idx] |= z[inside] <= near[pix] + 3.0 * footprint
    return seen.reshape(len(cells), len(grid)).any(axis=1)


def surface_init(
    verts: np.ndarray, cells: np.ndarray, n: int, gen: torch.Generator, faces: np.ndarray | None = None
) -> tuple[Tensor, Tensor, Tensor]:
    """Means, quaternions and log scales of n flat Gaussians sampled area-weighted on the faces (only those where
    `faces` is True, when given and not empty), aligned with them."""
    tri = torch.from_numpy(verts[cells])  # (F,3,3) float64
    area = 0.5 * torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], dim=-1).norm(dim=-1)
    if faces is not None and bool(np.any(faces)):
        area = area * torch.from_numpy(np.asarray(faces, bool))
    weights = area if float(area.sum()) > 0 else torch.ones_like(area)
    face = torch.multinomial(weights, n, replacement=True, generator=gen)
    r1, r2 = torch.rand(n, generator=gen, dtype=torch.float64), torch.rand(n, generator=gen, dtype=torch.float64)
    s = r1.sqrt()  # uniform in the triangle: (1 - sqrt(r1), sqrt(r1)(1 - r2), sqrt(r1) r2)
    bary = torch.stack([1 - s, s * (1 - r2), s * r2], -1)
    means = torch.einsum("nc,ncx->nx", bary, tri[face])
    rot, _ = face_frames(tri[face], 0.0)
    flip = torch.linalg.det(rot) < 0  # make the frame right-handed: flipping an axis leaves the covariance alone
    rot = torch.where(flip[:, None, None], rot * torch.tensor([1.0, 1.0, -1.0]), rot)
    degenerate = ~torch.isfinite(rot).all(-1).all(-1) | (torch.linalg.det(rot) < 0.5)
    rot[degenerate] = torch.eye(3, dtype=rot.dtype)
    spacing = math.sqrt(max(float(area.sum()), 1e-12) / n)
    scales = torch.tensor([0.1 * spacing, 0.5 * spacing, 0.5 * spacing]).log().expand(n, 3)
    return means.float(), rotmat_to_quat(rot).float(), scales.float().clone()


def random_init(verts: np.ndarray, n: int, padding: float, gen: torch.Generator) -> tuple[Tensor, Tensor, Tensor]:
    """Means uniform in the padded bounding box of `verts`, identity rotations, isotropic scales from the box volume."""
    lo, hi = verts.min(0), verts.max(0)
    pad = padding * float((hi - lo).max())
    lo, hi = torch.from_numpy(lo - pad), torch.from_numpy(hi + pad)
    means = lo + (hi - lo) * torch.rand(n, 3, generator=gen, dtype=torch.float64)
    side = (float(torch.prod((hi - lo).clamp(min=1e-3))) / n) ** (1.0 / 3.0)
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(n, 4).clone()
    return means.float(), quats, torch.full((n, 3), math.log(0.5 * side))


class Gs3dRenderer:
    """Free 3D Gaussians fitted independently on each frame; renders the frame whose mesh it is given."""

    name = "gs3d"
    per_frame = True  # fitted anew on every scored frame (the NVS task checks this flag)

    def __init__(self, config: Gs3dConfig | None = None, seed: int = 0, progress: bool = False) -> None:
        """Check the config; the cache of fitted frames starts empty."""
        self.config = config or Gs3dConfig()
        self.config.validate(f"renderer_config.{self.name}")
        self.seed = seed
        self.progress = progress
        self.frames: list[tuple[np.ndarray, dict[str, Tensor]]] = []  # (verts (V,3), fitted parameters)

    def fit(self, verts: Any, cells: Any, mesh_pos: Any, images: Any, cameras: Sequence[Camera]) -> dict[str, float]:
        """Fit one representation per frame b on images[b] (initialised from verts[b]); returns mean statistics."""
        data = check_fit_inputs(verts, cells, mesh_pos, images, cameras, f"renderer '{self.name}'.fit")
        cfg, cams = self.config, list(data.cameras)
        device = fit_device(cfg.device, f"renderer_config.{self.name}")
        stats: list[dict[str, float]] = []
        for b in range(data.verts.shape[0]):
            gen = torch.Generator().manual_seed(self.seed * 100003 + len(self.frames))
            v = data.verts[b]
            if cfg.init in ("visible", "surface"):
                faces = visible_faces(v, data.cells, cams) if cfg.init == "visible" else None
                means, quats, log_scales = surface_init(v, data.cells, cfg.num_gaussians, gen, faces)
            else:
                means, quats, log_scales = random_init(v, cfg.num_gaussians, cfg.box_padding, gen)
            p = {
                "means": means.requires_grad_(),
                "quats": quats.requires_grad_(),
                "log_scales": log_scales.requires_grad_(),
                "opacity_logit": torch.full((cfg.num_gaussians,), logit(cfg.init_opacity)).requires_grad_(),
                **init_colors(cfg.num_gaussians, cfg.sh_degree),
            }  # drawn on the CPU: the same initial values on every device
            p = {k: leaf_to(t, device) for k, t in p.items()}
            target = torch.from_numpy(data.images[b]).to(device)
            extent = float(np.linalg.norm(v.max(0) - v.min(0))) or mean_face_size(v, data.cells)
            groups = [
                ParamGroup("means", [p["means"]], cfg.lr_means * extent),
                ParamGroup("quats", [p["quats"]], cfg.lr_quats),
                ParamGroup("log_scales", [p["log_scales"]], cfg.lr_scale),
                ParamGroup("opacity", [p["opacity_logit"]], cfg.lr_opacity),
                ParamGroup("color", [p["color"]], cfg.lr_color),
            ]
            if "sh_rest" in p:
                groups.append(ParamGroup("sh_rest", [p["sh_rest"]], cfg.lr_color / 20.0))

            def loss_at(it: int, p: dict[str, Tensor] = p, target: Tensor = target) -> Tensor:
                return render_loss(self._render(p, cams), target, cfg.lambda_dssim)

            stats.append(fit_adam(groups, loss_at, cfg.iterations, cfg.lr_final_factor, self.progress, f"fit {self.name} frame {b}"))
            for t in p.values():
                t.requires_grad_(False)
            self._store(v, p)
        out = {k: float(np.mean([s[k] for s in stats])) for k in stats[0]}
        out["fit_seconds"] = float(sum(s["fit_seconds"] for s in stats))
        out["frames"] = float(len(stats))
        out["num_gaussians"] = float(cfg.num_gaussians)
        return out

    def _store(self, verts: np.ndarray, params: dict[str, Tensor]) -> None:
        """Cache a fitted frame, replacing an earlier fit of the same mesh."""
        i = self._lookup(verts)
        if i is None:
            self.frames.append((verts.copy(), params))
        else:
            self.frames[i] = (verts.copy(), params)

    def _lookup(self, verts: np.ndarray) -> int | None:
        """Index of the cached frame whose mesh matches `verts` (closest within tolerance), else None."""
        best, best_err = None, math.inf
        for i, (v, _) in enumerate(self.frames):
            if v.shape != verts.shape:
                continue
            tol = self.config.match_tol * max(float(np.linalg.norm(v.max(0) - v.min(0))), 1e-9)
            err = float(np.abs(v - verts).max())
            if err <= tol and err < best_err:
                best, best_err = i, err
        return best

    def _render(self, p: dict[str, Tensor], cameras: Sequence[Camera]) -> Tensor:
        """(N,H,W,3) images of one parameter set."""
        cfg = self.config
        return render_gaussians(
            p["means"], None, torch.sigmoid(p["opacity_logit"]), colors_of(p, p["means"].dtype), cameras,
            quats=p["quats"], scales=torch.exp(p["log_scales"]),
            sh_degree=cfg.sh_degree if cfg.sh_degree > 0 else None, background=cfg.background, backend=cfg.backend,
        ).rgb  # fmt: skip

    def render(self, verts: Any, cameras: Sequence[Camera]) -> Tensor:
        """(N,H,W,3) images of the representation fitted on the frame whose mesh is `verts` (not differentiable in verts)."""
        where = f"renderer '{self.name}'.render"
        if not self.frames:
            raise ClodsError("render called before fit", where=where, hint="gs3d is per-frame: call fit on this frame first")
        v = check_render_verts(verts, self.frames[0][0].shape[0], where)
        cams = check_render_cameras(cameras, where)
        i = self._lookup(v.detach().cpu().numpy().astype(np.float64))
        if i is None:
            raise ClodsError(f"no representation fitted on this mesh ({len(self.frames)} frames cached)", where=where,
                             hint="gs3d is per-frame: call fit with this frame's mesh and images first")  # fmt: skip
        return self._render(self.frames[i][1], cams).to(v.device)
