"""The pins and the probe: the pins are in effect in this test session, four tiny fits (one per model family) give
the committed bits on every x86-64 CPU with AVX2, and the CLI's errors and switches say what is wrong in one line."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from clods_bench import numerics as dm
from clods_bench.cli import main
from clods_bench.benchmark.core.determinism import effective_paths
from clods_bench.numerics import cpu, scope
from clods_bench.errors import ClodsError

COMMITTED = json.loads((Path(__file__).parents[1] / "benchmark" / "speed" / "data" / "determinism_probe.json").read_text())
X86_AVX2 = not dm.missing_cpu_features()


def test_the_test_session_runs_on_the_pinned_paths() -> None:
    """The numerics pytest plugin pins first and runs the session in the exact scope, as the CLI runs a command."""
    assert dm.requested() and dm.active() and dm.loaded_too_early() == [] and dm.missing_pins() == []
    paths = effective_paths()
    assert paths["mkl_cbwr"] == "COMPATIBLE" and paths["onednn_max_isa"] == "AVX2" and paths["torch_threads"] == 1
    if X86_AVX2:
        assert paths["torch_cpu_capability"] == "AVX2" and paths["numba_cpu_name"] == "haswell"
        assert paths["numpy_dispatch_above_avx2"] == [] and paths["openblas_core"] == "Haswell"
    assert paths["torch_functions_on_numpy"] == ["sqrt", "log", "tan", "asin", "acos", "atan"]
    assert paths["torch_products_on_fma_gemm"] == ["mm", "addmm", "bmm", "baddbmm"]
    assert paths["fma_gemm_isa"] in ("avx512", "avx2")


@pytest.mark.skipif(not X86_AVX2, reason="the committed digests are of the pinned x86-64 AVX2 paths")
@pytest.mark.parametrize("family", ["graph net", "video predictor", "renderer fit", "extraction"])
def test_each_model_family_gives_the_committed_bits(family: str) -> None:
    """The digests were made on another CPU (see the file's `made_on`); on the host's own paths they differ
    (`CLODS_BENCH_DETERMINISTIC=0 pytest tests/test_deterministic_mode.py` fails here on an AVX-512 CPU)."""
    from clods_bench.benchmark.speed.determinism_probe import probe

    assert probe((family,))[family]["digest"] == COMMITTED["digests"][family]


def test_a_cpu_without_avx2_gets_one_line_and_exit_2(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    monkeypatch.setattr(cpu, "missing_cpu_features", lambda: ["avx2", "fma"])
    assert main(["run", "cdg", "--sim", "constvel", "--set", f"runs_dir={tmp_path}"]) == 2
    err = capsys.readouterr().err
    assert "exact numerics pin AVX2 code paths, and this CPU" in err and "lacks avx2, fma" in err and "--no-deterministic" in err
    assert len(err.strip().splitlines()) <= 3  # one message (rich wraps long lines)
    assert main(["list"]) == 0  # commands that compute nothing still work
    with pytest.raises(dm.ExactNumericsError, match="lacks avx2, fma"):  # the library's typed error
        with dm.exact():
            pass


def test_numpy_imported_before_the_pins_is_named(tmp_path: Path) -> None:
    code = "import numpy\nfrom clods_bench import numerics\nnumerics.pin_environment()\nwith numerics.exact():\n    pass"
    env = {k: v for k, v in os.environ.items() if k not in dm.pins()}  # a fresh process: nothing pinned beforehand
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert out.returncode != 0 and "ExactNumericsError" in out.stderr
    assert "numpy loaded before the pins were set, so its floating-point paths are the host's" in out.stderr
    assert "call clods_bench.numerics.pin_environment() before importing numpy" in out.stderr
    env.update(dm.pins())  # the variables of `clods-bench numerics --export`, set before Python starts: fine
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path).returncode == 0


def test_the_scope_refuses_without_the_pins(tmp_path: Path) -> None:
    code = "from clods_bench import numerics\nimport torch\nwith numerics.exact():\n    pass"
    env = {k: v for k, v in os.environ.items() if k not in dm.pins()}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert out.returncode != 0 and "the numeric libraries' pins are not in the environment" in out.stderr


def test_no_deterministic_is_a_plain_flag_on_the_host_paths() -> None:
    """In a fresh process the flag undoes even pins inherited from this (pinned) test session, before numpy loads."""
    exe = shutil.which("clods-bench", path=str(Path(sys.executable).parent)) or "clods-bench"
    out = subprocess.run([exe, "--no-deterministic", "numerics"], capture_output=True, text=True)
    assert out.returncode == 0 and "mode: host paths" in out.stdout.replace("\n", " ")
    assert "mkl_cbwr=host" in out.stdout.replace("\n", "") and "torch_products_on_fma_gemm=[]" in out.stdout.replace("\n", "")
    env = dm.host_environ()  # the environment from before the pins, with the switch off
    assert env[dm.SWITCH_ENV] == "0" and "MKL_CBWR" not in env or env["MKL_CBWR"] != "COMPATIBLE"


def test_records_and_caches_of_the_two_modes_never_mix(monkeypatch: pytest.MonkeyPatch) -> None:
    from clods_bench.benchmark.core.cache_keys import digest
    from clods_bench.benchmark.core.registry import default_registry
    from clods_bench.benchmark.running.records import record_dir
    from tests.conftest import tiny_config

    cfg = tiny_config(Path("/tmp/x"), sim="constvel")
    registry = default_registry()
    pinned = (record_dir(cfg, registry), digest({"a": 1}))
    monkeypatch.setitem(scope._state, "depth", 0)  # as outside the scope
    assert dm.numeric_mode() == "host"
    assert record_dir(cfg, registry) != pinned[0] and digest({"a": 1}) != pinned[1]


def test_a_cpu_without_avx2_keeps_openblass_own_kernel(monkeypatch: pytest.MonkeyPatch) -> None:
    """Haswell's kernel on such a CPU stops numpy's import with an illegal instruction (seen under QEMU's Nehalem),
    before the run could name the missing feature; so the pin is left out there."""
    assert dm.pins()["OPENBLAS_CORETYPE"] == "Haswell" or not X86_AVX2
    monkeypatch.setattr(dm.pinning, "missing_cpu_features", lambda: ["avx2"])
    assert "OPENBLAS_CORETYPE" not in dm.pins()


_EPYC = "processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 25\nmodel\t\t: 17\nmodel name\t: AMD EPYC\nflags\t\t: fpu avx2 fma f16c {}\n\nprocessor\t: 1\nmodel name\t: other\n"


def test_the_cpu_is_named_with_family_model_and_vector_width() -> None:
    """A virtual machine's "AMD EPYC" alone names no microarchitecture; records say which one made them."""
    assert dm.cpu_model(_EPYC.format("avx512f avx512dq avx512bw avx512vl")) == "AMD EPYC (family 25, model 17, AVX-512)"
    assert dm.cpu_model(_EPYC.format("avx512f")) == "AMD EPYC (family 25, model 17, AVX2)"
    assert dm.cpu_model(_EPYC.replace(" avx2", "").format("")) == "AMD EPYC (family 25, model 17, no AVX2)"


def test_records_name_the_product_kernels_in_use(monkeypatch: pytest.MonkeyPatch) -> None:
    from clods_bench.numerics import fma_gemm

    assert dm.describe()["product_kernels"] == fma_gemm.host_isa()
    monkeypatch.setenv("CLODS_BENCH_GEMM_ISA", "avx2")
    assert dm.describe()["product_kernels"] == "avx2"


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("qemu-x86_64") is None or not X86_AVX2, reason="needs qemu-user (apt-get install qemu-user) on an x86-64 AVX2 host")
@pytest.mark.parametrize("cpu", ["Haswell", "EPYC-Rome", "Skylake-Server-v4"])
def test_emulated_intel_and_amd_cpus_give_the_committed_bits(cpu: str) -> None:
    """The same fits under QEMU's models of an AVX2 Intel (Haswell), an AVX2 AMD (EPYC Rome) and an AVX-512 Intel
    (Skylake Server) CPU give the committed digests of a real Intel Xeon: MKL dispatches by vendor, oneDNN and ATen by
    instruction set, and under the pins all take the same arithmetic. QEMU computes IEEE arithmetic exactly and the
    CPU's approximate instructions its own way, so this also shows that no pinned path depends on those (before
    `exact_math`, MKL's vector sqrt did: see the file's `before_exact_math`)."""
    code = ("from clods_bench import numerics\nnumerics.pin_environment()\nimport json\nfrom clods_bench.benchmark.speed.determinism_probe import probe\n"
            "print(json.dumps({k: v['digest'] for k, v in probe().items()}))")
    out = subprocess.run(["qemu-x86_64", "-cpu", cpu, sys.executable, "-c", code], capture_output=True, text=True, timeout=3000)
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout.strip().splitlines()[-1]) == COMMITTED["digests"]
