"""Cloth textures: a seeded, seamlessly tiling procedural pattern, and image file I/O.

The procedural texture has detail at several scales (random-coloured checker cells, smooth
periodic colour noise at three scales, wrapped Gaussian blobs, thin dark grid lines), so a
deforming cloth has image gradients everywhere and no two regions look alike. Every component
is periodic over the image, so the texture tiles without seams (the rasterizer wraps UVs).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from clods_bench.atomic import atomic_path
from clods_bench.errors import ClodsError

__all__ = ["procedural_texture", "load_texture", "save_texture"]


def _hsv_to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectorised HSV (all in [0,1]) to RGB, last axis 3."""
    i = np.floor(h * 6.0).astype(int) % 6
    f = h * 6.0 - np.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    table = np.stack([np.stack(x, -1) for x in ((v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q))])
    return np.take_along_axis(table, i[None, ..., None].repeat(3, -1), 0)[0]


def _periodic_noise(rng: np.random.Generator, size: int, scale: float) -> np.ndarray:
    """(size,size,3) smooth noise, periodic over the image, features ~`scale` pixels, unit std."""
    freq = np.fft.fftfreq(size)
    k2 = freq[:, None] ** 2 + freq[None, :] ** 2
    filt = np.exp(-0.5 * k2 * (2.0 * np.pi * scale / 2.0) ** 2)
    white = rng.standard_normal((3, size, size))
    noise = np.real(np.fft.ifft2(np.fft.fft2(white) * filt))
    noise /= noise.std(axis=(1, 2), keepdims=True) + 1e-12
    return np.moveaxis(noise, 0, -1)


def procedural_texture(size: int = 512, seed: int = 0) -> np.ndarray:
    """(size,size,3) float32 colourful, seamlessly tiling texture in [0,1] (deterministic per seed)."""
    if int(size) != size or size < 16:
        raise ClodsError(f"size must be an integer >= 16, got {size}", where="texture.size")
    size = int(size)
    rng = np.random.default_rng(seed)
    coord = np.arange(size)
    # checker cells with random, well-spread colours (8 x 8 cells over the image)
    cells = 8
    ci = coord * cells // size
    hue = (rng.permutation(cells * cells) / (cells * cells) + rng.random()) % 1.0
    sat = rng.uniform(0.45, 0.9, cells * cells)
    val = rng.uniform(0.45, 0.95, cells * cells)
    cell_rgb = _hsv_to_rgb(hue, sat, val).reshape(cells, cells, 3)
    img = cell_rgb[ci[:, None], ci[None, :]]
    # smooth colour noise at three scales
    for scale, amp in ((size / 6.0, 0.12), (size / 24.0, 0.08), (size / 96.0, 0.05)):
        img = img + amp * _periodic_noise(rng, size, scale)
    # wrapped Gaussian blobs of random colour and size
    yy, xx = np.meshgrid(coord, coord, indexing="ij")
    for _ in range(24):
        cy, cx = rng.uniform(0, size, 2)
        dy = (yy - cy + size / 2) % size - size / 2
        dx = (xx - cx + size / 2) % size - size / 2
        radius = rng.uniform(0.01, 0.05) * size
        weight = 0.8 * np.exp(-0.5 * (dx * dx + dy * dy) / radius**2)[..., None]
        img = img * (1 - weight) + weight * _hsv_to_rgb(np.array(rng.random()), np.array(0.8), np.array(rng.uniform(0.3, 1.0)))
    # thin dark grid lines, 32 per side (every 4th darker)
    lines = 32
    li = coord * lines // size
    on_line = np.r_[True, li[1:] != li[:-1]]  # first pixel of each line period (period wraps at 0)
    strength = np.where(li % 4 == 0, 0.55, 0.3) * on_line
    line = np.maximum(strength[:, None], strength[None, :])[..., None]
    img = img * (1.0 - line)
    return np.clip(img, 0.0, 1.0).astype(np.float32)


def load_texture(path: str | os.PathLike[str]) -> np.ndarray:
    """(H,W,3) float32 RGB in [0,1] from a PNG/JPG (RGB, RGBA (alpha dropped) or grey)."""
    import imageio.v3 as iio

    p = Path(path)
    if not p.is_file():
        raise ClodsError("texture file not found", where=str(p))
    try:
        img = np.asarray(iio.imread(p, plugin="pillow"))
    except Exception as exc:  # imageio raises many types for unreadable files
        raise ClodsError(f"cannot read texture image: {exc}", where=str(p)) from exc
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4) or img.shape[0] < 1 or img.shape[1] < 1:
        raise ClodsError(f"texture image has shape {img.shape}, expected (H, W), (H, W, 3) or (H, W, 4)", where=str(p))
    img = img[..., :3]
    if np.issubdtype(img.dtype, np.integer):
        out = img.astype(np.float32) / float(np.iinfo(img.dtype).max)
    elif np.issubdtype(img.dtype, np.floating) or img.dtype == bool:
        out = img.astype(np.float32)
    else:
        raise ClodsError(f"unsupported pixel type {img.dtype}", where=str(p))
    return np.clip(np.nan_to_num(out, nan=0.0), 0.0, 1.0)


def save_texture(path: str | os.PathLike[str], tex: np.ndarray) -> None:
    """Write an (H,W,3) [0,1] texture as an 8-bit image (format from the suffix), atomically."""
    import imageio.v3 as iio

    tex = np.asarray(tex)
    if tex.ndim != 3 or tex.shape[2] != 3:
        raise ClodsError(f"texture has shape {tex.shape}, expected (H, W, 3)", where=str(path))
    data = np.clip(np.rint(np.nan_to_num(tex.astype(np.float64)) * 255.0), 0, 255).astype(np.uint8)
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, data, plugin="pillow", extension=Path(path).suffix or ".png")
