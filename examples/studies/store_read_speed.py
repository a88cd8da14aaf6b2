"""Read speed of the frame store's JPEG-LS codec against the pipeline it replaced, on the same frames, same run.

Renders a preset's trajectory-0 sample as `store_codecs.py` does (`blocks` chunk-aligned runs of frames, every
camera), writes it with both codec pipelines, then alternates reading each back through `LazyFrames` `repeats` times
(page cache warm: decode speed) and prints the best: every frame of every camera, and one camera's frame range.

    python examples/studies/store_read_speed.py paper 2 3
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from store_codecs import render_sample, write_legacy  # noqa: E402

from clods_bench.datasets.frame_store import LazyFrames, write_frames  # noqa: E402


def main(preset: str, blocks: int, repeats: int) -> None:
    frames, k, _ = render_sample(preset, blocks)
    t, n = frames.shape[:2]
    span = min(t, 4 * k)  # one camera, up to 4 time chunks
    best_all = {"earlier pipeline": np.inf, "JPEG-LS": np.inf}
    best_one = dict(best_all)
    with tempfile.TemporaryDirectory(prefix="store-read-") as tmp:
        paths = {"earlier pipeline": Path(tmp) / "legacy.zarr", "JPEG-LS": Path(tmp) / "jpegls.zarr"}
        write_legacy(paths["earlier pipeline"], frames, k)
        write_frames(paths["JPEG-LS"], frames, chunk_frames=k)
        for _ in range(repeats):
            for name, path in paths.items():
                lazy = LazyFrames(path)
                t0 = time.perf_counter()
                got = lazy[:]
                best_all[name] = min(best_all[name], time.perf_counter() - t0)
                t0 = time.perf_counter()
                lazy[:span, 0]
                best_one[name] = min(best_one[name], time.perf_counter() - t0)
                if not np.array_equal(got, frames):
                    raise AssertionError(f"{name} did not read back its frames")
    print(f"preset {preset}: {t} frames x {n} cameras of {frames.shape[3]}x{frames.shape[2]} px, best of {repeats}")
    for name in paths:
        print(f"  {name:17s} every image {t * n / best_all[name]:8.1f} images/s; camera 0, {span} frames {span / best_one[name]:8.1f} images/s")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]))
