"""How small can a paper-size trajectory's frames get losslessly? The frame store's codec against image codecs.

Issue 14, item 1 asks for <= 2 GB of frames per `paper` trajectory (401 frames x 30 cameras x 800 px, 23.10 GB raw);
the store's first codec pipeline (planar transpose, byte delta, blosc-zstd 5, crc32c) reached about 3.5 GB, which is
why the store now writes JPEG-LS. This renders chunk-aligned
runs of trajectory 0 exactly as `bench store` does (same scene, mesh, cameras, texture), encodes every image with
each lossless codec, checks that each decodes back bit for bit, and extrapolates bytes per trajectory from the
sample. Slow codecs (WebP, JPEG-XL at effort 7) run on every `--slow-every`-th camera only and are extrapolated
through their ratio to JPEG-LS on the same images. The image codecs come from `imagecodecs` (a dependency of
clods-bench since the store writes JPEG-LS).

    python examples/studies/store_codecs.py --blocks 5 --out results/studies/store_codecs/paper_blocks5.txt
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

from clods_bench.atomic import write_text
from clods_bench.benchmark.core.config import load_config
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.datasets.frame_store import LazyFrames, default_chunk_frames, write_frames
from clods_bench.datasets.generate import _setup, render_steps
from clods_bench.datasets.scenes import simulate_scene
from clods_bench.datasets.store_bench import sample_times


def render_sample(preset: str, blocks: int) -> tuple[np.ndarray, int, tuple[int, ...]]:
    """Frames (t, N, H, W, 3) of `blocks` chunk-aligned runs of trajectory 0, the chunk length and the full shape."""
    cfg = load_config(preset, None, [])
    d = cfg.data
    scene = default_registry().get("scene", d.scene)
    setup = _setup(d, scene)
    shape = (d.num_steps, len(setup.cameras), setup.cameras[0].height, setup.cameras[0].width, 3)
    k = default_chunk_frames(shape)
    times = sample_times(d.num_steps, k, blocks)
    traj = simulate_scene(scene, setup.mesh, d.num_steps, d.seed)
    frames = np.stack(list(render_steps(traj.slice(0, d.num_steps), setup.mesh.texture_uv(), setup.texture, setup.cameras,
                                        setup.settings, times=times)))  # fmt: skip
    return frames, k, shape


def write_legacy(path: Path, frames: np.ndarray, k: int) -> None:
    """Frames as the store wrote them before 2026-11-27: planar transpose, byte delta, blosc-zstd 5, crc32c."""
    import warnings

    import zarr
    from zarr.codecs import BloscCodec, BytesCodec, Crc32cCodec, TransposeCodec
    from zarr.codecs.numcodecs import Delta

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numcodecs.delta is not a core zarr v3 codec
        arr = zarr.create_array(store=str(path), shape=frames.shape, dtype="uint8", chunks=(k, 1, *frames.shape[2:]),
                                filters=[TransposeCodec(order=(0, 1, 4, 2, 3)), Delta(dtype="u1")], serializer=BytesCodec(),
                                compressors=[BloscCodec(cname="zstd", clevel=5, shuffle="noshuffle"), Crc32cCodec()],
                                fill_value=0, chunk_key_encoding={"name": "default", "separator": "."})  # fmt: skip
        arr[:] = frames


def store_row(frames: np.ndarray, k: int, legacy: bool = False) -> tuple[int, float, float]:
    """The frame store (or its pre-2026-11-27 pipeline): bytes of its chunk files, write and read seconds, checked equal."""
    with tempfile.TemporaryDirectory(prefix="store-codecs-") as tmp:
        path = Path(tmp) / "frames.zarr"
        t0 = time.perf_counter()
        if legacy:
            write_legacy(path, frames, k)
        else:
            write_frames(path, frames, chunk_frames=k)
        enc = time.perf_counter() - t0
        t0 = time.perf_counter()
        back = LazyFrames(path)[:]
        dec = time.perf_counter() - t0
        chunk_bytes = sum(p.stat().st_size for p in path.iterdir() if p.name.startswith("c."))
    if not np.array_equal(back, frames):
        raise AssertionError("the frame store did not read back its frames")
    return chunk_bytes, enc, dec


def image_row(images: list[np.ndarray], encode: Callable, decode: Callable) -> tuple[int, float, float]:
    """Bytes, encode and decode seconds of a per-image codec over `images`, each checked bit for bit."""
    t0 = time.perf_counter()
    blobs = [encode(im) for im in images]
    enc = time.perf_counter() - t0
    t0 = time.perf_counter()
    back = [decode(b) for b in blobs]
    dec = time.perf_counter() - t0
    for im, b in zip(images, back):
        if not np.array_equal(np.asarray(b).reshape(im.shape), im):
            raise AssertionError("a codec that claims to be lossless changed an image")
    return sum(len(b) for b in blobs), enc, dec


def image_codecs() -> dict[str, tuple[Callable, Callable, bool]]:
    """name -> (encode, decode, slow) for the lossless image codecs `imagecodecs` offers."""
    import imagecodecs as ic

    return {
        "PNG (zlib 9)": (lambda im: ic.png_encode(im, level=9), ic.png_decode, False),
        "JPEG-LS (CharLS)": (ic.jpegls_encode, ic.jpegls_decode, False),
        "JPEG-XL lossless, effort 1": (lambda im: ic.jpegxl_encode(im, lossless=True, effort=1, numthreads=1), ic.jpegxl_decode, False),
        "JPEG-XL lossless, effort 3": (lambda im: ic.jpegxl_encode(im, lossless=True, effort=3, numthreads=1), ic.jpegxl_decode, False),
        "WebP lossless (level 100)": (lambda im: ic.webp_encode(im, lossless=True, level=100), ic.webp_decode, True),
        "JPEG-XL lossless, effort 7": (lambda im: ic.jpegxl_encode(im, lossless=True, effort=7, numthreads=1), ic.jpegxl_decode, True),
    }  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="paper")
    ap.add_argument("--blocks", type=int, default=5, help="chunk-aligned runs of frames to render (bench store's --blocks)")
    ap.add_argument("--slow-every", type=int, default=6, help="slow codecs encode every n-th camera only")
    ap.add_argument("--out", type=Path, help="also write the table here")
    args = ap.parse_args()
    import numcodecs

    numcodecs.blosc.set_nthreads(1)  # blosc itself on one thread; zarr still works on several chunks at once
    t0 = time.perf_counter()
    frames, k, shape = render_sample(args.preset, args.blocks)
    render_s = time.perf_counter() - t0
    t, n = frames.shape[:2]
    full_raw = int(np.prod(shape))
    scale = full_raw / frames.nbytes
    images = [frames[i, c] for i in range(t) for c in range(n)]
    slow_images = [frames[i, c] for i in range(t) for c in range(0, n, args.slow_every)]
    lines = [f"preset {args.preset}: {t} of {shape[0]} frames ({t // k} chunk-aligned runs of {k}) x {n} cameras of "
             f"{shape[3]}x{shape[2]} px rendered in {render_s:.0f} s; full trajectory raw {full_raw / 1e9:.2f} GB",
             f"{'codec':34s} {'sample MB':>10s} {'ratio':>7s} {'GB/traj':>8s} {'enc img/s':>10s} {'dec img/s':>10s}"]  # fmt: skip

    def row(name: str, nbytes: float, enc: float, dec: float, count: int, note: str = "") -> None:
        lines.append(f"{name:34s} {nbytes / 1e6:10.2f} {frames.nbytes / nbytes:6.2f}x {nbytes * scale / 1e9:8.2f} "
                     f"{count / enc:10.1f} {count / dec:10.1f}{note}")  # fmt: skip
        print(lines[-1], flush=True)

    print("\n".join(lines), flush=True)
    b, enc, dec = store_row(frames, k, legacy=True)
    row("store until 2026-11 (delta+zstd5)", b, enc, dec, len(images))
    b, enc, dec = store_row(frames, k)
    row("frame store (JPEG-LS in zarr)", b, enc, dec, len(images))
    codecs = image_codecs()
    ref_full = ref_slow = None
    for name, (encode, decode, slow) in codecs.items():
        if not slow:
            b, enc, dec = image_row(images, encode, decode)
            row(name, b, enc, dec, len(images))
            if name.startswith("JPEG-LS"):
                ref_full = b
                ref_slow = image_row(slow_images, encode, decode)[0]
        elif ref_full is not None:
            b, enc, dec = image_row(slow_images, encode, decode)
            ratio = b / ref_slow
            row(name, ratio * ref_full, enc, dec, len(slow_images), f"  ({ratio:.3f} x JPEG-LS on every {args.slow_every}th camera)")
    if args.out is not None:
        write_text(args.out, "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
