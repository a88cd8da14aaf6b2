"""Stage digests: canonical bytes (key order, float bits, dtype and shape), collection per seed job, fitted state."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import torch

from clods_bench.benchmark.core import stage_digests
from clods_bench.benchmark.core.stage_digests import STAGES, collecting, fitted_state, record


def _digest(stage: str, *values: object) -> str:
    with collecting() as d:
        for v in values:
            record(stage, v)
    return d.result()[stage]


def test_a_digest_is_the_sha256_of_the_documented_bytes() -> None:
    """An int and a float64 array hash exactly as the canonical layout says (type tag, dtype, shape, raw bytes)."""
    arr = np.arange(3, dtype=np.float64)
    h = hashlib.sha256(b"I7")
    h.update(b"A" + arr.dtype.str.encode() + str(arr.shape).encode())
    h.update(arr.tobytes())
    assert _digest("fit", 7, arr) == h.hexdigest()[:16]


def test_mapping_order_does_not_matter_but_values_dtypes_and_shapes_do() -> None:
    a = {"x": 1.0, "y": np.zeros(2, np.float32)}
    b = {"y": np.zeros(2, np.float32), "x": 1.0}
    assert _digest("score", a) == _digest("score", b)
    assert _digest("score", {"x": 1.0}) != _digest("score", {"x": np.nextafter(1.0, 2.0)})  # one ulp
    assert _digest("score", np.zeros(2, np.float32)) != _digest("score", np.zeros(2, np.float64))
    assert _digest("score", np.zeros((2, 1))) != _digest("score", np.zeros((1, 2)))
    assert _digest("score", float("nan")) == _digest("score", float("nan"))  # NaN metrics compare equal
    assert _digest("rollout", torch.ones(3)) == _digest("rollout", np.ones(3, np.float32))


def test_nothing_is_recorded_outside_a_collection_and_stages_come_in_pipeline_order() -> None:
    record("fit", 1)  # no collection: ignored, no error
    with collecting() as d:
        record("score", 1.0)
        record("data", "abc")
    assert list(d.result()) == ["data", "score"] and STAGES.index("data") < STAGES.index("score")
    with pytest.raises(ValueError, match="unknown stage"):
        with collecting():
            record("training", 1)


def test_fitted_state_finds_modules_and_arrays_two_levels_down() -> None:
    class Renderer:
        def __init__(self) -> None:
            self.config = {"lr": 0.1}  # plain numbers: not learned state
            self.params = {"means": torch.zeros(2, 3), "colors": torch.ones(2, 3)}
            self.model = torch.nn.Linear(2, 2)

    r = Renderer()
    state = fitted_state(r)
    assert set(state) == {"params", "model"} and set(state["params"]) == {"colors", "means"}
    before = _digest("fit", r)
    with torch.no_grad():
        r.params["means"][0, 0] = 1e-7
    assert _digest("fit", r) != before
    assert fitted_state(object()) == {} and stage_digests.fitted_state(torch.nn.Linear(1, 1)).keys() == {"weight", "bias"}
