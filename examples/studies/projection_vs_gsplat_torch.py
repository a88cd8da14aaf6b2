"""Does the splatting projection compute what gsplat's pure-torch projection computes? float64, values and gradients.

gsplat (installed, 1.5.3 here) keeps a pure-torch twin of its CUDA kernels, `gsplat.cuda._torch_impl`; its
`_fully_fused_projection` (EWA projection, Jacobian at the clamped mean, 0.3 px^2 dilation, near-plane culling)
runs on the CPU. This study projects random Gaussians (some behind the camera, some outside the image, some flat)
into a rig of cameras with both and compares, on the Gaussians both keep, the means in pixels, depths, conics and
the gradients of a fixed random weighting of the three with respect to the means and the covariances. The bounding
boxes differ by design and are reported, not required equal: gsplat's torch twin uses 3 sigma, this project the
opacity-aware extent sqrt(2 ln(255 opacity)) sigma (gsplat's CUDA kernel's rule, arXiv:2402.00525 B.2); the kept
sets differ only by Gaussians whose box misses the image under one rule.

The compositing half of gsplat's torch twin (`accumulate`) needs nerfacc's packed ray operations, which run on
CUDA only (nerfacc 0.5.3: "Only support cuda inputs"); it is compared on a GPU by
`tests/splatting/test_backends.py::test_gsplat_backend_matches_the_reference_and_the_cpu`.

    python examples/studies/projection_vs_gsplat_torch.py --out results/studies/projection_vs_gsplat_torch/differences.txt
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from clods_bench.datasets.cameras import camera_rig
from clods_bench.splatting import covariances_from_quats_scales
from clods_bench.splatting.projection import project_gaussians


def fail(message: str) -> None:
    print(message)
    raise SystemExit(1)


def scene(g_count: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Means spread over +-3.5 (some behind cameras 3 units out, some off-image), covariances (a third flat), opacities."""
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(g_count, 3, generator=g, dtype=torch.float64) - 0.5) * 7.0
    scales = torch.rand(g_count, 3, generator=g, dtype=torch.float64) * 0.1 + 0.01
    scales[: g_count // 3, 0] = 0.0  # flat: rank-deficient 3D covariance, as GaMeS faces
    covars = covariances_from_quats_scales(torch.randn(g_count, 4, generator=g, dtype=torch.float64), scales)
    return means, covars, torch.rand(g_count, generator=g, dtype=torch.float64) * 0.9 + 0.05


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="also write the table here")
    args = parser.parse_args()
    try:
        import gsplat
        from gsplat.cuda._torch_impl import _fully_fused_projection
    except ImportError as err:
        fail(f"gsplat's torch implementation is not importable ({err}); pip install gsplat")
    cameras = camera_rig(4, np.zeros(3), 3.0, 64, 48)
    means, covars, opac = scene(600, seed=0)
    Ks = torch.as_tensor(np.stack([c.K for c in cameras]))
    Rs, ts = torch.as_tensor(np.stack([c.R for c in cameras])), torch.as_tensor(np.stack([c.t for c in cameras]))
    viewmats = torch.eye(4, dtype=torch.float64).repeat(len(cameras), 1, 1)
    viewmats[:, :3, :3], viewmats[:, :3, 3] = Rs, ts
    w, h = cameras[0].width, cameras[0].height

    leaves_ours = [means.clone().requires_grad_(True), covars.clone().requires_grad_(True)]
    leaves_ref = [means.clone().requires_grad_(True), covars.clone().requires_grad_(True)]
    ours = project_gaussians(*leaves_ours, opac, Ks, Rs, ts, w, h, near=0.01, eps2d=0.3)
    radii, means2d, depths, conics, _ = _fully_fused_projection(*leaves_ref, viewmats, Ks, w, h, eps2d=0.3, near_plane=0.01)
    ref_kept, our_kept = (radii > 0).all(-1), (ours.radii > 0).all(-1)
    both = ref_kept & our_kept
    if int(both.sum()) < 100:
        fail(f"only {int(both.sum())} Gaussian-camera pairs kept by both; the scene does not test much")
    g = torch.Generator().manual_seed(1)
    weights = [torch.rand(x[both].shape, generator=g, dtype=torch.float64) for x in (means2d, depths, conics)]
    sum(((x[both]) * wt).sum() for x, wt in zip((ours.means2d, ours.depths, ours.conics), weights)).backward()
    sum(((x[both]) * wt).sum() for x, wt in zip((means2d, depths, conics), weights)).backward()

    def rel(a: torch.Tensor, b: torch.Tensor) -> float:
        return float((a - b).abs().max() / b.abs().max())

    rows = {
        "means2d": rel(ours.means2d[both].detach(), means2d[both].detach()),
        "depths": rel(ours.depths[both].detach(), depths[both].detach()),
        "conics": rel(ours.conics[both].detach(), conics[both].detach()),
        "d/d means": rel(leaves_ours[0].grad, leaves_ref[0].grad),
        "d/d covariances": rel(leaves_ours[1].grad, leaves_ref[1].grad),
    }
    worst = max(rows.values())
    lines = [
        f"gsplat {gsplat.__version__} gsplat.cuda._torch_impl._fully_fused_projection, float64, 600 Gaussians x 4 cameras of 64x48",
        f"pairs kept: both {int(both.sum())}, only gsplat's 3-sigma boxes {int((ref_kept & ~our_kept).sum())}, "
        f"only the opacity-aware boxes {int((our_kept & ~ref_kept).sum())}; behind the near plane {int((depths <= 0.01).sum())}",
        "max |clods-bench - gsplat| / max |gsplat| over pairs kept by both:",
        *(f"  {k:<16} {v:.3e}" for k, v in rows.items()),
        "",
        f"worst: {worst:.3e} ({'within' if worst <= 1e-10 else 'OUTSIDE'} 1e-10)",
    ]
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")
    sys.exit(0 if worst <= 1e-10 else 1)


if __name__ == "__main__":
    main()
