"""The cases `test_aten_semantics` runs inside the exact scope and ATen runs outside it: PyTorch's OpInfo samples of
the replaced operators, with more layouts, shapes and refused calls, in every form; and optimizer steps.

`build()` runs in the reference child process (`aten_reference`), never in the test session: importing PyTorch's
OpInfo database freezes torch's backend flags (`torch.backends.disable_global_flags()`) and may start CUDA, which
the rest of a test session must not inherit. The cases travel to the session with `torch.save`.
"""

from __future__ import annotations

from typing import Any, Iterator

import torch
from torch.testing import make_tensor

from clods_bench.numerics import exact_math, exact_matmul

UNARY = tuple(exact_math.REPLACED)
PRODUCTS = tuple(exact_matmul.REPLACED)
Sample = tuple[list[Any], dict[str, Any], str, tuple[int, ...]]  # args, kwargs, label, positions to differentiate


def _tensor(shape: tuple[int, ...], dtype: torch.dtype, low: float = 0.05, high: float = 0.95) -> torch.Tensor:
    """Values inside every replaced function's domain (integers: 0 to 3, so some fall outside it)."""
    if dtype.is_floating_point or dtype.is_complex:
        return make_tensor(shape, dtype=dtype, device="cpu", low=low, high=high)
    return make_tensor(shape, dtype=dtype, device="cpu", low=0, high=4)


def _opinfo_samples(op: Any, dtype: torch.dtype) -> Iterator[Sample]:
    """OpInfo's samples (those that require grad for float64, which autograd then checks)."""
    grad = dtype == torch.float64 and op.supports_autograd
    for s in op.sample_inputs("cpu", dtype, requires_grad=grad):
        args = [s.input, *s.args]
        wrt = tuple(i for i, a in enumerate(args) if isinstance(a, torch.Tensor) and a.requires_grad)
        yield [a.detach() if isinstance(a, torch.Tensor) else a for a in args], dict(s.kwargs), "opinfo", wrt


def _unary_extras(dtype: torch.dtype) -> Iterator[Sample]:
    """Layouts and shapes OpInfo's unary samples lack."""
    grad = (0,) if dtype == torch.float64 else ()
    yield [_tensor((), dtype)], {}, "0-d", grad
    yield [_tensor((0, 3), dtype)], {}, "empty", grad
    yield [_tensor((2, 3, 4, 5), dtype).to(memory_format=torch.channels_last)], {}, "channels-last", grad
    yield [_tensor((1, 5), dtype).expand(3, 5)], {}, "expanded", grad
    yield [_tensor((6, 8), dtype)[::2].t()], {}, "non-dense transposed", grad
    yield [_tensor((3, 4, 5), dtype).permute(2, 0, 1)], {}, "permuted", grad


def _product_extras(name: str, dtype: torch.dtype) -> Iterator[Sample]:
    """Broadcast `self` terms, nn.Linear's bias row, and calls ATen refuses."""
    grad3 = (0, 1, 2) if dtype == torch.float64 else ()
    batch = (2,) if name in ("bmm", "baddbmm") else ()
    a, b = _tensor((*batch, 5, 7), dtype), _tensor((*batch, 7, 3), dtype)
    if dtype == torch.float32:  # bool, which ATen's products do not take
        flags = [t > 0.5 for t in (_tensor((*batch, 5, 3), dtype), a, b)]
        yield flags[(1 if name in ("mm", "bmm") else 0):], {}, "error: bool", ()
    if name in ("mm", "bmm"):
        yield [a, b], {}, "plain", grad3[:2]
        yield [a, _tensor((*batch, 6, 3), dtype)], {}, "error: inner sizes differ", ()
        yield [a[0] if batch else a[None], b], {}, "error: wrong rank", ()
        other = {torch.float64: torch.float32, torch.complex64: torch.complex128, torch.complex128: torch.complex64}
        yield [a, b.to(other.get(dtype, torch.float64))], {}, "error: mixed dtypes", ()
        return
    one = 1 if not (dtype.is_floating_point or dtype.is_complex) else 1.0
    for shape in [(3,), (1, 3), (5, 1), (*batch, 5, 3), ()]:
        yield [_tensor(batch[:0] + shape, dtype), a, b], {}, f"self {shape}", grad3
        yield [_tensor(shape, dtype), a, b], {"beta": 2 * one, "alpha": 3 * one}, f"self {shape}, beta 2, alpha 3", grad3
    yield [_tensor((3,), dtype).expand(*batch, 5, 3), a, b], {}, "expanded bias", grad3
    yield [_tensor((1, 3), dtype), a, b], {"beta": one, "alpha": one}, "bias row, explicit beta alpha", grad3
    if dtype.is_floating_point:
        yield [torch.full((*batch, 5, 3), float("nan"), dtype=dtype), a, b], {"beta": 0.0}, "beta 0 ignores NaN self", ()
    else:
        yield [_tensor((3,), dtype), a, b], {"alpha": 0.5}, "error: float alpha, integer tensors", ()
    yield [_tensor((4,), dtype), a, b], {}, "error: self does not broadcast", ()
    other = {torch.float64: torch.float32, torch.complex64: torch.complex128, torch.complex128: torch.complex64}
    yield [_tensor((3,), other.get(dtype, torch.float64)), a, b], {}, "error: self dtype", ()


def _slack(name: str, args: list[Any], kwargs: dict[str, Any]) -> float:
    """How far two correct products may differ beyond the default tolerance: a k-term sum rounded in another order
    (BLAS's blocking against one k-ordered chain) differs by up to about k * eps * sum |terms|, which for OpInfo's
    values (up to 9 in magnitude) exceeds the default absolute tolerance where a sum cancels."""
    if name in UNARY or not all(isinstance(a, torch.Tensor) for a in args[-2:]):
        return 0.0
    a, b = args[-2], args[-1]
    if a.numel() == 0 or b.numel() == 0 or not (a.dtype.is_floating_point or a.dtype.is_complex) or a.dim() < 2:
        return 0.0
    k = a.shape[-1]
    eps = torch.finfo(torch.float64 if a.dtype in (torch.float64, torch.complex128) else torch.float32).eps
    terms = k * a.abs().max().item() * b.abs().max().item() * abs(kwargs.get("alpha", 1))
    return 2 * (k + 2) * eps * float(terms)


def _layouts(args: list[Any]) -> Iterator[tuple[str, list[Any]]]:
    """The same values as given, non-contiguous (every other element), transposed, and as conjugate views."""
    tensors = [a for a in args if isinstance(a, torch.Tensor)]
    yield "", args
    if any(t.numel() > 1 for t in tensors):
        yield " non-contiguous", [_every_other(a) if isinstance(a, torch.Tensor) else a for a in args]
    if any(t.dim() >= 2 and t.numel() > 1 for t in tensors):
        yield " transposed", [a.mT.contiguous().mT if isinstance(a, torch.Tensor) and a.dim() >= 2 else a for a in args]
    if any(t.is_complex() for t in tensors):
        yield " conjugate", [a.conj() if isinstance(a, torch.Tensor) and a.is_complex() else a for a in args]


def _overlaps(t: Any) -> bool:
    """Whether elements of `t` share memory (an expanded tensor). ATen's `baddbmm_` writes into such a `self` without
    refusing, each element accumulating every product that lands on it in ATen's loop order, where `addmm_` and the
    unary in-place forms refuse: no semantics to compare, so in-place forms are not tried on them."""
    return isinstance(t, torch.Tensor) and any(st == 0 and n > 1 for st, n in zip(t.stride(), t.shape))


def _every_other(t: torch.Tensor) -> torch.Tensor:
    """`t`'s values in a view whose last dimension has stride 2."""
    if t.dim() == 0 or t.numel() == 0:
        return t
    wide = torch.zeros(*t.shape[:-1], 2 * t.shape[-1], dtype=t.dtype)
    wide[..., ::2] = t
    return wide[..., ::2]


def _meta_result(name: str, args: list[Any], kwargs: dict[str, Any]) -> torch.Tensor | None:
    """ATen's result on the meta device (its shape and dtype, computed without any CPU kernel), or None if refused."""
    try:
        return getattr(torch, name)(*[a.to("meta") if isinstance(a, torch.Tensor) else a for a in args], **kwargs)
    except Exception:  # noqa: BLE001 - a refused call has no out= variants to build
        return None


def _outs(result: torch.Tensor | None, first: torch.Tensor) -> Iterator[tuple[str, torch.Tensor]]:
    """`out=` tensors: empty (resized), the right shape transposed (kept), the wrong shape, and other dtypes."""
    dtype = first.dtype if result is None else result.dtype
    yield "empty out", torch.empty(0, dtype=dtype)
    if result is None:
        return
    shape = tuple(result.shape)
    if len(shape) >= 2:
        yield "transposed out", torch.zeros(shape[::-1], dtype=dtype).mT if len(shape) == 2 else torch.zeros(shape, dtype=dtype).mT.contiguous().mT
    yield "wrong-shape out", torch.zeros(7, dtype=dtype)
    if dtype.is_floating_point or dtype.is_complex:
        yield "integer out", torch.zeros(shape, dtype=torch.int64)
        wider = {torch.float32: torch.float64, torch.float16: torch.float32, torch.bfloat16: torch.float32}.get(dtype)
        if wider is not None:
            yield "wider out", torch.zeros(shape, dtype=wider)
    else:
        yield "float out", torch.zeros(shape, dtype=torch.float32)


def _cases_for(op: Any, dtype: torch.dtype) -> Iterator[dict[str, Any]]:
    """Every form of every sample of one operator and dtype."""
    name = op.name
    extras = _unary_extras(dtype) if name in UNARY else _product_extras(name, dtype)
    for seed, (args, kwargs, label, wrt) in enumerate([*_opinfo_samples(op, dtype), *extras]):
        for layout, laid in _layouts(args):
            base = {"kind": "call", "name": name, "args": laid, "kwargs": kwargs, "dtype": dtype, "label": label + layout,
                    "slack": _slack(name, args, kwargs)}  # fmt: skip
            yield base | {"form": "function", "grad": wrt, "seed": seed}
            yield base | {"form": "method"}
            if op.inplace_variant is not None and not _overlaps(laid[0]):
                yield base | {"form": "inplace"}
            if layout in ("", " transposed"):
                for what, out in _outs(_meta_result(name, laid, kwargs), laid[0]):
                    yield base | {"form": "out", "out": out, "label": f"{label}{layout}, {what}"}


def _optimizer_cases() -> Iterator[dict[str, Any]]:
    """Three steps of Adam, AdamW and SGD with momentum on 0-d, 1-d and n-d float32 parameters."""
    g = torch.Generator().manual_seed(7)
    params = [torch.randn((), generator=g), torch.randn(5, generator=g), torch.randn(3, 4, 2, generator=g)]
    grads = [[torch.randn(p.shape, generator=g) for p in params] for _ in range(3)]
    for optimizer, options in [("Adam", {"lr": 0.01}), ("Adam", {"lr": 0.01, "foreach": True}), ("Adam", {"lr": 0.01, "amsgrad": True}),
                               ("AdamW", {"lr": 0.01, "weight_decay": 0.1}), ("AdamW", {"lr": 0.01, "foreach": True}),
                               ("SGD", {"lr": 0.1, "momentum": 0.9}), ("SGD", {"lr": 0.1, "momentum": 0.9, "nesterov": True, "foreach": True})]:  # fmt: skip
        yield {"kind": "optim", "optimizer": optimizer, "options": options, "params": params, "grads": grads,
               "label": f"{optimizer} {options}"}  # fmt: skip


def build() -> list[dict[str, Any]]:
    """Every case: each replaced operator over every dtype OpInfo lists as CPU-supported, then the optimizers (the
    random values seeded, so each build gives the same cases)."""
    from torch.testing._internal.common_methods_invocations import op_db

    torch.manual_seed(0)
    ops = [op for op in op_db if op.name in UNARY + PRODUCTS and op.variant_test_name == ""]
    assert sorted(op.name for op in ops) == sorted(UNARY + PRODUCTS), "an OpInfo entry went missing"
    return [case for op in ops for dtype in op.supported_dtypes("cpu") for case in _cases_for(op, dtype)] + list(_optimizer_cases())
