"""The optimisation loop every renderer plugin fits with: Adam, per-parameter learning rates, exponential decay.

3DGS trains with Adam (eps 1e-15) and one learning rate per parameter kind; it decays the position
rate exponentially. Here every rate decays from its initial value to `final_factor` times it over
the run (a short ci-sized fit needs the decay on colours and opacities too to settle).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from rich.progress import Progress
from torch import Tensor

from clods_bench.errors import ClodsError


@dataclass(frozen=True)
class ParamGroup:
    """Tensors optimised with one learning rate (named for error messages and statistics)."""

    name: str
    params: Sequence[Tensor]
    lr: float


def check_positive(value: float, where: str, allow_zero: bool = False) -> None:
    """Raise ClodsError unless `value` is finite and > 0 (or >= 0)."""
    ok = math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        raise ClodsError(f"must be {'>= 0' if allow_zero else '> 0'}, got {value}", where=where)


def fit_adam(
    groups: Sequence[ParamGroup],
    loss_at: Callable[[int], Tensor],
    iterations: int,
    final_factor: float = 0.1,
    progress: bool = False,
    label: str = "fit",
) -> dict[str, float]:
    """Minimise `loss_at(iteration)` for `iterations` Adam steps; returns loss and time statistics.

    Raises ClodsError if the loss becomes NaN/inf (naming the iteration), so a diverging fit never
    leaves silently broken parameters behind.
    """
    active = [g for g in groups if g.lr > 0 and len(g.params) > 0]
    opt = torch.optim.Adam([{"params": list(g.params), "lr": g.lr, "name": g.name} for g in active], eps=1e-15)
    base = [g.lr for g in active]
    losses: list[float] = []
    t0 = time.perf_counter()
    with Progress(transient=True, disable=not progress) as bar:
        job = bar.add_task(label, total=iterations)
        for it in range(iterations):
            decay = final_factor ** (it / max(iterations - 1, 1))
            for group, lr in zip(opt.param_groups, base):
                group["lr"] = lr * decay
            opt.zero_grad(set_to_none=True)
            loss = loss_at(it)
            value = float(loss.detach())
            if not math.isfinite(value):
                raise ClodsError(f"loss became {value} at iteration {it}", where=label, hint="lower the learning rates")
            loss.backward()
            opt.step()
            losses.append(value)
            bar.advance(job)
    tail = losses[-max(1, len(losses) // 10) :] if losses else [float("nan")]
    return {
        "iterations": float(iterations),
        "loss_first": losses[0] if losses else float("nan"),
        "loss_final": sum(tail) / len(tail),
        "fit_seconds": time.perf_counter() - t0,
    }
