"""Atomic file writes: a file either appears complete or not at all (temp file + os.replace)."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Iterator

import numpy as np


def _read_umask() -> int:
    """The process umask (set back at once: os.umask can only be read by setting it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _read_umask()
"""Read once at import: os.umask is process-wide, and setting it while another thread creates a file would race."""


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path next to `path`; on success it replaces `path` in one rename.

    The file gets the mode a plain `open(path, "w")` would give it (an existing file's own mode, else 0o666 less the
    umask), not mkstemp's private 0o600: results and run records are read by other users (a shared runs_dir, a web
    server for the report)."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        mode = target.stat().st_mode & 0o7777
    except OSError:
        mode = 0o666 & ~_UMASK
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp" + target.suffix, dir=target.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    with contextlib.suppress(OSError):  # a filesystem without POSIX modes (a vfat mount) keeps what it has
        os.chmod(tmp_path, mode)
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp_path, target)
    except Exception as exc:
        full = _disk_full(exc, target)
        if full is None or full is exc:
            raise
        raise full from exc
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


FULL_BELOW = 1 << 20
"""A write that failed while its file system had fewer free bytes than this failed for lack of space."""


def _disk_full(exc: Exception, target: Path) -> OSError | None:
    """The error to raise for a write of `target` that failed for lack of space, naming `target`: `exc` itself when it
    is an ENOSPC/EDQUOT OSError (with `target` as its filename where it had none); an OSError(ENOSPC) when another
    exception (torch's zip writer says 'unexpected pos ...') was raised while the file system is full; else None."""
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        if not exc.filename:
            exc.filename = str(target)
        return exc
    try:
        free = shutil.disk_usage(target.parent).free
    except OSError:
        return None
    if free < FULL_BELOW:
        return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(target))  # raised from `exc`, which --debug shows
    return None


def write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write a text file atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_json(path: str | os.PathLike[str], obj: Any) -> None:
    """Write JSON atomically (sorted keys, indented, NaN written as null)."""
    write_text(path, json.dumps(_jsonable(obj), indent=2, sort_keys=True) + "\n")


def write_npz(path: str | os.PathLike[str], compress: bool = True, **arrays: np.ndarray) -> None:
    """Write an .npz atomically, deflated unless `compress` is off (for a file rewritten often: float arrays deflate by
    a few per cent at about 45x the cost)."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            (np.savez_compressed if compress else np.savez)(fh, **arrays)


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        value = float(obj)
        return value if np.isfinite(value) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj


@contextlib.contextmanager
def file_lock(path: str | os.PathLike[str]) -> Iterator[None]:
    """Hold an exclusive advisory lock on `path` (created if missing) for the block; waits for other holders.

    Guards cache entries that parallel jobs may compute at the same moment (the same stage-1 fit,
    extraction or simulator fit): the second job waits and then reads what the first one wrote,
    instead of computing it again. POSIX `flock`; where it does not exist the block runs unlocked.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - non-POSIX
        yield
        return
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    with open(target, "a+") as fh:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
