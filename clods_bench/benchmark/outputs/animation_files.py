"""Animation files of the report's videos: MP4 (H.264) through PyAV when it is installed, else animated WebP (Pillow).

PyAV comes with the `video` extra (`pip install clods-bench[video]`); the base install has Pillow only, so the report
writes animated WebP there and says which format it wrote. Both play in a browser from `file://` and are embedded in
the report's page.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from clods_bench.atomic import atomic_path
from clods_bench.errors import ClodsError


CONTROLS_PAD = 44
"""White rows under a video's content: a browser's paused-video controls cover the bottom of the picture."""


@functools.lru_cache(maxsize=8)
def label_font(size: int):  # noqa: ANN201 - a PIL font
    """Pillow's built-in scalable font at `size` pixels, for the labels drawn into video frames."""
    from PIL import ImageFont

    return ImageFont.load_default(size=size)


def mp4_available() -> bool:
    """True when PyAV (the `video` extra) can be imported, so videos are written as MP4."""
    try:
        import av  # noqa: F401
    except ImportError:
        return False
    return True


def write_animation(frames: np.ndarray, stem: Path, fps: float, fmt: str | None = None) -> Path:
    """Write (F,H,W,3) uint8 frames to `stem` + '.mp4' (PyAV, H.264) or '.webp' (Pillow, animated, lossless); return the
    path. `fmt` ('mp4' or 'webp') forces one; None takes MP4 when PyAV is installed."""
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or len(frames) == 0:
        raise ClodsError(f"frames of shape {frames.shape} and dtype {frames.dtype}, expected (F>0, H, W, 3) uint8", where=str(stem))
    fmt = fmt or ("mp4" if mp4_available() else "webp")
    path = Path(f"{stem}.{fmt}")
    if fmt == "mp4":
        _write_mp4(frames, path, fps)
    elif fmt == "webp":
        _write_webp(frames, path, fps)
    else:
        raise ClodsError(f"unknown animation format '{fmt}'", where=str(stem), hint="mp4 or webp")
    return path


def _write_mp4(frames: np.ndarray, path: Path, fps: float) -> None:
    import av

    f, h, w, _ = frames.shape
    ph, pw = h + h % 2, w + w % 2  # yuv420p needs even sides: pad with white
    if (ph, pw) != (h, w):
        padded = np.full((f, ph, pw, 3), 255, np.uint8)
        padded[:, :h, :w] = frames
        frames = padded
    with atomic_path(path) as tmp:
        with av.open(str(tmp), mode="w", format="mp4", container_options={"movflags": "+faststart"}) as container:
            stream = container.add_stream("libx264", rate=int(round(fps)))
            stream.width, stream.height, stream.pix_fmt = pw, ph, "yuv420p"
            stream.options = {"crf": "18", "preset": "medium"}
            for frame in frames:
                for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")):
                    container.mux(packet)
            for packet in stream.encode():
                container.mux(packet)


def _write_webp(frames: np.ndarray, path: Path, fps: float) -> None:
    from PIL import Image

    images = [Image.fromarray(np.ascontiguousarray(frame)) for frame in frames]
    with atomic_path(path) as tmp:
        images[0].save(tmp, format="WEBP", save_all=True, append_images=images[1:], duration=int(round(1000.0 / fps)), loop=0, lossless=True,
                       method=3)  # fmt: skip


def read_animation(path: Path) -> np.ndarray:
    """(F,H,W,3) uint8 frames of an MP4 (PyAV) or animated WebP (Pillow) written by `write_animation`."""
    path = Path(path)
    if path.suffix == ".mp4":
        import av

        with av.open(str(path)) as container:
            return np.stack([frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)])
    from PIL import Image, ImageSequence

    with Image.open(path) as img:
        return np.stack([np.asarray(frame.convert("RGB")) for frame in ImageSequence.Iterator(img)])
