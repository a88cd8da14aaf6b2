"""Backend 'gsplat': the same render through `gsplat.rasterization` on a CUDA GPU (optional dependency).

gsplat is imported lazily, only when this backend is used; without gsplat or CUDA the call raises a
ClodsError saying what to install. Inputs move to the GPU and results come back to the device of
`means` (autograd follows). We request 'RGB+D' (accumulated depth) without gsplat backgrounds and
composite the background / normalise depth in torch exactly like the CPU backends, which keeps the
call independent of how gsplat versions pad backgrounds for the depth channel.
Known differences from the CPU backends: gsplat projects in float32, where det(cov2d) of a flat Gaussian
seen nearly edge-on cancels (the CPU projection runs in float64): on `bench render`'s flag about 0.005% of
the image values differ by more than 1e-3, at most by 0.03 (128 px) to 0.27 (800 px), measured on an H100
and reproduced on the CPU by examples/studies/float32_projection.py. gsplat also clamps alpha at 0.999
instead of 3DGS's 0.99 and stops at T <= 1e-4 instead of T < 1e-4 (pixels with opacity above 0.99 or a
transmittance of exactly 1e-4).
"""

from __future__ import annotations

import torch
from torch import Tensor

from clods_bench.errors import ClodsError
from clods_bench.plugins.splatting.projection import EPS2D

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
    """rgb (C,H,W,3), alpha (C,H,W,1), depth (C,H,W,1), radii (C,G) rendered by gsplat on CUDA."""
    ok, why = gsplat_available()
    if not ok:
        raise ClodsError(INSTALL_HINT, where="render_gaussians(backend='gsplat')", hint=why)
    from gsplat import rasterization

    dev, dtype = torch.device("cuda"), torch.float32
    C = Ks.shape[0]
    viewmats = torch.eye(4, dtype=dtype, device=dev).repeat(C, 1, 1)  # (C,4,4) world-to-camera
    viewmats[:, :3, :3] = Rs.to(dev, dtype)
    viewmats[:, :3, 3] = ts.to(dev, dtype)
    render, alpha, meta = rasterization(
        means=means.to(dev, dtype),
        quats=None,
        scales=None,
        opacities=opacities.to(dev, dtype),
        colors=colors.to(dev, dtype),
        viewmats=viewmats,
        Ks=Ks.to(dev, dtype),
        width=width,
        height=height,
        near_plane=near,
        eps2d=EPS2D,
        sh_degree=sh_degree,
        packed=False,
        tile_size=tile,
        render_mode="RGB+D",
        rasterize_mode="classic",
        covars=covars.to(dev, dtype),
    )
    out = means.device, means.dtype
    color, dacc, alpha = render[..., :3].to(*out), render[..., 3:4].to(*out), alpha.to(*out)
    rgb = color + (1.0 - alpha) * background[:, None, None, :].to(*out)
    depth = dacc / alpha.clamp(min=1e-10) if depth_mode == "expected" else dacc
    radii = meta["radii"]
    if radii.dim() == 3:  # newer gsplat: per-axis (C,G,2)
        radii = radii.max(dim=-1).values
    return rgb, alpha, depth, radii.to(means.device, torch.int32)
