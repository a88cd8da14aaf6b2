"""The replacement kernels against ATen's own, on PyTorch's OpInfo samples: same shapes, dtypes, strides, errors and
gradients, values to each dtype's tolerance.

The test session runs inside `numerics.exact()`, so every call here reaches the replacements; the same calls (saved
with `torch.save`) run once more in a fresh Python with the same pins and no exact scope (`aten_reference`), where
they reach ATen's kernels. Samples: OpInfo's `sample_inputs` for each replaced operator over every dtype it lists as
CPU-supported, in the function, method, in-place and `out=` forms, and the same values non-contiguous, transposed and
as conjugate views; plus 0-d, empty, channels-last, expanded and non-dense inputs, broadcast `self` terms, nn.Linear's
bias row, and calls ATen refuses. Gradients of a random weighting of the output are compared for float64 samples.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import pytest
import torch

from clods_bench.numerics import exact_math, exact_matmul
from tests.numerics import aten_reference as ref

UNARY = tuple(exact_math.REPLACED)
PRODUCTS = tuple(exact_matmul.REPLACED)
DEFAULT_TOLERANCES = {torch.float16: (1e-3, 1e-5), torch.bfloat16: (1.6e-2, 1e-5), torch.float32: (1.3e-6, 1e-5),
                      torch.float64: (1e-7, 1e-7), torch.complex64: (1.3e-6, 1e-5), torch.complex128: (1e-7, 1e-7)}  # fmt: skip
"""`torch.testing.assert_close`'s defaults (rtol, atol); a product's absolute tolerance is widened by its case's
`slack`, the rounding a sum of its size may show in another order (`opinfo_cases._slack`)."""


@pytest.fixture(scope="module")
def sweep() -> list[tuple[dict[str, Any], dict[str, Any], dict[str, Any]]]:
    """(case, the replacements' record, ATen's record) for every case: ATen's computed in a child meanwhile."""
    assert exact_math.installed() and exact_matmul.installed(), "the test session runs inside numerics.exact()"
    with tempfile.TemporaryDirectory() as tmp:
        cases, want = ref.reference_of_built("tests.numerics.opinfo_cases:build", Path(tmp))
    return list(zip(cases, ref.run(cases), want))


def _compare_records(what: str, got: dict[str, Any], want: dict[str, Any], slack: float = 0.0) -> list[str]:
    """Shape, dtype, strides (where ATen's are dense) and values to the dtype's default tolerance (its absolute
    tolerance widened by `slack`)."""
    for key in ("shape", "dtype", "conj"):
        if got[key] != want[key]:
            return [f"{what}: {key} {got[key]} where ATen gives {want[key]}"]
    if want["dense"] and got["stride"] != want["stride"]:
        return [f"{what}: strides {got['stride']} where ATen gives {want['stride']}"]
    try:
        rtol, atol = DEFAULT_TOLERANCES.get(want["dtype"], (0.0, 0.0))
        torch.testing.assert_close(got["value"], want["value"], rtol=rtol, atol=atol + slack, equal_nan=True, check_stride=False)
    except AssertionError as exc:
        return [f"{what}: values differ: {' '.join(str(exc).split())[:300]}"]
    return []


def _differences(case: dict[str, Any], got: dict[str, Any], want: dict[str, Any]) -> list[str]:
    """What differs between the replacement's record of a case and ATen's."""
    where = case["label"] if case["kind"] == "optim" else f"{case['name']} {case['form']} {case['dtype']} {case['label']}"
    if got["error"] is not None or want["error"] is not None:
        if got["error"] is None or want["error"] is None or got["error"][0] != want["error"][0]:
            return [f"{where}: {got['error'] or 'no error'} where ATen gives {want['error'] or 'no error'}"]
        return []
    if case["kind"] == "optim":
        return [d for i, (gs, ws) in enumerate(zip(got["steps"], want["steps"])) for g, w in zip(gs, ws)
                for d in _compare_records(f"{where} step {i + 1}", g, w)]  # fmt: skip
    out = _compare_records(where, got["result"], want["result"], case.get("slack", 0.0))
    for key in ("returns_out", "returns_self"):
        if got.get(key) != want.get(key):
            out.append(f"{where}: {key} {got.get(key)} where ATen gives {want.get(key)}")
    for i, (g, w) in enumerate(zip(got.get("grads", []), want.get("grads", []))):
        if (g is None) != (w is None):
            out.append(f"{where}: gradient {i} {g is None and 'missing'} where ATen's is {w is None and 'missing'}")
        elif g is not None:
            out.extend(_compare_records(f"{where} gradient {i}", g, w, case.get("slack", 0.0)))
    return out


@pytest.mark.parametrize("name", UNARY + PRODUCTS)
def test_kernels_match_atens_shapes_dtypes_strides_errors_values_and_gradients(name: str, sweep: list[Any]) -> None:
    diffs = [d for case, got, want in sweep if case["kind"] == "call" and case["name"] == name for d in _differences(case, got, want)]
    assert not diffs, f"{len(diffs)} differences from ATen, the first:\n" + "\n".join(diffs[:25])


def test_the_sweep_covers_what_the_kernels_must_handle(sweep: list[Any]) -> None:
    """Every form, the integer and half types, 0-d, empty, broadcast, strided and conjugate inputs, refused calls,
    and gradients: each reaches both sides for every operator (a shrunken sample set would pass silently)."""
    for name in UNARY + PRODUCTS:
        mine = [(case, want) for case, _, want in sweep if case["kind"] == "call" and case["name"] == name]
        forms = {case["form"] for case, _ in mine}
        assert forms >= {"function", "method", "out"} | ({"inplace"} if name not in ("mm", "bmm") else set()), name
        dtypes = {case["dtype"] for case, _ in mine}
        assert {torch.float16, torch.bfloat16, torch.int64, torch.uint8, torch.complex64} <= dtypes, name
        labels = " | ".join(case["label"] for case, _ in mine)
        for feature in ("non-contiguous", "transposed", "conjugate", "empty out", "transposed out", "integer out"):
            assert feature in labels, (name, feature)
        extras = ("0-d", "empty", "channels-last", "expanded", "non-dense") if name in UNARY else ("error: bool",)
        extras += {"addmm": ("self (3,)", "self ()", "expanded bias"), "baddbmm": ("self (3,)", "self ()", "expanded bias"),
                   "mm": ("plain",), "bmm": ("plain",)}.get(name, ())  # fmt: skip
        for feature in extras:
            assert feature in labels, (name, feature)
        assert any(want["error"] for _, want in mine) and any(not want["error"] for _, want in mine), name
        assert any(want.get("grads") for _, want in mine), name


@pytest.mark.parametrize("optimizer", ["Adam", "AdamW", "SGD"])
def test_optimizers_step_like_aten_on_0d_1d_and_nd_parameters(optimizer: str, sweep: list[Any]) -> None:
    """Adam's and AdamW's steps divide by `torch.sqrt` (the replacement, for single tensors and `_foreach_sqrt`)."""
    runs = [(case, got, want) for case, got, want in sweep if case["kind"] == "optim" and case["optimizer"] == optimizer]
    assert runs
    for case, got, want in runs:
        assert got["error"] is None and want["error"] is None, (case["label"], got["error"], want["error"])
        assert [r["shape"] for r in got["steps"][-1]] == [(), (5,), (3, 4, 2)]
        assert not _differences(case, got, want)
        assert not any(torch.equal(r["value"], p) for r, p in zip(got["steps"][-1], case["params"]))  # they moved
