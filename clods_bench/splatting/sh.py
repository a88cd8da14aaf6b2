"""Per-view Gaussian colours: plain RGB, or real spherical harmonics of degree 0-3 in the view direction.

Constants, basis order and the +0.5 offset / clamp at 0 follow the original 3DGS
`computeColorFromSH` (and gsplat), so SH coefficients trained there render identically here.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from clods_bench.errors import ClodsError

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (
    -0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
    -0.4570457994644658, 1.445305721320277, -0.5900435899266435,
)  # fmt: skip
MAX_SH_DEGREE = 3


def num_sh_bases(degree: int) -> int:
    """Number of real SH coefficients up to `degree`: (degree + 1)^2."""
    return (degree + 1) ** 2


def sh_basis(degree: int, dirs: Tensor) -> Tensor:
    """(..., (degree+1)^2) real SH basis values at unit directions (...,3), 3DGS sign convention."""
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [
            SH_C2[0] * xy, SH_C2[1] * yz, SH_C2[2] * (2 * zz - xx - yy),
            SH_C2[3] * xz, SH_C2[4] * (xx - yy),
        ]  # fmt: skip
    if degree >= 3:
        out += [
            SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * xy * z, SH_C3[2] * y * (4 * zz - xx - yy),
            SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy), SH_C3[4] * x * (4 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3 * yy),
        ]  # fmt: skip
    return torch.stack(out, dim=-1)


def sh_degree_of(colors: Tensor, sh_degree: int | None) -> int | None:
    """The SH degree used for `colors` ((G,3) -> None = RGB, (G,K,3) -> sqrt(K)-1 unless given); raises on mismatch."""
    if colors.dim() == 2:
        if sh_degree is not None:
            raise ClodsError(f"sh_degree={sh_degree} needs SH coefficients (G,K,3), got colors {tuple(colors.shape)}", where="colors")
        return None
    K = colors.shape[1]
    degree = sh_degree if sh_degree is not None else math.isqrt(K) - 1
    if not (0 <= degree <= MAX_SH_DEGREE) or num_sh_bases(degree) > K or (sh_degree is None and num_sh_bases(degree) != K):
        raise ClodsError(
            f"SH coefficients (G,K,3) need K = (degree+1)^2 >= {num_sh_bases(max(degree, 0))} with degree in 0..{MAX_SH_DEGREE}, "
            f"got K={K}, sh_degree={sh_degree}",
            where="colors",
        )
    return degree


def view_colors(colors: Tensor, means: Tensor, centers: Tensor, sh_degree: int | None) -> Tensor:
    """(C,G,3) colours seen from each camera centre (C,3): RGB as given, or SH + 0.5 clamped at 0.

    Args:
        colors: (G,3) RGB or (G,K,3) SH coefficients.
        means: (G,3) Gaussian centres, for the view directions (SH only).
        centers: (C,3) camera centres in world space.
        sh_degree: None for RGB, else the SH degree to evaluate (<= sqrt(K) - 1).
    """
    C = centers.shape[0]
    if sh_degree is None:
        return colors[None].expand(C, -1, -1)
    d = means[None, :, :] - centers[:, None, :].to(means.dtype)  # (C,G,3)
    d = d / d.norm(dim=-1, keepdim=True).clamp(min=1e-12)
    basis = sh_basis(sh_degree, d)  # (C,G,B)
    coeffs = colors[:, : basis.shape[-1], :]  # (G,B,3)
    rgb = torch.einsum("cgb,gbk->cgk", basis, coeffs)
    return torch.clamp(rgb + 0.5, min=0.0)
