"""Input validation shared by the renderer plugins: every problem is a ClodsError naming the argument."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor

from clods_bench.datasets.cameras import Camera
from clods_bench.errors import ClodsError


@dataclass(frozen=True)
class FitInputs:
    """Validated `Renderer.fit` arguments as numpy arrays (B frames, V nodes, F faces, N cameras)."""

    verts: np.ndarray  # (B,V,3) float64
    cells: np.ndarray  # (F,3) int64
    mesh_pos: np.ndarray  # (V,D) float64 rest / UV coordinates
    images: np.ndarray  # (B,N,H,W,3) float32 in [0,1]
    cameras: tuple[Camera, ...]


def _array(x: Any, name: str, where: str) -> np.ndarray:
    """A numpy copy of a numpy array or torch tensor (detached)."""
    if isinstance(x, Tensor):
        return x.detach().cpu().numpy()
    try:
        return np.asarray(x)
    except Exception as exc:  # ragged lists and the like
        raise ClodsError(f"cannot read as an array: {exc}", where=f"{where}.{name}") from exc


def check_verts(verts: np.ndarray, name: str, where: str) -> None:
    """Raise unless `verts` is (...,V,3) and finite, naming the first bad node."""
    if verts.ndim < 2 or verts.shape[-1] != 3 or verts.shape[-2] == 0:
        raise ClodsError(f"expected (V,3) vertex positions, got shape {verts.shape}", where=f"{where}.{name}")
    bad = ~np.isfinite(verts).all(axis=-1)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ClodsError(f"non-finite vertex position (NaN or inf) at index {idx}", where=f"{where}.{name}")


def check_cells(cells: np.ndarray, num_verts: int, where: str) -> np.ndarray:
    """(F,3) int64 triangle indices, all in [0, num_verts)."""
    if cells.ndim != 2 or cells.shape[1] != 3 or cells.shape[0] == 0:
        raise ClodsError(f"expected (F,3) triangles, got shape {cells.shape}", where=f"{where}.cells")
    if not np.issubdtype(cells.dtype, np.integer):
        raise ClodsError(f"triangle indices must be integers, got {cells.dtype}", where=f"{where}.cells")
    if cells.min() < 0 or cells.max() >= num_verts:
        raise ClodsError(f"triangle indices must be in [0, {num_verts}), got [{cells.min()}, {cells.max()}]", where=f"{where}.cells")
    return cells.astype(np.int64)


def check_fit_inputs(verts: Any, cells: Any, mesh_pos: Any, images: Any, cameras: Sequence[Camera], where: str) -> FitInputs:
    """Validate `fit` arguments: shapes agree with each other and with the cameras' image size."""
    v = _array(verts, "verts", where).astype(np.float64)
    if v.ndim == 2:
        raise ClodsError(f"expected (B,V,3) frames of vertex positions, got shape {v.shape}", where=f"{where}.verts",
                         hint="add a leading frame axis: verts[None]")  # fmt: skip
    if v.ndim != 3:
        raise ClodsError(f"expected (B,V,3) frames of vertex positions, got shape {v.shape}", where=f"{where}.verts")
    check_verts(v, "verts", where)
    B, V = v.shape[:2]
    c = check_cells(_array(cells, "cells", where), V, where)
    mp = _array(mesh_pos, "mesh_pos", where).astype(np.float64)
    if mp.ndim != 2 or mp.shape[0] != V or not np.isfinite(mp).all():
        raise ClodsError(f"expected finite (V={V},D) mesh coordinates, got shape {mp.shape}", where=f"{where}.mesh_pos")
    cams = tuple(cameras)
    if len(cams) == 0:
        raise ClodsError("need at least one camera", where=f"{where}.cameras")
    for i, cam in enumerate(cams):
        cam.validate(where=f"{where}.cameras[{i}]")
    img = _array(images, "images", where)
    if not np.issubdtype(img.dtype, np.floating):
        raise ClodsError(f"images must be floats in [0,1], got {img.dtype}", where=f"{where}.images", hint="divide uint8 frames by 255")
    expected = (B, len(cams), cams[0].height, cams[0].width, 3)
    if img.shape != expected:
        raise ClodsError(f"images have shape {img.shape}, expected {expected} (B frames, N cameras, H, W, RGB)", where=f"{where}.images")
    for i, cam in enumerate(cams):
        if (cam.height, cam.width) != expected[2:4]:
            raise ClodsError(f"camera is {cam.width}x{cam.height}, images are {expected[3]}x{expected[2]}", where=f"{where}.cameras[{i}]")
    if not np.isfinite(img).all() or img.min() < -1e-6 or img.max() > 1 + 1e-6:
        raise ClodsError("image values must be finite and in [0,1]", where=f"{where}.images")
    return FitInputs(v, c, mp, np.clip(img, 0.0, 1.0).astype(np.float32), cams)


def check_render_verts(verts: Any, num_verts: int, where: str) -> Tensor:
    """The (V,3) floating torch tensor `render` was given (autograd kept); ClodsError if it is unusable."""
    if not isinstance(verts, Tensor):
        verts = torch.as_tensor(np.asarray(verts, dtype=np.float32))
    if not verts.is_floating_point():
        verts = verts.to(torch.float32)
    if verts.shape != (num_verts, 3):
        raise ClodsError(f"expected ({num_verts},3) vertex positions of the fitted mesh, got {tuple(verts.shape)}", where=f"{where}.verts")
    check_verts(verts.detach().cpu().numpy(), "verts", where)
    return verts


def check_render_cameras(cameras: Sequence[Camera], where: str) -> tuple[Camera, ...]:
    """The cameras as a tuple (at least one, each valid)."""
    cams = tuple(cameras)
    if len(cams) == 0:
        raise ClodsError("need at least one camera", where=f"{where}.cameras")
    for i, cam in enumerate(cams):
        cam.validate(where=f"{where}.cameras[{i}]")
    return cams
