"""Gaussians anchored on mesh faces (GaMeS; paper section 3.2): centres, rotations and scales from vertices.

For a face (v0, v1, v2) with centroid c (GaMeS code, `prepare_scaling_rot`):
- r1 = normalize((v1 - v0) x (v2 - v0)), the face normal;
- r2 = normalize(v1 - c);
- r3 = normalize(Gram-Schmidt of (v2 - c) against r1, r2);
- s1 = eps (flat along the normal), s2 = |v1 - c| / 2, s3 = |<v2 - c, r3>| / 2.
The paper writes the same frame from the edge v1 - v0 and full lengths; the centroid version keeps
all Gaussians of a face the same shape whatever the vertex order, and the per-Gaussian learnable
scale factor absorbs the factor 2. A Gaussian's centre is fixed barycentric weights times its face's
vertices, its covariance R diag(f s)^2 R^T with f its in-plane scale factor: everything follows the
face rigidly (and stays differentiable w.r.t. the vertices). Degenerate faces give zero-size,
finite Gaussians: every normalisation divides by sqrt(|x|^2 + tiny).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from clods_bench.errors import ClodsError

TINY = 1e-30  # added to squared norms so zero-length vectors normalise to 0, not NaN


def _normalize(x: Tensor) -> Tensor:
    """x / |x| along the last axis; 0 for a zero vector (finite value and gradient)."""
    return x / torch.sqrt((x * x).sum(-1, keepdim=True) + TINY)


def barycentric_layout(k: int) -> np.ndarray:
    """(k,3) well-spread barycentric weights inside a triangle: the centroid for k=1, else an R2 sequence.

    The R2 low-discrepancy sequence (Roberts 2018) fills the unit square evenly; points above the
    diagonal are reflected into the lower triangle (u, v) -> (1-u, 1-v), giving weights (1-u-v, u, v).
    """
    if k < 1:
        raise ClodsError(f"need at least 1 Gaussian per face, got {k}", where="gaussians_per_face")
    if k == 1:
        return np.full((1, 3), 1.0 / 3.0)
    g = 1.32471795724474602596  # plastic number: R2's generator
    n = np.arange(k, dtype=np.float64)
    u = (0.5 + n / g) % 1.0
    v = (0.5 + n / g**2) % 1.0
    flip = u + v > 1.0
    u, v = np.where(flip, 1.0 - u, u), np.where(flip, 1.0 - v, v)
    return np.stack([1.0 - u - v, u, v], axis=1)


def face_frames(tri: Tensor, normal_scale: float) -> tuple[Tensor, Tensor]:
    """(F,3,3) rotations with columns (normal, r2, r3) and (F,3) axis scales (normal_scale, s2, s3) of (F,3,3) faces."""
    v0, v1, v2 = tri.unbind(-2)
    c = (v0 + v1 + v2) / 3.0
    r1 = _normalize(torch.linalg.cross(v1 - v0, v2 - v0, dim=-1))
    a = v1 - c
    r2 = _normalize(a)
    b = v2 - c
    b_perp = b - (b * r1).sum(-1, keepdim=True) * r1 - (b * r2).sum(-1, keepdim=True) * r2
    r3 = _normalize(b_perp)
    s2 = torch.sqrt((a * a).sum(-1) + TINY) / 2.0
    s3 = (b * r3).sum(-1).abs() / 2.0
    scales = torch.stack([torch.full_like(s2, normal_scale), s2, s3], dim=-1)
    return torch.stack([r1, r2, r3], dim=-1), scales


def anchor_gaussians(
    verts: Tensor,  # (V,3) world positions
    cells: Tensor,  # (F,3) int64
    bary: Tensor,  # (K,3) barycentric weights shared by all faces
    scale_factor: Tensor,  # (F*K,) per-Gaussian in-plane scale multiplier (> 0)
    normal_scale: float,
) -> tuple[Tensor, Tensor, Tensor]:
    """Means (F*K,3), covariances (F*K,3,3) and rotations (F*K,3,3) of K Gaussians on each face, face-major."""
    tri = verts[cells]  # (F,3,3): face, corner, xyz
    F_, K = tri.shape[0], bary.shape[0]
    means = torch.einsum("kc,fcx->fkx", bary.to(verts.dtype), tri).reshape(F_ * K, 3)
    rot, scales = face_frames(tri, normal_scale)
    rot = rot[:, None].expand(F_, K, 3, 3).reshape(F_ * K, 3, 3)
    scales = scales[:, None].expand(F_, K, 3).reshape(F_ * K, 3)
    f = scale_factor.to(verts.dtype)
    in_plane = torch.stack([torch.ones_like(f), f, f], dim=-1)
    M = rot * (scales * in_plane)[:, None, :]  # R diag(s)
    return means, M @ M.transpose(-1, -2), rot


def mesh_space_means(mesh_pos: Tensor, cells: Tensor, bary: Tensor) -> Tensor:
    """(F*K,D) mesh-space (rest / UV) coordinates of the Gaussian centres: the same barycentric weights on mesh_pos."""
    tri = mesh_pos[cells]  # (F,3,D)
    return torch.einsum("kc,fcd->fkd", bary.to(mesh_pos.dtype), tri).reshape(-1, mesh_pos.shape[-1])


def mean_face_size(verts: np.ndarray, cells: np.ndarray) -> float:
    """Square root of the mean face area (a length scale for initialising free Gaussians)."""
    tri = verts[cells]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=-1)
    return float(math.sqrt(max(float(area.mean()), 1e-12)))
