"""Run torch calls described as data and record what they give, so that ATen's own kernels (in a fresh Python, outside
the exact scope) and the replacements (inside it) can be compared call for call.

A case is a dict: `kind` "call" (`name`, `form` of "function", "method", "inplace" or "out", `args`, `kwargs`, `out`,
`grad`: the positions of the arguments to differentiate, `seed` of the random weighting of the output) or "optim"
(`optimizer`, `options`, `params`, `grads`: one list of gradients per step). `reference(cases)` computes the records
in a child process, with the pins this process has, and never inside `numerics.exact()`; `reference_of_built` has
the child make the cases too.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Any

import torch
from torch._prims_common import is_non_overlapping_and_dense_or_false

ROOT = Path(__file__).resolve().parents[2]


def fresh(value: Any) -> Any:
    """`value` with tensors given storage of their own (the same sizes, strides, offset and conjugate / negative bits,
    so that in-place and `out=` calls change nothing another case sees); other values as they are."""
    if isinstance(value, (list, tuple)):
        return type(value)(fresh(v) for v in value)
    if not isinstance(value, torch.Tensor):
        return value
    t = value.detach()
    plain = torch.empty(0, dtype=t.dtype).set_(t.untyped_storage().clone(), t.storage_offset(), t.size(), t.stride())
    if t.is_conj():
        plain = plain.conj()
    if t.is_neg():
        plain = torch._neg_view(plain)
    return plain


def record(t: torch.Tensor) -> dict[str, Any]:
    """What a result is: shape, dtype, strides, whether it is non-overlapping and dense, and its values."""
    return {"shape": tuple(t.shape), "dtype": t.dtype, "stride": t.stride(), "dense": is_non_overlapping_and_dense_or_false(t),
            "conj": t.is_conj(), "value": t.detach().resolve_conj().resolve_neg().clone()}  # fmt: skip


def _function(case: dict[str, Any]) -> Any:
    """The torch callable a case names."""
    name, form = case["name"], case["form"]
    if form in ("function", "out"):
        return getattr(torch, name)
    return getattr(torch.Tensor, name + "_" if form == "inplace" else name)


def _call(case: dict[str, Any]) -> dict[str, Any]:
    """Run one call and record its result, its `out=` tensor, its error, and the gradients of a random weighting."""
    args, kwargs = fresh(case["args"]), {k: fresh(v) for k, v in case["kwargs"].items()}
    leaves = [args[i].requires_grad_() for i in case.get("grad", ())]
    if case["form"] == "out":
        kwargs["out"] = fresh(case["out"])
    try:
        with warnings.catch_warnings():  # "An output with one or more elements was resized": what the test checks
            warnings.simplefilter("ignore")
            result = _function(case)(*args, **kwargs)
    except Exception as exc:  # noqa: BLE001 - the error itself is the record
        return {"error": (type(exc).__name__, str(exc).strip().splitlines()[0] if str(exc).strip() else "")}
    rec: dict[str, Any] = {"error": None, "result": record(result)}
    if case["form"] == "out":
        rec["returns_out"] = result is kwargs["out"]
    if case["form"] == "inplace":
        rec["returns_self"] = result is args[0]
    if leaves:
        weight = torch.randn(result.shape, generator=torch.Generator().manual_seed(case["seed"]), dtype=result.dtype)
        grads = torch.autograd.grad((result * weight).sum(), leaves, allow_unused=True)
        rec["grads"] = [None if g is None else record(g) for g in grads]
    return rec


def _optimise(case: dict[str, Any]) -> dict[str, Any]:
    """Step an optimizer over the case's gradients and record the parameters after each step."""
    params = [fresh(p).requires_grad_() for p in case["params"]]
    try:
        opt = getattr(torch.optim, case["optimizer"])(params, **case["options"])
        steps = []
        for grads in case["grads"]:
            for p, g in zip(params, grads):
                p.grad = fresh(g)
            opt.step()
            steps.append([record(p) for p in params])
    except Exception as exc:  # noqa: BLE001 - the error itself is the record
        return {"error": (type(exc).__name__, str(exc).strip().splitlines()[0])}
    return {"error": None, "steps": steps}


def run(cases: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The record of every case, computed by this process's kernels."""
    return [_optimise(c) if c["kind"] == "optim" else _call(c) for c in cases]


_CHILD = """
from clods_bench import numerics
numerics.pin_environment()
import importlib, sys, torch
from clods_bench.numerics import exact_math, exact_matmul, scope
from tests.numerics import aten_reference as ref
assert not (scope.active() or exact_math.installed() or exact_matmul.installed())
source, target, build = sys.argv[1:4]
if build:
    module, _, function = build.partition(":")
    cases = getattr(importlib.import_module(module), function)()
    torch.save(cases, source)
else:
    cases = torch.load(source, weights_only=False)
torch.save(ref.run(cases), target)
"""


def _child(folder: Path, build: str = "") -> tuple[Path, Path]:
    """Run a fresh Python that computes the records of the cases in folder/cases.pt (or first makes them there with
    `build`, "module:function") with ATen's kernels: the pins of this process, no exact scope."""
    source, target = folder / "cases.pt", folder / "aten.pt"
    out = subprocess.run([sys.executable, "-c", _CHILD, str(source), str(target), build], cwd=ROOT, env=dict(os.environ),
                         capture_output=True, text=True, timeout=300)  # fmt: skip
    if out.returncode != 0:
        raise RuntimeError(f"the ATen reference process failed:\n{out.stderr[-3000:]}")
    return source, target


def reference(cases: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The records of `cases` computed by ATen's own kernels in a fresh Python."""
    with tempfile.TemporaryDirectory() as tmp:
        torch.save(cases, Path(tmp) / "cases.pt")
        _, target = _child(Path(tmp))
        return torch.load(target, weights_only=False)


def reference_of_built(build: str, folder: Path) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The cases `build` ("module:function") makes in a fresh Python, and their records by ATen's kernels there: what
    makes the cases (torch's OpInfo database, say) is never imported into this process."""
    source, target = _child(folder, build)
    return torch.load(source, weights_only=False), torch.load(target, weights_only=False)
