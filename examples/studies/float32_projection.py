"""How far the images move when the EWA projection runs in float32 instead of float64 (bench scene).

gsplat projects in float32; the cpu backends project in float64 because det(cov2d) = a c - b^2 of a flat
Gaussian seen nearly edge-on cancels. This script renders `bench render`'s scene twice with the torch
reference backend (the cpu backend projects in numba, float64 only), once with the torch projection switched to float32, and prints the differences, to compare with the
'max |gsplat - cpu|' rows of `clods-bench bench render` on a GPU.

    python examples/studies/float32_projection.py 128 8     # bench render's default scene
    python examples/studies/float32_projection.py 800 30    # the paper's image size and cameras
"""

from __future__ import annotations

import inspect
import sys

import torch

import clods_bench.splatting.projection as projection
import clods_bench.splatting.rasterize as rasterize
from clods_bench.splatting.flag_scene import bench_scene


def render(data: dict, cameras: list) -> torch.Tensor:
    """(C,H,W,4) rgb and alpha of the scene with the reference backend (torch projection)."""
    out = rasterize.render_gaussians(data["means"], data["covars"], data["opacities"], data["colors"], cameras, backend="reference")
    return torch.cat([out.rgb, out.alpha], dim=-1)


def main(size: int, views: int) -> None:
    data, cameras = bench_scene(0, size, views)
    f64 = render(data, cameras)
    source = inspect.getsource(projection.project_gaussians)
    assert "f64 = torch.float64" in source, "projection.project_gaussians no longer has the float64 switch"
    namespace = dict(vars(projection))
    exec(source.replace("f64 = torch.float64", "f64 = torch.float32"), namespace)
    original = rasterize.project_gaussians
    rasterize.project_gaussians = namespace["project_gaussians"]
    try:
        f32 = render(data, cameras)
    finally:
        rasterize.project_gaussians = original
    d = (f64 - f32).abs()
    print(f"{views} views {size}x{size}: |float32 - float64 projection| rgb+alpha max {d.max():.2e}, mean {d.mean():.2e}, "
          f"share > 1e-3 {100 * (d > 1e-3).double().mean():.4f}%")  # fmt: skip


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 128, int(sys.argv[2]) if len(sys.argv) > 2 else 8)
