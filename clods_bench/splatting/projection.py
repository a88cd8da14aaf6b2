"""EWA projection of 3D Gaussians into pinhole cameras, in plain torch (autograd gives gradients).

Conventions follow `clods_bench.datasets.cameras` (OpenCV, x_cam = R x + t, pixel (r, c) centre at
(c + 0.5, r + 0.5)) and the 3DGS / gsplat rasterizers:
- the Jacobian of the perspective map is evaluated at the mean with x/z, y/z clamped to 1.3x the
  field of view (gsplat `_persp_proj`), so Gaussians far outside the image do not explode;
- the 2D covariance is dilated by `eps2d` = 0.3 px^2 (low-pass filter), which also makes flat,
  rank-deficient 3D covariances (zero thickness along a face normal) invertible in 2D;
- the bounding box is opacity-aware (gsplat, arXiv:2402.00525 B.2): a pixel with alpha >= 1/255 lies
  within k = sqrt(2 ln(255 opacity)) <= 3.33 sigma, so the per-axis radii ceil(k sqrt(cov2d_xx)),
  ceil(k sqrt(cov2d_yy)) never cut off a visible contribution and tile binning changes no pixel.
Gaussians at or behind the near plane, non-finite, degenerate, fainter than 1/255 or entirely outside
the image are culled: radii 0 and `valid` False, with finite placeholder values (never NaN).
The projection runs in float64 (cancellation in det(cov2d) for flat Gaussians) and returns the
input dtype.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

ALPHA_MIN = 1.0 / 255.0  # alphas below this are skipped by the rasterizers
EPS2D = 0.3  # px^2 added to the projected covariance (3DGS low-pass dilation)
FOV_CLAMP = 1.3  # the Jacobian is evaluated with x/z, y/z clamped to 1.3x the half field of view
MAX_RADIUS = 1 << 28  # radii are clamped here so they fit int32; far larger than any image


@dataclass
class Projection:
    """Screen-space Gaussians for C cameras and G Gaussians (culled entries have radii 0)."""

    means2d: Tensor  # (C,G,2) pixel coordinates (u, v) of the projected centres
    depths: Tensor  # (C,G) camera-space z of the centres
    covars2d: Tensor  # (C,G,2,2) dilated 2D covariances in px^2
    conics: Tensor  # (C,G,3) (a, b, c) of the inverse 2D covariance [[a, b], [b, c]]
    radii: Tensor  # (C,G,2) int32 half extents (x, y) of the bounding box in px; 0 = culled
    valid: Tensor  # (C,G) bool, True where the Gaussian is rendered
    order: Tensor  # (C,G) float64 camera z, detached: the compositing order (as the CPU kernels sort; a float32 z
    # ties Gaussians closer than one float32 step and would composite them in index order)


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """(...,4) quaternions (w, x, y, z), not necessarily normalised, to (...,3,3) rotations."""
    w, x, y, z = torch.nn.functional.normalize(quats, dim=-1).unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]  # fmt: skip
    return torch.stack(rows, dim=-1).reshape(quats.shape[:-1] + (3, 3))


def covariances_from_quats_scales(quats: Tensor, scales: Tensor) -> Tensor:
    """(G,3,3) covariances R S S^T R^T from (G,4) quaternions (w,x,y,z) and (G,3) axis scales."""
    M = quat_to_rotmat(quats) * scales[..., None, :]  # (G,3,3) = R @ diag(s)
    return M @ M.transpose(-1, -2)


def project_gaussians(
    means: Tensor,  # (G,3) world-space centres
    covars: Tensor,  # (G,3,3) world-space covariances (symmetric PSD, may be rank-deficient)
    opacities: Tensor,  # (G,) in [0,1], only used for the bounding boxes
    Ks: Tensor,  # (C,3,3) intrinsics
    Rs: Tensor,  # (C,3,3) world-to-camera rotations
    ts: Tensor,  # (C,3) world-to-camera translations
    width: int,
    height: int,
    near: float = 0.01,
    eps2d: float = EPS2D,
) -> Projection:
    """Project Gaussians into every camera (EWA splatting); differentiable w.r.t. means and covars.

    Returns:
        A `Projection`; radii and valid carry no gradient.
    """
    out_dtype = means.dtype
    f64 = torch.float64
    m, S = means.to(f64), covars.to(f64)
    K, R, t = Ks.to(f64), Rs.to(f64), ts.to(f64)
    finite = torch.isfinite(m).all(-1) & torch.isfinite(S).flatten(-2).all(-1)  # (G,)
    m = torch.where(finite[:, None], m, torch.zeros_like(m))
    S = torch.where(finite[:, None, None], S, torch.zeros_like(S))

    pc = m[None] @ R.transpose(1, 2) + t[:, None, :]  # (C,G,3) camera-space centres
    x, y, z = pc.unbind(-1)
    valid = (z > near) & finite[None, :]
    z_s = torch.where(valid, z, torch.ones_like(z))  # safe denominators: no inf/NaN even in backward
    x_s = torch.where(valid, x, torch.zeros_like(x))
    y_s = torch.where(valid, y, torch.zeros_like(y))

    fx, fy = K[:, 0, 0, None], K[:, 1, 1, None]  # (C,1)
    cx, cy = K[:, 0, 2, None], K[:, 1, 2, None]
    means2d = torch.stack([fx * x_s / z_s + cx, fy * y_s / z_s + cy], dim=-1)  # (C,G,2)

    margin = FOV_CLAMP - 1.0
    lim_xp = (width - cx) / fx + margin * 0.5 * width / fx
    lim_xn = cx / fx + margin * 0.5 * width / fx
    lim_yp = (height - cy) / fy + margin * 0.5 * height / fy
    lim_yn = cy / fy + margin * 0.5 * height / fy
    tx = z_s * torch.clamp(x_s / z_s, min=-lim_xn, max=lim_xp)
    ty = z_s * torch.clamp(y_s / z_s, min=-lim_yn, max=lim_yp)
    zero = torch.zeros_like(z_s)
    J = torch.stack([fx / z_s, zero, -fx * tx / z_s**2, zero, fy / z_s, -fy * ty / z_s**2], dim=-1)
    J = J.reshape(z_s.shape + (2, 3))  # (C,G,2,3)

    JR = J @ R[:, None]  # (C,G,2,3): Jacobian of pixel w.r.t. world position
    cov2d = JR @ S[None] @ JR.transpose(-1, -2)  # (C,G,2,2) = J R S R^T J^T
    cov2d = 0.5 * (cov2d + cov2d.transpose(-1, -2)) + eps2d * torch.eye(2, dtype=f64, device=m.device)
    a, b, c = cov2d[..., 0, 0], cov2d[..., 0, 1], cov2d[..., 1, 1]
    det = a * c - b * b
    valid = valid & torch.isfinite(det) & (det > 0)
    det_s = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([c / det_s, -b / det_s, a / det_s], dim=-1)  # (C,G,3)
    conics = torch.where(valid[..., None], conics, torch.zeros_like(conics))
    cov2d = torch.where(valid[..., None, None], cov2d, eps2d * torch.eye(2, dtype=f64, device=m.device).expand_as(cov2d))

    radii = _radii(means2d.detach(), a.detach(), c.detach(), opacities.detach().to(f64), valid, width, height)
    valid = valid & (radii > 0).all(-1)
    return Projection(
        means2d=means2d.to(out_dtype),
        depths=z.to(out_dtype),
        covars2d=cov2d.to(out_dtype),
        conics=conics.to(out_dtype),
        radii=radii,
        valid=valid,
        order=z.detach(),
    )


def _radii(means2d: Tensor, a: Tensor, c: Tensor, opacities: Tensor, valid: Tensor, width: int, height: int) -> Tensor:
    """(C,G,2) int32 opacity-aware bounding-box half extents; 0 where culled."""
    o = opacities.expand_as(a)  # (C,G)
    visible = valid & (o >= ALPHA_MIN)
    k = torch.sqrt(2.0 * torch.log(torch.clamp(o, min=ALPHA_MIN) / ALPHA_MIN))  # <= 3.33 for o <= 1
    r = torch.stack([k * torch.sqrt(a.clamp(min=0)), k * torch.sqrt(c.clamp(min=0))], dim=-1)
    r = torch.ceil(torch.nan_to_num(r, nan=0.0, posinf=MAX_RADIUS)).clamp(max=MAX_RADIUS)
    u, v = means2d.unbind(-1)
    inside = (u + r[..., 0] > 0) & (u - r[..., 0] < width) & (v + r[..., 1] > 0) & (v - r[..., 1] < height)
    keep = visible & inside & (r > 0).all(-1)
    return torch.where(keep[..., None], r, torch.zeros_like(r)).to(torch.int32)


def tile_bounds(means2d: Tensor, radii: Tensor, width: int, height: int, tile: int) -> Tensor:
    """(C,G,4) int32 tile rectangles [x0, y0, x1, y1) each Gaussian's bounding box touches (empty if culled).

    Shared by both CPU rasterizers so they bin identically; computed in float64 without gradient.
    """
    tiles_x, tiles_y = math.ceil(width / tile), math.ceil(height / tile)
    m = means2d.detach().to(torch.float64)
    r = radii.to(torch.float64)
    lo = torch.floor((m - r) / tile)
    hi = torch.ceil((m + r) / tile)
    lim = torch.tensor([tiles_x, tiles_y], dtype=torch.float64)
    lo = torch.minimum(torch.clamp(torch.nan_to_num(lo), min=0), lim)
    hi = torch.minimum(torch.clamp(torch.nan_to_num(hi), min=0), lim)
    culled = (radii <= 0).any(-1, keepdim=True)
    bounds = torch.cat([lo, hi], dim=-1)
    return torch.where(culled, torch.zeros_like(bounds), bounds).to(torch.int32)
