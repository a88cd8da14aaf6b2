"""The fixed splatting benchmark scene: flat Gaussians anchored on the faces of the FLAGSIMPLE-size flag.

Gaussians sit at fixed barycentric points of every triangle (GaMeS / SMGS style) with a flat covariance
from the GaMeS face frame (waczjoan/gaussian-mesh-splatting): centroid c, r2 = normalize(v1 - c),
r3 = Gram-Schmidt of (v2 - c) against r2, standard deviations s2 = |v1 - c| / 2, s3 = <v2 - c, r3> / 2
and zero thickness along the normal. `face_gaussians` is differentiable in the vertices and stays finite
for zero-area and collapsed faces, so it also serves the degenerate-input tests.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from clods_bench.datasets.cameras import Camera, camera_rig
from clods_bench.datasets.meshes import make_flagsimple_mesh

# 5 barycentric points per face: the centroid and four points towards the vertices / an edge
BARYCENTRICS = ((1 / 3, 1 / 3, 1 / 3), (2 / 3, 1 / 6, 1 / 6), (1 / 6, 2 / 3, 1 / 6), (1 / 6, 1 / 6, 2 / 3), (0.45, 0.45, 0.1))
TINY = 1e-30  # guards |v1 - c|^2 of a collapsed face; the term it divides is then exactly zero


def face_gaussians(verts: Tensor, faces: Tensor, bary: Tensor | None = None, scale: float = 1.0) -> tuple[Tensor, Tensor]:
    """(F*B,3) means at barycentric points and (F*B,3,3) flat GaMeS covariances of the faces (F,3) of verts (V,3).

    The covariance (scale^2 / 4) (e e^T + u u^T), with e = v1 - c and u = (v2 - c) minus its part along e,
    equals s2^2 r2 r2^T + s3^2 r3 r3^T of the GaMeS frame without normalising anything: smooth in the
    vertices, rank 1 for a zero-area face and 0 for a face collapsed to a point.
    """
    b = torch.tensor(BARYCENTRICS, dtype=verts.dtype) if bary is None else bary.to(verts.dtype)  # (B,3)
    tri = verts[faces.long()]  # (F,3,3): vertex, coordinate
    means = torch.einsum("bk,fkd->fbd", b, tri).reshape(-1, 3)
    c = tri.mean(dim=1)
    e, w = tri[:, 1] - c, tri[:, 2] - c
    u = w - ((w * e).sum(-1, keepdim=True) / (e * e).sum(-1, keepdim=True).clamp(min=TINY)) * e
    cov = 0.25 * scale**2 * (e[:, :, None] * e[:, None, :] + u[:, :, None] * u[:, None, :])  # (F,3,3)
    return means, cov.repeat_interleave(b.shape[0], dim=0)


def wavy_flag_vertices() -> tuple[np.ndarray, np.ndarray]:
    """(1579,3) vertices of the FLAGSIMPLE-size flag bent by a fixed travelling wave, and its (3028,3) faces."""
    mesh = make_flagsimple_mesh()
    v = np.array(mesh.rest_pos, dtype=np.float64)
    v[:, 1] += 0.12 * v[:, 0] * np.sin(3.0 * v[:, 0] + 2.0 * v[:, 2])  # a wave, growing away from the pole
    return v, np.asarray(mesh.cells)


def bench_scene(seed: int = 0, size: int = 128, num_cameras: int = 8, dtype: torch.dtype = torch.float32) -> tuple[dict[str, Tensor], list[Camera]]:
    """The fixed benchmark scene: Gaussian tensors (means, covars, opacities, colors) and `num_cameras` cameras."""
    v, faces = wavy_flag_vertices()
    means, covars = face_gaussians(torch.tensor(v), torch.tensor(faces))
    rng = np.random.default_rng(seed)
    G = means.shape[0]
    data = {
        "means": means.to(dtype),
        "covars": covars.to(dtype),
        "opacities": torch.tensor(rng.uniform(0.5, 0.95, G), dtype=dtype),
        "colors": torch.tensor(rng.uniform(0.0, 1.0, (G, 3)), dtype=dtype),
    }
    centre = 0.5 * (v.min(0) + v.max(0))
    return data, camera_rig(num_cameras, centre, 4.5, size, size)
