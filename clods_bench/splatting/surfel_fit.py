"""Fit 2DGS surfels to the multi-view images of frame 0 and render the depth maps TSDF fusion needs.

Why: stage 0 of CloDS (paper appendix, "Initial mesh extraction ... using 2D Gaussian Splatting"): the
initial cloth mesh comes from TSDF fusion of the fitted surfels' median-depth maps (done elsewhere).
Kept simple: one surfel per given point, Adam on L1 (+ D-SSIM) + the 2DGS normal-consistency and
depth-distortion regularisers (`surfel_losses`), no densification, transparent surfels pruned at
the end. Parameterisation: opacity = sigmoid(logit), scales = exp(log-scale), colours = sigmoid(logit),
quaternions (w, x, y, z) raw (the renderer normalises them). Runs in float64 on the CPU, or with
backend 'gsplat' on the CUDA GPU (parameters and images there; gsplat composites in float32).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import torch
from torch import Tensor

from clods_bench.datasets.cameras import Camera
from clods_bench.errors import ClodsError
from clods_bench.splatting.checks import check_cameras
from clods_bench.splatting.surfel_losses import surfel_losses
from clods_bench.splatting.surfels import SurfelBackend, render_surfels

F64 = torch.float64


def _logit(x: Tensor) -> Tensor:
    x = x.clamp(1e-4, 1 - 1e-4)
    return torch.log(x / (1 - x))


def ssim(a: Tensor, b: Tensor, window: int = 11, sigma: float = 1.5) -> Tensor:
    """Mean SSIM of (N,H,W,3) images with a Gaussian window (3DGS `ssim`, zero padding)."""
    x = torch.arange(window, dtype=a.dtype, device=a.device) - window // 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    g = g / g.sum()
    k = (g[:, None] * g[None, :]).expand(3, 1, window, window).contiguous()
    a, b = a.permute(0, 3, 1, 2), b.permute(0, 3, 1, 2)

    def blur(t: Tensor) -> Tensor:
        return torch.nn.functional.conv2d(t, k, padding=window // 2, groups=3)

    mu_a, mu_b = blur(a), blur(b)
    s_aa, s_bb, s_ab = blur(a * a) - mu_a**2, blur(b * b) - mu_b**2, blur(a * b) - mu_a * mu_b
    c1, c2 = 0.01**2, 0.03**2
    m = ((2 * mu_a * mu_b + c1) * (2 * s_ab + c2)) / ((mu_a**2 + mu_b**2 + c1) * (s_aa + s_bb + c2))
    return m.mean()


def init_surfels(points: Tensor, colors: Tensor | None, seed: int = 0, init_opacity: float = 0.1) -> dict[str, Tensor]:
    """Raw (optimised) parameters of one surfel per point: scale = mean distance to the 3 nearest points
    (3DGS / 2DGS init), uniformly random rotation, opacity `init_opacity`, colour given or grey."""
    from scipy.spatial import cKDTree

    pts = points.detach().to(F64)
    N = pts.shape[0]
    g = torch.Generator().manual_seed(seed)
    k = min(4, N)
    d, _ = cKDTree(pts.numpy()).query(pts.numpy(), k=k)
    nn = np.asarray(d, float).reshape(N, -1)[:, 1:] if k > 1 else np.ones((N, 1))
    scale = torch.from_numpy(np.maximum(nn.mean(axis=1), 1e-6))
    col = torch.full((N, 3), 0.5, dtype=F64) if colors is None else colors.detach().to(F64)
    return {
        "means": pts.clone(),
        "quats": torch.nn.functional.normalize(torch.randn(N, 4, generator=g, dtype=F64), dim=-1),
        "log_scales": torch.log(scale)[:, None].repeat(1, 2),
        "opacity_logits": torch.full((N,), float(_logit(torch.tensor(init_opacity))), dtype=F64),
        "color_logits": _logit(col),
    }


def activate(raw: dict[str, Tensor]) -> dict[str, Tensor]:
    """Renderer inputs (means, quats, scales, opacities, colors) of raw parameters."""
    return {
        "means": raw["means"],
        "quats": raw["quats"],
        "scales": torch.exp(raw["log_scales"]),
        "opacities": torch.sigmoid(raw["opacity_logits"]),
        "colors": torch.sigmoid(raw["color_logits"]),
    }


def _check_fit_inputs(images: Tensor, cameras: Sequence[Camera], points: Tensor, colors: Tensor | None, iterations: int) -> None:
    if not isinstance(images, Tensor) or images.dim() != 4 or images.shape[-1] != 3:
        raise ClodsError(f"expected a (C,H,W,3) tensor, got {getattr(images, 'shape', type(images).__name__)}", where="images")
    width, height = check_cameras(cameras)
    if images.shape[:3] != (len(cameras), height, width):
        raise ClodsError(f"shape {tuple(images.shape)} does not match {len(cameras)} cameras of {width}x{height}", where="images")
    if not bool(torch.isfinite(images).all()) or float(images.min()) < 0 or float(images.max()) > 1:
        raise ClodsError("images must be finite values in [0, 1]", where="images")
    if not isinstance(points, Tensor) or points.dim() != 2 or points.shape[1] != 3 or points.shape[0] < 1:
        raise ClodsError(f"expected a (N,3) tensor with N >= 1, got {getattr(points, 'shape', None)}", where="init_points")
    if not bool(torch.isfinite(points).all()):
        raise ClodsError("non-finite values", where="init_points")
    if colors is not None and (not isinstance(colors, Tensor) or colors.shape != points.shape or not bool(torch.isfinite(colors).all())):
        raise ClodsError(f"expected finite {tuple(points.shape)} colours in [0, 1]", where="init_colors")
    if int(iterations) != iterations or iterations < 0:
        raise ClodsError(f"must be a non-negative integer, got {iterations}", where="iterations")


def fit_surfels(
    images: Tensor,  # (C,H,W,3) float in [0,1]
    cameras: Sequence[Camera],
    init_points: Tensor,  # (N,3) e.g. visual-hull samples or a random box
    init_colors: Tensor | None = None,  # (N,3) in [0,1], or None for grey
    iterations: int = 300,
    *,
    lr_means: float = 2e-3,
    lr_quats: float = 1e-2,
    lr_scales: float = 1e-2,
    lr_opacity: float = 5e-2,
    lr_colors: float = 5e-2,
    lambda_dssim: float = 0.2,
    lambda_normal: float = 0.05,
    lambda_dist: float = 10.0,  # the |m_i - m_j| distortion of 2DGS-mapped depths is O(1e-3) per pixel here
    regularize_from: float = 0.3,
    init_opacity: float = 0.1,
    prune_opacity: float = 1.0 / 255.0,
    background: Sequence[float] = (1.0, 1.0, 1.0),
    backend: SurfelBackend = "cpu",
    seed: int = 0,
    callback: Callable[[int, dict[str, float]], None] | None = None,
) -> tuple[dict[str, Tensor], dict[str, list[float]]]:
    """Fit surfels to one frame's views with Adam.

    Loss per iteration: (1 - lambda_dssim) L1 + lambda_dssim (1 - SSIM), plus lambda_normal * normal
    consistency and lambda_dist * distortion (`surfel_losses`) from iteration regularize_from * iterations
    on (2DGS also switches them on late: the geometry must first roughly exist). lr_means is in scene
    units per step, scaled by the extent (bounding-box diagonal) of the initial points.

    Returns:
        params: activated float64 tensors means (K,3), quats (K,4) unit, scales (K,2), opacities (K,),
            colors (K,3) of the K surfels left after dropping those with opacity < prune_opacity;
        history: per-iteration lists 'loss', 'l1', 'normal', 'distortion'.
    """
    _check_fit_inputs(images, cameras, init_points, init_colors, iterations)
    dev = torch.device("cuda") if backend == "gsplat" and torch.cuda.is_available() else torch.device("cpu")
    target = images.detach().to(device=dev, dtype=F64)
    raw = {k: v.to(dev).requires_grad_(True) for k, v in init_surfels(init_points, init_colors, seed, init_opacity).items()}
    lo, hi = init_points.detach().cpu().to(F64).min(0).values, init_points.detach().cpu().to(F64).max(0).values
    extent = max(float((hi - lo).norm()), 1e-6)
    lrs = {"means": lr_means * extent, "quats": lr_quats, "log_scales": lr_scales, "opacity_logits": lr_opacity, "color_logits": lr_colors}
    opt = torch.optim.Adam([{"params": [raw[k]], "lr": lr, "name": k} for k, lr in lrs.items()], eps=1e-15)
    history: dict[str, list[float]] = {"loss": [], "l1": [], "normal": [], "distortion": []}
    reg_start = int(math.ceil(regularize_from * iterations))
    for it in range(iterations):
        opt.zero_grad(set_to_none=True)
        p = activate(raw)
        out = render_surfels(p["means"], p["quats"], p["scales"], p["opacities"], p["colors"], cameras,
                             background=background, backend=backend)  # fmt: skip
        l1 = (out.rgb - target).abs().mean()
        loss = (1.0 - lambda_dssim) * l1 + (lambda_dssim * (1.0 - ssim(out.rgb, target)) if lambda_dssim > 0 else 0.0)
        reg = surfel_losses(out, cameras)
        if it >= reg_start:
            loss = loss + lambda_normal * reg["normal"] + lambda_dist * reg["distortion"]
        loss.backward()
        opt.step()
        rec = {"loss": float(loss.detach()), "l1": float(l1.detach()), "normal": float(reg["normal"].detach()),
               "distortion": float(reg["distortion"].detach())}  # fmt: skip
        for k, v in rec.items():
            history[k].append(v)
        if callback is not None:
            callback(it, rec)
    with torch.no_grad():
        p = {k: v.detach().cpu().clone() for k, v in activate(raw).items()}
        p["quats"] = torch.nn.functional.normalize(p["quats"], dim=-1)
        keep = p["opacities"] >= prune_opacity
        p = {k: v[keep] for k, v in p.items()}
    return p, history


def surfel_depth_maps(params: dict[str, Tensor], cameras: Sequence[Camera], backend: SurfelBackend = "cpu") -> tuple[Tensor, Tensor]:
    """Median-depth maps (C,H,W) (camera z, 0 where alpha <= 0.5) and alpha (C,H,W) of fitted surfels, for TSDF fusion."""
    with torch.no_grad():
        out = render_surfels(params["means"], params["quats"], params["scales"], params["opacities"], params["colors"],
                             cameras, backend=backend)  # fmt: skip
    return out.depth_median[..., 0], out.alpha[..., 0]
