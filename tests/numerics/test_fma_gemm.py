"""`fma_gemm`: every element one k-ordered chain of fused multiply-adds, the same bits at AVX2 and AVX-512 width.

References independent of the kernels: exact rational arithmetic (`fractions`) rounded once per step for small
products, the same chain emulated in numpy for larger ones (float32 products are exact in float64), each instruction
set's kernel against the other's on this CPU, and digests committed from an AVX-512 CPU's kernels, which an AVX2-only
CPU must reproduce.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from fractions import Fraction
from typing import Any

import numpy as np
import pytest

from clods_bench import numerics as dm
from clods_bench.numerics import fma_gemm

pytestmark = pytest.mark.skipif("avx2" not in (dm.cpu_flags() or {"avx2"}), reason="the kernels need an AVX2 CPU")

ISAS = ["avx2"] + (["avx512"] if fma_gemm.host_isa() == "avx512" else [])


def _values(rng: np.random.Generator, shape: tuple[int, ...], dtype: type) -> np.ndarray:
    """Random values that are exact in float32 (integers over a power of two): the same on every CPU and numpy."""
    return (rng.integers(-(2**22), 2**22, size=shape) / 2.0**20).astype(dtype)


def _round32(x: Fraction) -> np.float32:
    """`x` rounded once to float32 (nearest, ties to even), without double rounding through float64."""
    guess = np.float32(float(x))
    candidates = [np.nextafter(guess, np.float32(-np.inf)), guess, np.nextafter(guess, np.float32(np.inf))]
    return min(candidates, key=lambda c: (abs(Fraction(float(c)) - x), int(np.array(c).view(np.int32)) & 1))


def _exact_chain(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The definition itself: acc = round(a[i, k] * b[k, j] + acc) over k in order, in exact rationals."""
    rnd = _round32 if a.dtype == np.float32 else (lambda x: np.float64(float(x)))
    out = np.zeros((a.shape[0], b.shape[1]), dtype=a.dtype)
    for i in range(a.shape[0]):
        for j in range(b.shape[1]):
            acc = a.dtype.type(0)
            for k in range(a.shape[1]):
                acc = rnd(Fraction(float(a[i, k])) * Fraction(float(b[k, j])) + Fraction(float(acc)))
            out[i, j] = acc
    return out


def _emulated_chain32(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The float32 chain in numpy: the product is exact in float64, the sum rounded to float64 then float32 (a
    double rounding that can differ from one rounding, but not for these inputs: checked against `_exact_chain`)."""
    acc = np.zeros((a.shape[0], b.shape[1]), dtype=np.float32)
    for k in range(a.shape[1]):
        acc = (acc.astype(np.float64) + np.outer(a[:, k].astype(np.float64), b[k].astype(np.float64))).astype(np.float32)
    return acc


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("isa", ISAS)
def test_small_products_are_the_exact_chain(dtype: type, isa: str) -> None:
    rng = np.random.default_rng(3)
    for m, k, n in [(1, 1, 1), (7, 5, 3), (13, 40, 17), (2, 70, 33)]:  # tails of every tile and panel
        a, b = _values(rng, (m, k), dtype), _values(rng, (k, n), dtype)
        a = a * _values(rng, (m, k), dtype)  # products of 42-bit significands: float64 sums round
        want = _exact_chain(a, b)
        assert np.array_equal(fma_gemm.matmul(a, b, isa=isa), want), (m, k, n)


@pytest.mark.parametrize("isa", ISAS)
def test_float32_products_are_the_chain_in_every_layout_and_block(isa: str) -> None:
    """Layouts: row-major, column-major, a strided slice, a broadcast row (stride 0); k past one block (384) and past
    the strided block (32); a folded row added once after the chain."""
    rng = np.random.default_rng(4)
    for m, k, n in [(64, 32, 48), (97, 1000, 130), (300, 129, 18)]:
        a, b = _values(rng, (m, k), np.float32), _values(rng, (k, n), np.float32) * np.float32(1 / 3)
        want = _emulated_chain32(a, b)
        assert np.array_equal(_exact_chain(a[:3], b[:, :2]), want[:3, :2])  # the emulation holds for these inputs
        wide = np.zeros((k, 2 * n), np.float32)
        wide[:, ::2] = b
        for la in (a, np.asfortranarray(a)):
            for lb in (b, np.asfortranarray(b), wide[:, ::2]):
                assert np.array_equal(fma_gemm.matmul(la, lb, isa=isa), want), (m, k, n)
        row = _values(rng, (n,), np.float32)
        assert np.array_equal(fma_gemm.matmul(a, b, row, isa=isa), want + row)
    one_row = np.broadcast_to(_values(rng, (1, 50), np.float32), (9, 50))  # stride 0 between rows
    b = _values(rng, (50, 20), np.float32)
    assert np.array_equal(fma_gemm.matmul(one_row, b, isa=isa), _emulated_chain32(np.ascontiguousarray(one_row), b))


@pytest.mark.parametrize("isa", ISAS)
def test_batches_are_each_matrix_alone(isa: str) -> None:
    rng = np.random.default_rng(5)
    for dtype in (np.float32, np.float64):
        x, y = _values(rng, (4, 23, 70), dtype), _values(rng, (4, 70, 9), dtype)
        got = fma_gemm.matmul(x, y, isa=isa)
        assert got.shape == (4, 23, 9)
        for i in range(4):
            assert np.array_equal(got[i], fma_gemm.matmul(x[i], y[i], isa=isa))
        assert np.array_equal(fma_gemm.matmul(x.transpose(0, 2, 1).copy().transpose(0, 2, 1), y, isa=isa), got)


def test_threads_split_rows_without_changing_a_bit() -> None:
    rng = np.random.default_rng(8)
    for dtype in (np.float32, np.float64):
        for shape_a, shape_b in [((2000, 300), (300, 70)), ((3, 700, 300), (3, 300, 33))]:
            a, b = _values(rng, shape_a, dtype) / 3, _values(rng, shape_b, dtype) / 7
            one = fma_gemm.matmul(a, b)
            for threads in (2, 3, 8):
                assert np.array_equal(fma_gemm.matmul(a, b, threads=threads), one), (shape_a, threads)
                assert np.array_equal(fma_gemm.matmul(np.asfortranarray(a) if a.ndim == 2 else a, b, threads=threads), one)


def test_both_instruction_sets_give_the_same_bits_on_this_cpu() -> None:
    """The point of the module: the AVX-512 kernel (16 lanes, 12-row tiles) and the AVX2 kernel (8 lanes, 6-row tiles)
    agree bit for bit. Needs an AVX-512 CPU; an AVX2-only CPU checks the committed digests below instead."""
    if "avx512" not in ISAS:
        pytest.skip("this CPU has no AVX-512: test_committed_digests compares with an AVX-512 CPU's results")
    rng = np.random.default_rng(6)
    for dtype in (np.float32, np.float64):
        for m, k, n in [(9000, 128, 128), (128, 1579, 128), (33, 777, 65), (1, 384, 1)]:
            a = rng.standard_normal((m, k)).astype(dtype)
            b = rng.standard_normal((k, n)).astype(dtype)
            for la in (a, np.asfortranarray(a)):
                assert np.array_equal(fma_gemm.matmul(la, b, isa="avx512"), fma_gemm.matmul(la, b, isa="avx2"))


# sha256 (16 hex) of the products below, made by both kernels on an Intel Xeon (Sapphire Rapids), 2026-11-29
COMMITTED = {
    "float32 9000x128x128": "c066cf8130a634a9",
    "float32 128x1579x128 column-major A": "2b386bb75c83cc5f",
    "float32 33x777x65 + row": "0a5e9300b4d7fd12",
    "float64 300x129x18": "584af5a1688eca24",
    "float64 3 x 23x70x9": "21dc0dc564d73677",
}


def _digest_cases() -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray | None]]:
    rng = np.random.default_rng(7)
    v = _values
    return {
        "float32 9000x128x128": (v(rng, (9000, 128), np.float32), v(rng, (128, 128), np.float32) / 7, None),
        "float32 128x1579x128 column-major A": (np.asfortranarray(v(rng, (128, 1579), np.float32)), v(rng, (1579, 128), np.float32) / 3, None),
        "float32 33x777x65 + row": (v(rng, (33, 777), np.float32), v(rng, (777, 65), np.float32) / 5, v(rng, (65,), np.float32)),
        "float64 300x129x18": (v(rng, (300, 129), np.float64) / 3, v(rng, (129, 18), np.float64) / 7, None),
        "float64 3 x 23x70x9": (v(rng, (3, 23, 70), np.float64) / 3, v(rng, (3, 70, 9), np.float64) / 11, None),
    }


@pytest.mark.parametrize("isa", ISAS)
def test_committed_digests(isa: str) -> None:
    """This CPU's kernels reproduce the bits an AVX-512 CPU's made (the cross-CPU check in miniature)."""
    for name, (a, b, row) in _digest_cases().items():
        got = hashlib.sha256(np.ascontiguousarray(fma_gemm.matmul(a, b, row, isa=isa)).tobytes()).hexdigest()[:16]
        assert got == COMMITTED[name], name


def test_the_kernels_use_the_instruction_sets_they_are_named_for() -> None:
    """Width independence is only shown if the two kernels differ: AVX-512's uses zmm registers, AVX2's never."""
    wide, narrow = fma_gemm.machine_code("avx512"), fma_gemm.machine_code("avx2")
    assert "%zmm" in wide and "vfmadd" in wide
    assert "%zmm" not in narrow and "%ymm" in narrow and "vfmadd" in narrow


def test_bad_operands_and_settings_say_what_is_wrong(monkeypatch: pytest.MonkeyPatch) -> None:
    a = np.ones((3, 4), np.float32)
    with pytest.raises(TypeError, match="float32 or float64 operands of one dtype expected, got float32 and float64"):
        fma_gemm.matmul(a, np.ones((4, 2)))
    with pytest.raises(ValueError, match=r"shapes \(3, 4\) and \(5, 2\) cannot be multiplied"):
        fma_gemm.matmul(a, np.ones((5, 2), np.float32))
    with pytest.raises(ValueError, match=r"the added row must be float32 of shape \(2,\)"):
        fma_gemm.matmul(a, np.ones((4, 2), np.float32), np.ones(3, np.float32))
    monkeypatch.setenv(fma_gemm.ISA_ENV, "sse2")
    with pytest.raises(ValueError, match="CLODS_BENCH_GEMM_ISA='sse2': expected one of avx512, avx2"):
        fma_gemm.host_isa()
    assert np.array_equal(fma_gemm.matmul(np.ones((2, 0), np.float32), np.ones((0, 3), np.float32), isa="avx2"), np.zeros((2, 3), np.float32))


def test_compiled_kernels_are_kept_on_disk_and_give_the_same_bits(tmp_path: Any) -> None:
    """The second process loads the first one's machine code (no compilation) and computes the same bits; an
    unwritable cache folder only costs the compilation."""
    code = ("import hashlib, numpy as np\nfrom clods_bench.numerics import fma_gemm\n"
            "a = (np.arange(4000, dtype=np.float32).reshape(40, 100) % 97) / 7\n"
            "print(hashlib.sha256(fma_gemm.matmul(a, a.T.copy(), isa='avx2').tobytes()).hexdigest())")  # fmt: skip
    env = {k: v for k, v in os.environ.items()} | {fma_gemm.CACHE_ENV: str(tmp_path / "kernels")}
    runs = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300) for _ in range(2)]
    assert all(r.returncode == 0 for r in runs), runs[-1].stderr[-2000:]
    assert len(list((tmp_path / "kernels").glob("avx2-float32-*.o"))) == 1
    assert runs[0].stdout == runs[1].stdout
    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    env[fma_gemm.CACHE_ENV] = str(blocked / "kernels")
    third = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert third.returncode == 0 and third.stdout == runs[0].stdout, third.stderr[-2000:]


def test_unoptimised_kernels_give_the_same_bits(tmp_path: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    """Without LLVM's optimisation passes (an llvmlite older than 0.44) the kernels are slower, not different: every
    fused multiply-add is an explicit intrinsic that no pass may split or reorder."""
    import llvmlite.binding as llvm

    rng = np.random.default_rng(9)
    a, b = _values(rng, (50, 300), np.float32) / 3, _values(rng, (300, 40), np.float32) / 7
    want = fma_gemm.matmul(a, b, isa="avx2")
    monkeypatch.setenv(fma_gemm.CACHE_ENV, str(tmp_path))
    monkeypatch.delattr(llvm, "create_pass_builder")
    monkeypatch.setattr(fma_gemm, "_kernels", {})
    assert np.array_equal(fma_gemm.matmul(a, b, isa="avx2"), want)
