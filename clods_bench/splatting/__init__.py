"""Differentiable 3D Gaussian splatting core shared by the Gaussian renderer plugins (GaMeS, SMGS, 3DGS).

Entry point: `render_gaussians(means, covars, opacities, colors, cameras, ...) -> RenderOutput`, with
backends 'cpu' (numba kernels, default), 'reference' (plain torch oracle) and 'gsplat' (CUDA, optional).
Importing this package compiles nothing and never imports numba kernels or gsplat.
"""

from clods_bench.splatting.projection import (
    Projection,
    covariances_from_quats_scales,
    project_gaussians,
    quat_to_rotmat,
    tile_bounds,
)
from clods_bench.splatting.rasterize import RenderOutput, camera_tensors, render_gaussians
from clods_bench.splatting.sh import sh_basis, view_colors

__all__ = [
    "Projection",
    "RenderOutput",
    "camera_tensors",
    "covariances_from_quats_scales",
    "project_gaussians",
    "quat_to_rotmat",
    "render_gaussians",
    "sh_basis",
    "tile_bounds",
    "view_colors",
]
