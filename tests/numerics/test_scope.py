"""The exact scope: importing clods_bench changes nothing in the process, the scope installs its kernels and takes
them away again, nests, refuses where it cannot hold, and its thread pools survive a fork."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from clods_bench import numerics

ROOT = Path(__file__).resolve().parents[2]
_PROBE_PROCESS = r"""
import json, os, sys
def state():
    import torch
    x = torch.arange(1, 1201, dtype=torch.float32).reshape(1, 1200) / 7
    y = torch.linspace(-1, 1, 1200 * 3, dtype=torch.float32).reshape(1200, 3)
    return {"mm": torch.mm(x, y).tolist(), "sqrt0d": list(torch.sqrt(torch.tensor(4.0)).shape),
            "threads": torch.get_num_threads(), "interop": torch.get_num_interop_threads(),
            "mkldnn_det": bool(getattr(torch.backends.mkldnn, "deterministic", False))}
env0, hooks0 = dict(os.environ), [type(f).__name__ for f in sys.meta_path]
import torch
before = state()
import importlib, pkgutil
import clods_bench, clods_bench.api
names = [m.name for m in pkgutil.walk_packages(clods_bench.__path__, "clods_bench.")
         if not m.name.endswith(("pytest_plugin", "__main__"))]
for name in names:
    importlib.import_module(name)
from importlib.metadata import entry_points
for ep in entry_points(group="clods_bench"):
    if ep.value.startswith("clods_bench."):
        ep.load()
after = state()
changed = sorted(k for k in set(env0) | set(os.environ) if env0.get(k) != os.environ.get(k))
hooks = [type(f).__name__ for f in sys.meta_path]
print(json.dumps({"modules": len(names), "changed_env": changed, "hooks_before": hooks0, "hooks_after": hooks,
                  "same_torch": before == after, "before": before, "after": after}))
"""


def _fresh(code: str, env: dict[str, str] | None = None) -> dict:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                         env={**os.environ, **(env or {})}, timeout=600)  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_importing_the_package_and_every_module_changes_nothing() -> None:
    """A fresh process: the API, every module of the package and every built-in plugin's entry point imported, and
    torch's dispatch for mm and sqrt, its thread counts, the environment and the import hooks are as before."""
    got = _fresh(_PROBE_PROCESS)
    assert got["modules"] > 150  # the walk did reach the whole package
    assert got["changed_env"] == [] and got["hooks_after"] == got["hooks_before"]
    assert got["same_torch"], (got["before"], got["after"])
    assert got["after"]["sqrt0d"] == []  # ATen's own 0-d result


def test_the_scope_installs_its_kernels_and_removes_them_on_exit() -> None:
    """In a fresh, pinned process: torch's own mm (k = 1200, where its blocked sums round otherwise) before the scope,
    fma_gemm's chains of fused multiply-adds inside it, torch's own again after it; the thread count restored."""
    code = r"""
import json
from clods_bench import numerics
numerics.pin_environment()
import numpy as np, torch
from clods_bench.numerics import exact_math, exact_matmul, fma_gemm
torch.set_num_threads(2)
x = torch.randn(64, 1200, generator=torch.Generator().manual_seed(0))
y = torch.randn(1200, 48, generator=torch.Generator().manual_seed(1))
chains = torch.from_numpy(fma_gemm.matmul(x.numpy(), y.numpy()))
def look():
    return {"fma": bool(torch.equal(torch.mm(x, y), chains)), "installed": [exact_math.installed(), exact_matmul.installed()],
            "threads": torch.get_num_threads(), "active": numerics.active(), "mode": numerics.numeric_mode()}
out = {"before": look()}
with numerics.exact():
    out["inside"] = look()
    with numerics.exact():
        out["nested"] = look()
    out["after_nested"] = look()
out["after"] = look()
print(json.dumps(out))
"""
    got = _fresh(code)
    assert got["before"] == {"fma": False, "installed": [False, False], "threads": 2, "active": False, "mode": "host"}
    inside = {"fma": True, "installed": [True, True], "threads": numerics.threads(), "active": True, "mode": "deterministic"}
    assert got["inside"] == got["nested"] == got["after_nested"] == inside
    assert got["after"] == got["before"]


def test_the_scope_is_left_on_an_error_and_nests() -> None:
    from clods_bench.numerics import exact_matmul

    assert numerics.active() and exact_matmul.installed()  # the test session's own scope
    with pytest.raises(RuntimeError, match="boom"):
        with numerics.exact():
            raise RuntimeError("boom")
    assert numerics.active() and exact_matmul.installed()  # the outer scope still holds


def test_the_product_threads_survive_a_fork() -> None:
    """A child forked after fma_gemm's thread pool ran (a forked DataLoader worker) multiplies on fresh threads
    instead of waiting forever on its parent's."""
    code = r"""
import os, json
from clods_bench import numerics
numerics.pin_environment()
import numpy as np
from clods_bench.numerics import fma_gemm
a = np.random.default_rng(0).standard_normal((512, 512)).astype(np.float32)
want = fma_gemm.matmul(a, a, threads=2)  # large enough to run on the pool
pid = os.fork()
if pid == 0:
    ok = np.array_equal(fma_gemm.matmul(a, a, threads=2), want)
    os._exit(0 if ok else 3)
_, status = os.waitpid(pid, 0)
print(json.dumps({"child": os.waitstatus_to_exitcode(status)}))
"""
    assert _fresh(code) == {"child": 0}
