"""Content hashes sealed into the files a later step trusts, checked when those files are read.

A seal is written in the same atomic rename as the file it protects, so a file and its hash never disagree by
accident; a mismatch means the file changed after it was written, and it is reported in one line naming the file and
what to do, never used:

- zip containers (numpy `.npz`, PyTorch `.pt` checkpoints and caches): the archive comment holds
  `clods-sha256:<64 hex>`, the SHA-256 of the file's bytes before the comment was added (zip readers skip comments);
- JSON documents (`result.json`, `record.json`, `content_digest.json`): the key `content_sha256` holds the SHA-256
  of the document's canonical JSON (sorted keys, no spaces) without that key;
- files whose hash is kept elsewhere (a dataset's arrays: the manifest's sha256 records): `check_sha256`.

Files written before seals existed carry none and are read as before. A file is hashed at most once per process:
a verified file is remembered by (path, size, inode, status-change time), so reading it again costs one `stat`
(the status-change time moves with every write, rename or copy onto the path, and no tool can set it back).
`$CLODS_BENCH_INTEGRITY_LOG` (a file path; for measuring the checks' cost only) appends one line per hash computed
and per dataset check: `<kind> <seconds> <bytes>` (kinds: seal, seal-json, json, check-zip, check-file,
dataset-files; a dataset check's line includes the check-file hashes it made).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import time
from pathlib import Path
from typing import Any, Iterator

from clods_bench.atomic import _jsonable, atomic_path
from clods_bench.errors import ClodsError

SEAL_PREFIX = b"clods-sha256:"
SEAL_BYTES = len(SEAL_PREFIX) + 64
JSON_KEY = "content_sha256"
LOG_ENV = "CLODS_BENCH_INTEGRITY_LOG"
_EOCD = b"PK\x05\x06"  # a zip's end-of-central-directory record: 22 bytes, then the comment
_BLOCK = 1 << 22

_sealed_ok: dict[str, tuple[int, int, int]] = {}
"""Per process: absolute path -> `_stamp` of zip files whose seal was checked (or that have none)."""
_hashes: dict[str, tuple[tuple[int, int, int], str]] = {}
"""Per process: absolute path -> (stat key, SHA-256 of its bytes) of files `check_sha256` hashed."""


def changed(path: str | os.PathLike[str], remedy: str, recorded: str = "written with it") -> ClodsError:
    """The one-line error of a file whose content differs from the hash `recorded` for it."""
    return ClodsError(f"content differs from the SHA-256 {recorded}: the file was changed or damaged after it was written",
                      where=str(path), hint=remedy)  # fmt: skip


# ------------------------------------------------------------------ zip containers


def seal_zip(path: str | os.PathLike[str]) -> str:
    """Append the seal (SHA-256 of the file as it is) as the zip comment of `path`, a comment-less zip; return the hash.
    Call it on the temp file inside `atomic_path`, so the seal lands in the same rename as the file."""
    target = Path(path)
    size = target.stat().st_size
    with open(target, "rb") as fh:
        fh.seek(max(0, size - 22))
        tail = fh.read()
    if size < 22 or tail[:4] != _EOCD or tail[-2:] != b"\x00\x00":
        raise ValueError(f"{target}: not a zip file without a comment; cannot seal it")
    digest = _hash_file(target, size, "seal")
    with open(target, "r+b") as fh:
        fh.seek(size - 2)
        fh.write(SEAL_BYTES.to_bytes(2, "little") + SEAL_PREFIX + digest.encode())
    return digest


def check_zip(path: str | os.PathLike[str], remedy: str) -> None:
    """Raise the one-line `changed` error unless `path`'s content matches its seal (an unsealed file passes)."""
    target = Path(path)
    stat = target.stat()
    key, skey = os.path.abspath(target), _stamp(stat)
    if _sealed_ok.get(key) == skey:
        return
    size = stat.st_size
    with open(target, "rb") as fh:
        fh.seek(max(0, size - SEAL_BYTES - 22))
        tail = fh.read()
    sealed, eocd = tail[-SEAL_BYTES:], tail[:22]
    has_seal = len(tail) == SEAL_BYTES + 22 and sealed.startswith(SEAL_PREFIX)
    has_end = len(tail) == SEAL_BYTES + 22 and eocd[:4] == _EOCD and int.from_bytes(eocd[-2:], "little") == SEAL_BYTES
    if not has_seal and not has_end:
        _sealed_ok[key] = skey  # written before seals: read as before
        return
    if not (has_seal and has_end):  # one of the two damaged: the seal's prefix, or the zip end record that frames it
        raise changed(target, remedy, "written with it (its zip end record is damaged)")
    want = sealed[len(SEAL_PREFIX):].decode("ascii", "replace")
    got = _hash_file(target, size - SEAL_BYTES - 2, "check-zip", suffix=b"\x00\x00")
    if got != want:
        raise changed(target, remedy)
    _sealed_ok[key] = skey


def write_npz(path: str | os.PathLike[str], compress: bool = True, **arrays: Any) -> None:
    """`atomic.write_npz` with a seal: the arrays, deflated unless `compress` is off, and their hash in one rename."""
    import numpy as np

    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            (np.savez_compressed if compress else np.savez)(fh, **arrays)
        seal_zip(tmp)


def save_torch(obj: Any, path: str | os.PathLike[str]) -> None:
    """`torch.save(obj)` to `path` with a seal, in one atomic rename (a crash leaves the previous file intact)."""
    import torch

    with atomic_path(path) as tmp:
        torch.save(obj, tmp)
        seal_zip(tmp)


# ------------------------------------------------------------------ JSON documents


def seal_json(doc: dict[str, Any]) -> dict[str, Any]:
    """`doc` as `atomic.write_json` writes it (NaN as null), with `content_sha256` over the rest."""
    t0 = time.perf_counter()
    clean = _jsonable({k: v for k, v in doc.items() if k != JSON_KEY})
    clean[JSON_KEY] = _json_hash(clean)
    _log("seal-json", time.perf_counter() - t0, 0)
    return clean


def check_json(doc: dict[str, Any], path: str | os.PathLike[str], remedy: str) -> dict[str, Any]:
    """`doc` (read from `path`) if its `content_sha256` matches, or has none (written before seals); else the
    one-line `changed` error."""
    want = doc.get(JSON_KEY)
    if want is None:
        return doc
    t0 = time.perf_counter()
    got = _json_hash({k: v for k, v in doc.items() if k != JSON_KEY})
    _log("json", time.perf_counter() - t0, 0)
    if got != want:
        raise changed(path, remedy)
    return doc


def read_json(path: str | os.PathLike[str], remedy: str) -> dict[str, Any]:
    """A sealed (or seal-less) JSON object from `path`, checked; malformed JSON is one error naming the file."""
    try:
        doc = json.loads(Path(path).read_text())
    except json.JSONDecodeError as exc:
        raise ClodsError(f"malformed JSON at line {exc.lineno}: {exc.msg}", where=str(path), hint=remedy) from None
    if not isinstance(doc, dict):
        raise ClodsError(f"expected a JSON object, got {type(doc).__name__}", where=str(path), hint=remedy)
    return check_json(doc, path, remedy)


def _json_hash(doc: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


# ------------------------------------------------------------------ hashes kept elsewhere


def check_sha256(path: str | os.PathLike[str], expected: str, remedy: str, recorded: str = "recorded for it") -> None:
    """Raise the one-line `changed` error unless the SHA-256 of `path`'s bytes is `expected` (hashed once per process
    while the file's size, inode and status-change time stay)."""
    target = Path(path)
    stat = target.stat()
    key, skey = os.path.abspath(target), _stamp(stat)
    known = _hashes.get(key)
    got = known[1] if known is not None and known[0] == skey else _hash_file(target, stat.st_size, "check-file")
    _hashes[key] = (skey, got)
    if got != expected:
        raise changed(target, remedy, recorded)


def _stamp(stat: os.stat_result) -> tuple[int, int, int]:
    """What changes when a file's content may have: its size, inode and status-change time (ctime)."""
    return (stat.st_size, stat.st_ino, stat.st_ctime_ns)


def forget(path: str | os.PathLike[str] | None = None) -> None:
    """Drop what this process remembers of `path` (every file when None): its next check hashes it again."""
    if path is None:
        _sealed_ok.clear()
        _hashes.clear()
    else:
        _sealed_ok.pop(os.path.abspath(Path(path)), None)
        _hashes.pop(os.path.abspath(Path(path)), None)


def _hash_file(path: Path, length: int, kind: str, suffix: bytes = b"") -> str:
    """SHA-256 of the first `length` bytes of `path` followed by `suffix`."""
    t0 = time.perf_counter()
    h = hashlib.sha256()
    left = length
    with open(path, "rb") as fh:
        while left > 0:
            block = fh.read(min(_BLOCK, left))
            if not block:
                break
            h.update(block)
            left -= len(block)
    h.update(suffix)
    _log(kind, time.perf_counter() - t0, length)
    return h.hexdigest()


@contextlib.contextmanager
def timed(kind: str) -> Iterator[None]:
    """Log the block's wall time under `kind` in $CLODS_BENCH_INTEGRITY_LOG, when set (checks made of more than hashes)."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        _log(kind, time.perf_counter() - t0, 0)


def _log(kind: str, seconds: float, nbytes: int) -> None:
    """One line in $CLODS_BENCH_INTEGRITY_LOG, when set (a measurement of the checks' cost; off otherwise)."""
    target = os.environ.get(LOG_ENV)
    if target:
        fd = os.open(target, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, f"{kind} {seconds:.9f} {nbytes}\n".encode())
        finally:
            os.close(fd)
