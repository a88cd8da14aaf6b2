"""Multi-view frames on disk: one chunked, compressed, checksummed zarr v3 array per trajectory.

`frames_0000.zarr/` holds `zarr.json` (shape (T, N, H, W, 3) uint8, chunk shape, codecs) and one file per
chunk, `c.<t>.<n>.0.0.0`: `chunk_frames` consecutive frames of ONE camera, whole images. Tasks read views
(cameras) and frame ranges, so a chunk never mixes cameras and never cuts an image; about 8 MiB of frames
per chunk (4 frames at 800 px, a whole 41-frame camera at 64 px) keeps one-frame reads cheap and the file
count low. Codecs, all lossless: each image of the chunk as a JPEG-LS stream (`clods_bench.jpegls`,
`jpegls_codec.py`: LOCO-I prediction from the left, upper and upper-left neighbours, context-modelled residuals),
then `crc32c`, so every chunk carries its own checksum and a damaged one fails loudly. On the `paper` preset's
800 px flag frames that is 8.8x smaller than raw, against 6.7x for the planar transpose + byte delta + blosc-zstd
pipeline that stores written before 2026-11-27 use (they keep loading: zarr reads each array's codecs from its
`zarr.json`; README, "How datasets are stored").

Writing streams time steps into a temp directory (`.frames_0000.zarr.<random>.tmp`) and renames it into
place only when every chunk is written, so a killed writer never leaves a complete-looking array. Reading
(`LazyFrames`) decodes only the chunks a selection touches and names the chunk file in every error; a
missing chunk file is an error, never the zero fill value zarr would silently return.
"""

from __future__ import annotations

import abc
import hashlib
import os
import shutil
import tempfile
import warnings
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from clods_bench.errors import ClodsError

FORMAT = "zarr-v3"
CHUNK_TARGET_BYTES = 8 << 20  # uncompressed bytes per chunk the chunk length aims at (4 frames of 800 px)
MAX_CHUNK_FRAMES = 64
CODEC_NAME = "jpegls+crc32c"
LEGACY_CODEC_NAME = "transpose-planar+delta+blosc-zstd5+crc32c"  # stores written before 2026-11-27
_NOT_CORE = "Numcodecs codecs are not in the Zarr version 3 specification"  # zarr's note on numcodecs.delta
_HINT = "the file is damaged; regenerate the trajectory (clods-bench data generate --force) or restore the dataset"


def _zarr() -> Any:
    try:
        import zarr

        from clods_bench.datasets import jpegls_codec
    except ImportError:  # pragma: no cover - a declared dependency
        raise ClodsError("reading and writing frames needs the 'zarr' package", hint="pip install 'zarr>=3.1'") from None
    jpegls_codec.register()
    return zarr


def default_chunk_frames(shape: Sequence[int]) -> int:
    """Frames per chunk for frames of `shape` (T, N, H, W, 3): about CHUNK_TARGET_BYTES uncompressed, 1..64, <= T."""
    frame_bytes = int(np.prod(shape[2:]))
    return int(max(1, min(int(shape[0]), MAX_CHUNK_FRAMES, CHUNK_TARGET_BYTES // max(frame_bytes, 1))))


def chunk_key(t_chunk: int, view: int) -> str:
    """File name of the chunk holding time chunk `t_chunk` of camera `view`."""
    return f"c.{t_chunk}.{view}.0.0.0"


class FrameWriter:
    """Streams (N, H, W, 3) uint8 time steps into a new frame array; `close()` publishes it atomically.

    Use as a context manager: leaving the block by an exception deletes the temp directory.
    """

    def __init__(self, path: Path, shape: Sequence[int], chunk_frames: int | None = None) -> None:
        """Prepare `path` (a `.zarr` directory) for frames of `shape` (T, N, H, W, 3)."""
        zarr = _zarr()
        from zarr.codecs import Crc32cCodec

        from clods_bench.datasets.jpegls_codec import JpegLsCodec

        self.path = Path(path)
        self.shape = tuple(int(s) for s in shape)
        self.chunk_frames = int(chunk_frames or default_chunk_frames(self.shape))
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent))
        self._array = zarr.create_array(
            store=str(self.tmp), shape=self.shape, dtype="uint8", chunks=(self.chunk_frames, 1, *self.shape[2:]),
            filters=[], serializer=JpegLsCodec(), compressors=[Crc32cCodec()],
            fill_value=0, chunk_key_encoding={"name": "default", "separator": "."}, config={"write_empty_chunks": True},
        )  # fmt: skip
        self._buffer = np.empty((self.chunk_frames, *self.shape[1:]), np.uint8)
        self._filled = 0  # steps in the buffer
        self._written = 0  # steps flushed to chunks

    @property
    def steps(self) -> int:
        """Time steps appended so far."""
        return self._written + self._filled

    def append(self, step: np.ndarray) -> None:
        """Add the next time step's (N, H, W, 3) uint8 images; a full time chunk is written at once."""
        if self.steps >= self.shape[0]:
            raise ClodsError(f"more than the declared {self.shape[0]} time steps", where=str(self.path))
        if step.shape != self.shape[1:] or step.dtype != np.uint8:
            raise ClodsError(f"time step {self.steps}: {step.shape} {step.dtype}, expected {self.shape[1:]} uint8", where=str(self.path))
        self._buffer[self._filled] = step
        self._filled += 1
        if self._filled == self.chunk_frames or self.steps == self.shape[0]:
            self._array[self._written : self._written + self._filled] = self._buffer[: self._filled]
            self._written += self._filled
            self._filled = 0

    def close(self) -> dict[str, Any]:
        """Check every step was written, sync the chunks, rename the array into place; return its file record."""
        if self.steps != self.shape[0]:
            raise ClodsError(f"{self.steps} time steps written, {self.shape[0]} declared", where=str(self.path))
        for p in self.tmp.iterdir():
            with open(p, "rb") as fh:
                os.fsync(fh.fileno())
        record = frames_record(self.tmp, self.shape, name=self.path.name)
        if self.path.exists():  # rewriting a trajectory: its manifest entry is already gone
            shutil.rmtree(self.path)
        os.replace(self.tmp, self.path)
        return record

    def abort(self) -> None:
        """Delete the temp directory (what a failed write leaves)."""
        shutil.rmtree(self.tmp, ignore_errors=True)

    def __enter__(self) -> "FrameWriter":
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if isinstance(exc, OSError) and not exc.filename:
            exc.filename = str(self.path)  # a chunk write that failed (a full disk) names the frame array it was for
        if exc_type is not None or self.tmp.exists():
            self.abort()


def write_frames(path: Path, frames: np.ndarray | Iterable[np.ndarray], shape: Sequence[int] | None = None,
                 chunk_frames: int | None = None) -> dict[str, Any]:  # fmt: skip
    """Write (T, N, H, W, 3) frames, or an iterable of T (N, H, W, 3) steps of `shape`, atomically; the file record."""
    if shape is None:
        if not isinstance(frames, np.ndarray):
            raise ClodsError("frames given as an iterable of steps need their total shape", where=str(path))
        shape = frames.shape
    with FrameWriter(path, shape, chunk_frames) as writer:
        for step in frames:
            writer.append(np.asarray(step))
        return writer.close()


def frames_record(path: Path, shape: Sequence[int], name: str | None = None) -> dict[str, Any]:
    """The manifest record of a frame array on disk: name, bytes (all files), sha256 of zarr.json, chunk count and shape."""
    path = Path(path)
    meta = path / "zarr.json"
    if not meta.is_file():
        raise ClodsError("frame array metadata zarr.json missing", where=str(path), hint=_HINT)
    array = _open(path)
    files = [p for p in path.iterdir() if p.is_file()]
    expected = _grid(array.shape, array.chunks)
    if tuple(array.shape) != tuple(shape):
        raise ClodsError(f"frame array shape {tuple(array.shape)}, expected {tuple(shape)}", where=str(path))
    chunks = [p for p in files if p.name.startswith("c.")]
    if len(chunks) != expected:
        raise ClodsError(f"{len(chunks)} chunk files, the array has {expected} chunks", where=str(path), hint=_HINT)
    return {
        "name": name or path.name,
        "format": FORMAT,
        "codec": _codec_name(array),
        "bytes": sum(p.stat().st_size for p in files),
        "sha256": hashlib.sha256(meta.read_bytes()).hexdigest(),  # of zarr.json; each chunk carries a crc32c
        "chunks": expected,
        "chunk_shape": [int(c) for c in array.chunks],
    }


def _codec_name(array: Any) -> str:
    """The manifest's name for an array's codec pipeline: this version's, or that of stores written before it."""
    from clods_bench.datasets.jpegls_codec import NAME

    names = [c.get("name") for c in array.metadata.to_dict().get("codecs", [])]
    return CODEC_NAME if names and names[0] == NAME else LEGACY_CODEC_NAME


def _open(path: Path) -> Any:
    zarr = _zarr()
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=_NOT_CORE)
            return zarr.open_array(store=str(path), mode="r")
    except Exception as exc:  # zarr raises several types for damaged or missing metadata
        raise ClodsError(f"cannot open frame array: {type(exc).__name__}: {exc}", where=str(path), hint=_HINT) from None


def _grid(shape: Sequence[int], chunks: Sequence[int]) -> int:
    return int(np.prod([-(-s // c) for s, c in zip(shape, chunks)]))


Index = int | slice | Sequence[int] | np.ndarray


class FrameArray(abc.ABC):
    """What a trajectory's frames (T, N, H, W, 3) uint8 offer a task, however they are obtained: `shape`, `read`
    (orthogonal selection), and numpy-like indexing on the time and camera axes."""

    path: Path
    shape: tuple[int, ...]

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def nbytes(self) -> int:
        """Decoded size of the whole array in bytes."""
        return int(np.prod(self.shape))

    def __len__(self) -> int:
        return self.shape[0]

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        out = self.read(slice(None), slice(None))
        return out if dtype is None else out.astype(dtype)

    def __getitem__(self, key: Any) -> np.ndarray:
        key = key if isinstance(key, tuple) else (key,)
        if any(k is Ellipsis or k is None for k in key[:2]):
            raise ClodsError("'...' and None are not supported on the time/camera axes", where=str(self.path))
        t_key = key[0] if len(key) > 0 else slice(None)
        v_key = key[1] if len(key) > 1 else slice(None)
        if not _is_basic(t_key) and not _is_basic(v_key):
            raise ClodsError("a list on both the time and the camera axis is ambiguous", where=str(self.path),
                             hint="use frames.read(times, views) for every listed frame of every listed camera")  # fmt: skip
        out = self.read(t_key, v_key)
        rest = (0 if isinstance(t_key, (int, np.integer)) else slice(None), 0 if isinstance(v_key, (int, np.integer)) else slice(None))
        return out[(*rest, *key[2:])]

    def select(self, times: Index = slice(None), views: Index = slice(None)) -> "FrameSelection":
        """A lazy selection of these frames and cameras: nothing is read until it is indexed (see FrameSelection)."""
        return FrameSelection(self, times, views)

    @abc.abstractmethod
    def read(self, times: Index, views: Index) -> np.ndarray:
        """(len(times), len(views), H, W, 3): every selected frame of every selected camera (ints keep their axis)."""

    @abc.abstractmethod
    def verify(self) -> None:
        """Check whatever backs the frames; ClodsError naming what is wrong."""


class FrameSelection(FrameArray):
    """Some frames and cameras of another frame array, read only when indexed: what stage 2 walks through frame by frame
    (a 300-frame, 25-camera paper video is 14 GB decoded; frame by frame it is one frame at a time).

    Reading one frame of every selected camera (`sel[t]`, the frame-by-frame pattern) reads the base array up to the end
    of its time chunk (`chunk_frames`, 1 for frames rendered on demand) and keeps that block, so walking the frames
    decodes each stored chunk once; any other selection is passed to the base array as it is."""

    def __init__(self, base: FrameArray, times: Index = slice(None), views: Index = slice(None)) -> None:
        self.base, self.path = base, base.path
        self.times = indices(times, base.shape[0], "time", base.path)
        self.views = indices(views, base.shape[1], "camera", base.path)
        self.shape = (len(self.times), len(self.views), *base.shape[2:])
        self.dtype = np.dtype(np.uint8)
        self._block: tuple[int, np.ndarray] | None = None  # (first selected frame, frames first.. of every selected camera)

    def read(self, times: Index, views: Index) -> np.ndarray:
        """(len(times), len(views), H, W, 3) of the selection (ints keep their axis)."""
        t_idx = indices(times, self.shape[0], "time", self.path)
        v_idx = indices(views, self.shape[1], "camera", self.path)
        if len(t_idx) == 1 and len(v_idx) == self.shape[1] and np.array_equal(v_idx, np.arange(self.shape[1])):
            return self._frame(int(t_idx[0]))[None]
        return self.base.read(self.times[t_idx], self.views[v_idx])

    def verify(self) -> None:
        self.base.verify()

    def _frame(self, t: int) -> np.ndarray:
        """Frame t of every selected camera, from the block held or a new block t..(end of its base chunk)."""
        if self._block is not None and 0 <= t - self._block[0] < len(self._block[1]):
            return self._block[1][t - self._block[0]]
        k = int(getattr(self.base, "chunk_frames", 1))
        stop = t + 1
        while stop < self.shape[0] and self.times[stop] == self.times[stop - 1] + 1 and self.times[stop] % k != 0:
            stop += 1  # the rest of the base chunk that holds frame t, while the selected frames run consecutively
        block = self.base.read(self.times[t:stop], self.views)
        self._block = (t, block)
        return block[0]


class LazyFrames(FrameArray):
    """Frames (T, N, H, W, 3) uint8 of one trajectory, decoded only where indexed.

    `frames[t0:t1, views]` reads the chunks of those cameras and frames only; the first two axes take an int,
    a slice or a list of indices, the rest any numpy index (applied after reading whole images). A list on
    both the time and the camera axis is refused (numpy would pair them up): use `read(times, views)`,
    which selects orthogonally (every listed frame of every listed camera).
    """

    def __init__(self, path: Path, record: dict[str, Any] | None = None) -> None:
        """Open the array at `path`; with the manifest `record`, its metadata is checked against it."""
        self.path = Path(path)
        if not self.path.is_dir():
            raise ClodsError("frame array missing", where=str(self.path), hint="re-run generation, or regenerate with --force")
        self._array = _open(self.path)
        if record is not None and record.get("sha256") is not None:
            digest = hashlib.sha256((self.path / "zarr.json").read_bytes()).hexdigest()
            if digest != record["sha256"]:
                raise ClodsError("zarr.json differs from the manifest (corrupted or replaced)", where=str(self.path / "zarr.json"), hint=_HINT)
        self.shape: tuple[int, ...] = tuple(int(s) for s in self._array.shape)
        self.dtype = np.dtype(np.uint8)
        self.chunk_frames = int(self._array.chunks[0])
        self.chunks_read = 0  # chunk files decoded by this object (what a selection cost)

    def read(self, times: Index, views: Index) -> np.ndarray:
        """(len(times), len(views), H, W, 3): every selected frame of every selected camera (ints keep their axis)."""
        t_idx = indices(times, self.shape[0], "time", self.path)
        v_idx = indices(views, self.shape[1], "camera", self.path)
        out = np.empty((len(t_idx), len(v_idx), *self.shape[2:]), np.uint8)
        k = self.chunk_frames
        for first, last in _runs(np.unique(t_idx // k)):  # consecutive time chunks: one zarr read each (decoded concurrently)
            lo, hi = first * k, min((last + 1) * k, self.shape[0])
            sel = np.nonzero((t_idx >= lo) & (t_idx < hi))[0]
            for j, view in enumerate(v_idx):
                out[sel, j] = self._span(first, last, int(view))[t_idx[sel] - lo]
        return out

    def verify(self) -> None:
        """Decode every chunk (checks each crc32c); ClodsError naming the first bad chunk file."""
        last = -(-self.shape[0] // self.chunk_frames) - 1
        for view in range(self.shape[1]):
            self._span(0, last, view)

    def _span(self, first: int, last: int, view: int) -> np.ndarray:
        """Time chunks first..last of camera `view`, decoded; a missing, truncated or corrupted chunk raises naming its file."""
        k = self.chunk_frames
        for tc in range(first, last + 1):  # zarr would fill a missing chunk with zeros: refuse instead
            path = self.path / chunk_key(tc, view)
            if not path.is_file():
                raise ClodsError(f"chunk file missing (frames {tc * k}..{min((tc + 1) * k, self.shape[0]) - 1} of camera {view})",
                                 where=str(path), hint=_HINT)  # fmt: skip
        try:
            block = np.asarray(self._array[first * k : min((last + 1) * k, self.shape[0]), view])
        except ImportError as exc:  # a codec's library is missing: the chunks are fine, the install is not
            raise ClodsError(f"cannot decode the frames: {exc}", where=str(self.path), hint="pip install imagecodecs") from None
        except Exception:  # zarr: ValueError on a crc32c mismatch, codec errors on truncated data; find the chunk
            for tc in range(first, last + 1):
                self._chunk(tc, view)
            raise
        self.chunks_read += last - first + 1
        return block

    def _chunk(self, tc: int, view: int) -> np.ndarray:
        """One decoded chunk; ClodsError naming its file when it cannot be decoded."""
        lo, hi = tc * self.chunk_frames, min((tc + 1) * self.chunk_frames, self.shape[0])
        try:
            return np.asarray(self._array[lo:hi, view])
        except Exception as exc:
            raise ClodsError(f"chunk failed its crc32c check or cannot be decoded (frames {lo}..{hi - 1} of camera {view}): "
                             f"{type(exc).__name__}: {exc}", where=str(self.path / chunk_key(tc, view)), hint=_HINT) from None  # fmt: skip


def _runs(chunks: np.ndarray) -> list[tuple[int, int]]:
    """Sorted chunk indices grouped into runs of consecutive ones, as (first, last) pairs."""
    runs: list[tuple[int, int]] = []
    for c in (int(c) for c in chunks):
        if runs and c == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], c)
        else:
            runs.append((c, c))
    return runs


def _is_basic(key: Any) -> bool:
    return isinstance(key, (int, np.integer, slice))


def indices(key: Index, size: int, axis: str, where: Path) -> np.ndarray:
    """`key` (int, slice or sequence, negatives allowed) as an int64 index array into range(size)."""
    if isinstance(key, slice):
        return np.arange(size)[key]
    idx = np.atleast_1d(np.asarray(key))
    if idx.dtype == bool:
        if idx.shape != (size,):
            raise ClodsError(f"boolean {axis} mask of length {idx.shape[0]}, axis has {size}", where=str(where))
        return np.nonzero(idx)[0]
    if idx.ndim != 1 or (idx.size and not np.issubdtype(idx.dtype, np.integer)):
        raise ClodsError(f"{axis} index must be an int, a slice or a 1-D list of ints, got {key!r}", where=str(where))
    idx = idx.astype(np.int64)
    if idx.size and (idx.min() < -size or idx.max() >= size):
        raise IndexError(f"{axis} index {key!r} out of range for {size} {axis} entries ({where})")
    return np.where(idx < 0, idx + size, idx)
