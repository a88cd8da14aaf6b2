"""Cloth textures: seeded, seamlessly tiling procedural patterns by name, image files, and image file I/O.

`data.texture` names a texture: one of `TEXTURE_NAMES` (procedural: the default multi-scale pattern; stripes:
coarse two-colour stripes; weave: a low-contrast basket weave), or an image file, written `file:PATH` or as a
path ending in .png/.jpg/.jpeg (see `texture_file` and `make_named_texture`).

The procedural texture has detail at several scales (random-coloured checker cells, smooth
periodic colour noise at three scales, wrapped Gaussian blobs, thin dark grid lines), so a
deforming cloth has image gradients everywhere and no two regions look alike. Every component
is periodic over the image, so the texture tiles without seams (the rasterizer wraps UVs).
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from clods_bench.atomic import atomic_path
from clods_bench.errors import ClodsError, unknown_name

__all__ = [
    "procedural_texture", "stripes_texture", "weave_texture", "load_texture", "save_texture", "TEXTURE_NAMES",
    "STRIPE_PERIODS", "WEAVE_THREADS", "texture_file", "texture_file_digest", "make_named_texture",
]  # fmt: skip

STRIPE_PERIODS = 4
"""Light/dark stripe pairs across the stripes texture (period = size / 4: 128 px at 512, a quarter of the cloth)."""
WEAVE_THREADS = 32
"""Threads per side of the weave texture (one over/under crossing = 2 threads)."""
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
MAX_FILE_TEXTURE_SIDE = 8192


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


def _check_size(size: int) -> int:
    """`size` as an int, ClodsError unless it is an integer >= 16."""
    if int(size) != size or size < 16:
        raise ClodsError(f"size must be an integer >= 16, got {size}", where="texture.size")
    return int(size)


def procedural_texture(size: int = 512, seed: int = 0) -> np.ndarray:
    """(size,size,3) float32 colourful, seamlessly tiling texture in [0,1] (deterministic per seed)."""
    size = _check_size(size)
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


def stripes_texture(size: int = 512, seed: int = 0) -> np.ndarray:
    """(size,size,3) float32 coarse two-colour stripes (colour changes down the rows, constant along each row),
    `STRIPE_PERIODS` light/dark pairs per side, seeded colours: structure at one large scale only."""
    size = _check_size(size)
    if size % (2 * STRIPE_PERIODS):
        raise ClodsError(f"size must be a multiple of {2 * STRIPE_PERIODS} for stripes, got {size}",
                         where="texture.size")  # fmt: skip
    rng = np.random.default_rng(seed)
    hue = rng.random()
    light = _hsv_to_rgb(np.array(hue), np.array(0.6), np.array(0.9))
    dark = _hsv_to_rgb(np.array((hue + 0.5) % 1.0), np.array(0.7), np.array(0.35))
    period = size // STRIPE_PERIODS
    band = (np.arange(size) % period) < period // 2  # rows of the light half of each period
    img = np.where(band[:, None, None], light[None, None, :], dark[None, None, :])
    return np.broadcast_to(img, (size, size, 3)).astype(np.float32).copy()


def weave_texture(size: int = 512, seed: int = 0) -> np.ndarray:
    """(size,size,3) float32 low-contrast basket weave: one seeded yarn colour, each thread's crossing shaded by a
    smooth bump (over: lighter middle, under: darker), +-4% brightness, plus faint periodic fibre noise."""
    size = _check_size(size)
    if size % WEAVE_THREADS:
        raise ClodsError(f"size must be a multiple of {WEAVE_THREADS} for weave, got {size}", where="texture.size")
    rng = np.random.default_rng(seed)
    base = _hsv_to_rgb(np.array(rng.random()), np.array(0.35), np.array(0.7))
    pitch = size // WEAVE_THREADS
    coord = np.arange(size)
    thread = coord // pitch
    bump = np.sin(np.pi * (coord % pitch + 0.5) / pitch)  # 0 at a thread's edges, 1 at its middle
    over = (thread[:, None] + thread[None, :]) % 2 == 0  # warp over weft on a checkerboard of crossings
    shade = np.where(over, 0.04 * bump[None, :], -0.04 * bump[:, None])
    img = base[None, None, :] * (1.0 + shade[..., None]) + 0.01 * _periodic_noise(rng, size, 1.5)
    return np.clip(img, 0.0, 1.0).astype(np.float32)


TEXTURES: dict[str, Callable[[int, int], np.ndarray]] = {
    "procedural": procedural_texture, "stripes": stripes_texture, "weave": weave_texture,
}  # fmt: skip
TEXTURE_NAMES = tuple(TEXTURES)


def texture_file(spec: str) -> Path | None:
    """The image file a `data.texture` value names (`file:PATH`, or a path ending in .png/.jpg/.jpeg), else None."""
    if spec.startswith("file:"):
        return Path(spec[len("file:") :])
    if spec.lower().endswith(IMAGE_SUFFIXES):
        return Path(spec)
    return None


def _check_spec(spec: str) -> Path | None:
    """The file of a file texture; None for a known name; ClodsError naming `data.texture` otherwise."""
    path = texture_file(spec)
    if path is None and spec not in TEXTURES:
        err = unknown_name("texture", spec, TEXTURE_NAMES)
        raise ClodsError(err.what, where="data.texture", hint=err.hint or "or an image file: file:PATH, *.png, *.jpg")
    return path


def texture_file_digest(spec: str) -> str | None:
    """sha256 of the bytes of the image file `spec` names (None for a named texture): a dataset's identity follows
    the file's content, not only its path."""
    path = _check_spec(spec)
    if path is None:
        return None
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError as exc:
        raise ClodsError(f"cannot read texture file {path}: {exc.strerror or exc}", where="data.texture") from exc


def make_named_texture(spec: str, seed: int, size: int = 512) -> np.ndarray:
    """The texture a `data.texture` value names: a named pattern (size x size, seeded) or the image file's pixels."""
    path = _check_spec(spec)
    if path is None:
        return TEXTURES[spec](size, seed)
    try:
        return load_texture(path)
    except ClodsError as exc:
        raise ClodsError(f"texture file {path}: {exc.what}", where="data.texture", hint=exc.hint) from exc


def load_texture(path: str | os.PathLike[str]) -> np.ndarray:
    """(H,W,3) float32 RGB in [0,1] from a PNG/JPG (RGB, RGBA (alpha dropped) or grey)."""
    import imageio.v3 as iio

    p = Path(path)
    if not p.is_file():
        raise ClodsError("texture file not found", where=str(p))
    if p.stat().st_size == 0:
        raise ClodsError("texture file is empty", where=str(p))
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
    if max(img.shape[:2]) > MAX_FILE_TEXTURE_SIDE:
        raise ClodsError(f"texture image is {img.shape[1]} x {img.shape[0]} px, larger than {MAX_FILE_TEXTURE_SIDE}",
                         where=str(p), hint="downscale it; the rasterizer samples any size")
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
