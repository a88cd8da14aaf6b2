"""Where a run is when something fails: the stage contexts the runner enters (data generation, a task's seed) and
`plugin_call`, which the tasks and builders wrap around every call into a plugin (build, fit, rollout, render,
predict).

A plugin's exception becomes one `PluginError` naming the plugin, the stage and the seed (its traceback kept as the
cause); an exception of the environment (disk full, permission denied, out of memory) passes through with the stage
noted on it (`errors.mark_stage`), so the CLI can say where it happened; a `ClodsError` a plugin raises names its
problem already and passes through unchanged.
"""

from __future__ import annotations

import contextlib
from contextvars import ContextVar
from typing import Iterator

from clods_bench.errors import ClodsError, PluginError, environment_problem, mark_stage

_SEED: ContextVar[int | None] = ContextVar("clods_bench_seed", default=None)


@contextlib.contextmanager
def stage(what: str, seed: int | None = None) -> Iterator[None]:
    """Mark exceptions raised inside with `what` (unless an inner stage did); with `seed`, the plugin calls inside
    name that seed."""
    token = _SEED.set(seed) if seed is not None else None
    try:
        yield
    except BaseException as exc:
        mark_stage(exc, what if seed is None else f"{what}, seed {seed}")
        raise
    finally:
        if token is not None:
            _SEED.reset(token)


@contextlib.contextmanager
def plugin_call(kind: str, name: str, what: str, owner: object = None) -> Iterator[None]:
    """Run a call into plugin `name` of `kind` ('simulator', 'renderer', 'video predictor') at stage `what` ('build',
    'fit', 'rollout', 'render', 'predict'); `owner` (the plugin object, or its build function) tells whether the
    plugin is one of clods-bench's own, whose exception is then reported as a clods-bench bug."""
    try:
        yield
    except ClodsError:
        raise
    except Exception as exc:  # noqa: BLE001 - any exception of a plugin is named, never swallowed
        seed = _SEED.get()
        if environment_problem(exc) is not None:
            mark_stage(exc, f"{what} of {kind} '{name}'" + (f", seed {seed}" if seed is not None else ""))
            raise
        module = str(getattr(owner, "__module__", "") or "")
        raise PluginError(kind, name, what, type(exc).__name__, str(exc), seed, builtin=module.startswith("clods_bench.")) from exc
