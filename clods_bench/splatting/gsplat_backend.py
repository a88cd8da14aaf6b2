"""Backend 'gsplat': our EWA projection on the GPU, then gsplat's tile intersection and rasterization kernels.

gsplat is imported lazily, only when this backend is used; without gsplat or CUDA the call raises a
ClodsError saying what to install. Inputs move to the GPU and results come back to the device of
`means` (autograd follows).

Why not `gsplat.rasterization` end to end: it projects in float32, where det(cov2d) = a c - b^2 of a
flat Gaussian seen nearly edge-on cancels. On `bench render`'s flag that moved 0.005% of the image values
by more than 1e-3, at most 0.03 (128 px) to 0.27 (800 px) (measured on an H100; the same differences
appear on the CPU with the projection forced to float32: examples/studies/float32_projection.py). So the
projection here is `projection.project_gaussians` (float64 torch, autograd for its backward), shared
with the CPU backends; gsplat's kernels then bin (`isect_tiles`, `isect_offset_encode`) and composite
(`rasterize_to_pixels`, colour and depth as four channels) in float32.
gsplat sorts by the bits of the float32 depth it is given, under which Gaussians closer than one float32 step
tie and composite in index order (on the flat cloth that changed 12 pixels by up to 3.6e-3 against the CPU
kernels, which sort by float64 z); it is given `order_keys`, the ranks of the float64 depths, instead.
Remaining differences from the CPU backends: float32 compositing, and gsplat's alpha clamp at 0.999
instead of 3DGS's 0.99 (only Gaussians with opacity above 0.99 differ) and its stop at T <= 1e-4
instead of T < 1e-4.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from clods_bench.errors import ClodsError
from clods_bench.splatting.projection import EPS2D, project_gaussians
from clods_bench.splatting.sh import view_colors

INSTALL_HINT = "backend gsplat needs gsplat and a CUDA GPU: pip install gsplat"


def gsplat_available() -> tuple[bool, str]:
    """(True, '') if gsplat imports and CUDA is usable, else (False, the reason)."""
    if not torch.cuda.is_available():
        return False, "no CUDA GPU (torch.cuda.is_available() is False)"
    try:
        import gsplat  # noqa: F401
    except Exception as exc:  # ImportError, or a broken CUDA extension build
        return False, f"gsplat not importable: {exc}"
    return True, ""


def order_keys(order: Tensor) -> Tensor:
    """(C,G) float32 sort keys 1..G whose order is the stable order of the float64 depths `order` (C,G), exactly: the
    CPU backends' compositing order, which float32 depths would not keep (ranks are exact in float32 below 2^24)."""
    idx = torch.argsort(order.detach(), dim=-1, stable=True)
    ranks = torch.empty_like(idx)
    ranks.scatter_(-1, idx, torch.arange(idx.shape[-1], device=idx.device).expand_as(idx))
    return (ranks + 1).to(torch.float32).contiguous()


def gpu_for(means: Tensor) -> torch.device:
    """The CUDA device to render on: that of `means` if it is on one, else the current one."""
    return means.device if means.device.type == "cuda" else torch.device("cuda")


def render_gsplat(
    means: Tensor,  # (G,3)
    covars: Tensor,  # (G,3,3)
    opacities: Tensor,  # (G,)
    colors: Tensor,  # (G,3) or (G,K,3)
    Ks: Tensor,  # (C,3,3)
    Rs: Tensor,  # (C,3,3)
    ts: Tensor,  # (C,3)
    width: int,
    height: int,
    sh_degree: int | None,
    background: Tensor,  # (C,3)
    near: float,
    tile: int,
    depth_mode: str,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """rgb (C,H,W,3), alpha (C,H,W,1), depth (C,H,W,1), radii (C,G) rendered on CUDA."""
    ok, why = gsplat_available()
    if not ok:
        raise ClodsError(INSTALL_HINT, where="render_gaussians(backend='gsplat')", hint=why)
    from gsplat.cuda._wrapper import isect_offset_encode, isect_tiles, rasterize_to_pixels

    dev = gpu_for(means)
    f32 = torch.float32
    m, o = means.to(dev), opacities.to(dev)
    K, R, t = Ks.to(dev), Rs.to(dev), ts.to(dev)
    proj = project_gaussians(m, covars.to(dev), o, K, R, t, width, height, near=near, eps2d=EPS2D)  # float64 inside
    centers = -torch.einsum("cji,cj->ci", R, t)  # -R^T t
    C, G = proj.radii.shape[:2]
    rgb_cg = view_colors(colors.to(dev), m, centers.to(m.dtype), sh_degree)  # (C,G,3)
    feats = torch.cat([rgb_cg.to(f32), proj.depths.to(f32)[..., None]], dim=-1).contiguous()  # colour + depth
    means2d = proj.means2d.to(f32).contiguous()
    tiles_x, tiles_y = math.ceil(width / tile), math.ceil(height / tile)
    _, isect_ids, flatten_ids = isect_tiles(means2d.detach(), proj.radii.contiguous(), order_keys(proj.order), tile, tiles_x,
                                            tiles_y)  # fmt: skip
    offsets = isect_offset_encode(isect_ids, C, tiles_x, tiles_y)
    render, alpha = rasterize_to_pixels(
        means2d, proj.conics.to(f32).contiguous(), feats, o.to(f32)[None].expand(C, G).contiguous(),
        width, height, tile, offsets, flatten_ids,
    )  # fmt: skip
    out = means.device, means.dtype
    color, dacc, alpha = render[..., :3].to(*out), render[..., 3:4].to(*out), alpha.to(*out)
    rgb = color + (1.0 - alpha) * background[:, None, None, :].to(*out)
    depth = dacc / alpha.clamp(min=1e-10) if depth_mode == "expected" else dacc
    return rgb, alpha, depth, proj.radii.max(dim=-1).values.to(means.device)
