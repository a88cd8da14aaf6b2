"""Content digests of a seed's stages (data, renderer fit, extraction, fit, rollout, score), for exact comparisons.

A seed job collects, in order, a SHA-256 per stage of everything that stage produced: the dataset it read, the
fitted renderer's parameters (CloDS stage 1, NVS), the meshes it extracted (stage 2, stage 0), the trained
simulator's or video predictor's weights, every rollout or prediction, and the metrics. Two runs of one row then
agree stage by stage or name the first stage where they part, e.g. "equal data, equal extraction, different fit":
where a cross-host difference enters. Nothing is recorded outside `collecting()` (library use, benches).
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import math
import struct
from typing import Any, Iterator, Mapping

STAGES = ("data", "renderer fit", "extraction", "fit", "rollout", "score")
"""The stages in pipeline order: a comparison names the first that differs."""


class StageDigests:
    """Running SHA-256 hashes, one per stage, fed in call order."""

    def __init__(self) -> None:
        self._hashes = {stage: hashlib.sha256() for stage in STAGES}
        self._used: set[str] = set()

    def add(self, stage: str, value: Any) -> None:
        if stage not in self._hashes:
            raise ValueError(f"unknown stage {stage!r}; one of {STAGES}")
        _feed(self._hashes[stage], value)
        self._used.add(stage)

    def result(self) -> dict[str, str]:
        """{stage: 16 hex digits} for the stages that saw anything, in pipeline order."""
        return {s: self._hashes[s].hexdigest()[:16] for s in STAGES if s in self._used}


_current: contextvars.ContextVar[StageDigests | None] = contextvars.ContextVar("clods_bench_stage_digests", default=None)


@contextlib.contextmanager
def collecting() -> Iterator[StageDigests]:
    """Collect the `record` calls made inside the block (one seed job)."""
    digests = StageDigests()
    token = _current.set(digests)
    try:
        yield digests
    finally:
        _current.reset(token)


def record(stage: str, value: Any) -> None:
    """Feed `value` (arrays, tensors, a fitted model, numbers, nested dicts/lists) into `stage`'s digest, if collecting."""
    digests = _current.get()
    if digests is not None:
        digests.add(stage, value)


def fitted_state(obj: Any) -> Any:
    """What identifies a fitted plugin object: its `state_dict()`, else the torch modules, tensors and arrays among its
    attributes (in dicts and lists too, two levels down), by attribute name. Plugins without learned state digest to
    the same empty value."""
    if hasattr(obj, "state_dict") and callable(obj.state_dict):
        return obj.state_dict()
    found = _learned(vars(obj) if hasattr(obj, "__dict__") else {}, depth=2)
    return {} if found is None else found


def _learned(value: Any, depth: int) -> Any:
    """The learned content of an attribute value (None: nothing learned in it)."""
    if hasattr(value, "state_dict") and callable(value.state_dict):
        return value.state_dict()
    if _is_array(value):
        return value
    if depth <= 0:
        return None
    if isinstance(value, Mapping):
        items = {str(k): _learned(v, depth - 1) for k, v in value.items()}
        kept = {k: v for k, v in sorted(items.items()) if v is not None}
        return kept or None
    if isinstance(value, (list, tuple)):
        kept_list = [_learned(v, depth - 1) for v in value]
        return kept_list if any(v is not None for v in kept_list) else None
    return None


def _is_array(value: Any) -> bool:
    return hasattr(value, "dtype") and hasattr(value, "shape")


def _feed(h: "hashlib._Hash", value: Any) -> None:
    """Canonical bytes of `value`: type tag, shape and dtype of arrays, keys of mappings (sorted), IEEE bits of floats."""
    if value is None:
        h.update(b"N")
    elif isinstance(value, bool):
        h.update(b"B1" if value else b"B0")
    elif isinstance(value, int):
        h.update(b"I" + str(value).encode())
    elif isinstance(value, float):
        h.update(b"F" + (b"nan" if math.isnan(value) else struct.pack("<d", value)))
    elif isinstance(value, str):
        h.update(b"S" + value.encode() + b"\0")
    elif isinstance(value, Mapping):
        h.update(b"M%d" % len(value))
        for key in sorted(value, key=str):
            _feed(h, str(key))
            _feed(h, value[key])
    elif isinstance(value, (list, tuple)):
        h.update(b"L%d" % len(value))
        for item in value:
            _feed(h, item)
    elif _is_array(value):
        import numpy as np

        arr = value.detach().cpu().numpy() if hasattr(value, "detach") else np.asarray(value)
        arr = np.ascontiguousarray(arr)
        h.update(b"A" + arr.dtype.str.encode() + str(arr.shape).encode())
        h.update(arr.tobytes())
    else:
        _feed(h, fitted_state(value))
