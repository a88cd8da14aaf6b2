"""Input validation for `render_gaussians`: every problem becomes a ClodsError naming the argument and index."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor

from clods_bench.datasets.cameras import Camera
from clods_bench.errors import ClodsError
from clods_bench.splatting.projection import covariances_from_quats_scales

BACKENDS = ("cpu", "reference", "gsplat")
DEPTH_MODES = ("expected", "accumulated")


def check_shape(x: Tensor, shape: tuple[int | None, ...], name: str) -> None:
    """Raise unless `x` is a floating tensor of `shape` (None matches any size)."""
    if not isinstance(x, Tensor) or not x.is_floating_point():
        raise ClodsError(f"must be a floating-point torch.Tensor, got {type(x).__name__}", where=name)
    if x.dim() != len(shape) or any(s is not None and s != d for s, d in zip(shape, x.shape)):
        want = "(" + ",".join("*" if s is None else str(s) for s in shape) + ")"
        raise ClodsError(f"expected shape {want}, got {tuple(x.shape)}", where=name)


def check_finite(x: Tensor, name: str) -> None:
    """Raise naming the first Gaussian (leading index) holding a NaN or infinite value."""
    if x.numel() == 0:
        return
    bad = ~torch.isfinite(x.detach()).reshape(x.shape[0], -1).all(dim=1)
    if bool(bad.any()):
        i = int(torch.nonzero(bad)[0, 0])
        raise ClodsError(f"non-finite value (NaN or inf) at index {i}: {x[i].detach().tolist()}", where=f"{name}[{i}]")


def resolve_covariances(means: Tensor, covars: Tensor | None, quats: Tensor | None, scales: Tensor | None) -> Tensor:
    """(G,3,3) covariances: `covars` as given, or R S S^T R^T from (G,4) quats and (G,3) scales (exactly one of the two)."""
    if covars is not None:
        if quats is not None or scales is not None:
            raise ClodsError("give either covars or quats and scales, not both", where="covars")
        return covars
    if quats is None or scales is None:
        raise ClodsError("need covars, or both quats and scales", where="covars")
    check_shape(means, (None, 3), "means")
    G = means.shape[0]
    check_shape(quats, (G, 4), "quats")
    check_shape(scales, (G, 3), "scales")
    check_finite(quats, "quats")
    check_finite(scales, "scales")
    return covariances_from_quats_scales(quats, scales)


def check_gaussians(means: Tensor, covars: Tensor, opacities: Tensor, colors: Tensor) -> int:
    """Validate the Gaussian tensors; returns G."""
    check_shape(means, (None, 3), "means")
    G = means.shape[0]
    check_shape(covars, (G, 3, 3), "covars")
    check_shape(opacities, (G,), "opacities")
    if colors.dim() == 2:
        check_shape(colors, (G, 3), "colors")
    else:
        check_shape(colors, (G, None, 3), "colors")
    for x, name in ((means, "means"), (covars, "covars"), (opacities, "opacities"), (colors, "colors")):
        check_finite(x, name)
    outside = (opacities.detach() < 0) | (opacities.detach() > 1)
    if bool(outside.any()):
        i = int(torch.nonzero(outside)[0, 0])
        raise ClodsError(f"opacity must be in [0, 1], got {float(opacities[i])} at index {i}", where=f"opacities[{i}]")
    return G


def check_cameras(cameras: Sequence[Camera]) -> tuple[int, int]:
    """Validate the cameras (intrinsics, extrinsics, one shared image size); returns (width, height)."""
    if len(cameras) == 0:
        raise ClodsError("need at least one camera", where="cameras")
    for i, cam in enumerate(cameras):
        cam.validate(where=f"cameras[{i}]")
        K = np.asarray(cam.K, dtype=np.float64)
        if K[0, 1] != 0 or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
            raise ClodsError(f"the splatting rasterizer needs a pinhole K [[fx,0,cx],[0,fy,cy],[0,0,1]], got {K.tolist()}",
                             where=f"cameras[{i}].K", hint="skew and a scaled last row are not supported")  # fmt: skip
        if int(cam.width) != cam.width or int(cam.height) != cam.height:
            raise ClodsError(f"image size must be whole pixels, got {cam.width}x{cam.height}", where=f"cameras[{i}]")
    width, height = int(cameras[0].width), int(cameras[0].height)
    for i, cam in enumerate(cameras):
        if (cam.width, cam.height) != (width, height):
            raise ClodsError(
                f"all cameras must share one image size; cameras[0] is {width}x{height}, this one {cam.width}x{cam.height}",
                where=f"cameras[{i}]",
            )
    return width, height


def check_device(means: Tensor, backend: str) -> None:
    """The CPU backends need CPU tensors (gsplat moves inputs to the GPU itself)."""
    if backend != "gsplat" and means.device.type != "cpu":
        raise ClodsError(f"backend '{backend}' runs on the CPU, got tensors on {means.device}", where="means",
                         hint="move the inputs to the CPU or use backend='gsplat'")  # fmt: skip


def check_options(backend: str, near: float, tile: int, depth_mode: str = "expected") -> None:
    """Validate the scalar options."""
    if depth_mode not in DEPTH_MODES:
        raise ClodsError(f"unknown depth_mode '{depth_mode}'; known: {', '.join(DEPTH_MODES)}", where="depth_mode")
    if backend not in BACKENDS:
        raise ClodsError(f"unknown backend '{backend}'; known: {', '.join(BACKENDS)}", where="backend")
    if not near > 0:
        raise ClodsError(f"near plane must be positive, got {near}", where="near")
    if int(tile) != tile or tile < 1:
        raise ClodsError(f"tile size must be a positive integer, got {tile}", where="tile")


def background_tensor(background: Sequence[float] | Tensor, C: int, dtype: torch.dtype) -> Tensor:
    """(C,3) background colours from a (3,) or (C,3) sequence/tensor (kept differentiable)."""
    bg = background if isinstance(background, Tensor) else torch.tensor(background, dtype=dtype)
    bg = bg.to(dtype)
    if bg.shape == (3,):
        bg = bg[None].expand(C, 3)
    if bg.shape != (C, 3) or not bool(torch.isfinite(bg.detach()).all()):
        raise ClodsError(f"background must be finite with shape (3,) or ({C},3), got {tuple(bg.shape)}", where="background")
    return bg
