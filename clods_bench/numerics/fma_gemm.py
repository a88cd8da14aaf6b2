"""Matrix products in which every output element is one chain of fused multiply-adds in k order, compiled here.

`C[i, j] = fma(A[i, K-1], B[K-1, j], ... fma(A[i, 1], B[1, j], fma(A[i, 0], B[0, j], 0)))`: each element's
arithmetic is fixed by that formula alone, so kernels of any vector width, tiling or blocking give the same bits
(the partial sum between two blocks of k is stored and reloaded exactly). This module builds such kernels with
llvmlite (numba's LLVM binding) for AVX-512 (16 float lanes) and for AVX2 (8 lanes): an AVX-512 CPU runs its
products at AVX-512 speed and still gives an AVX2 CPU's bits, which a BLAS cannot promise (OpenBLAS's Haswell and
SkylakeX kernels, and MKL's branches, each round differently). Deterministic mode hands torch's `mm`, `addmm`,
`bmm` and `baddbmm` to `matmul` here (`exact_matmul`).

Register tiles of MR rows by NV vectors, B packed in panels of NV vectors, k in blocks of KC, rows in blocks of MC:
the layout of BLIS and OpenBLAS, without packing A (its rows are read with any strides).
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from clods_bench.atomic import atomic_path

ISA_ENV = "CLODS_BENCH_GEMM_ISA"
"""Forces the kernels' instruction set ('avx512' or 'avx2'; default: the widest this CPU has)."""

CACHE_ENV = "CLODS_BENCH_KERNEL_CACHE"
"""Folder for the compiled kernels (default ~/.cache/clods-bench/fma_gemm)."""

DTYPES = (np.float32, np.float64)


@dataclass(frozen=True)
class Shape:
    """One kernel's register tile and blocking (the bits do not depend on any of them)."""

    lanes: int  # elements per vector register
    mr: int  # rows per register tile
    nv: int  # vectors per tile row
    kc: int  # k per block where A's rows are contiguous (the partial sums are stored between blocks)
    kc_strided: int  # k per block where they are not
    mc: int  # rows per block (reused from cache across the panels of B)

    @property
    def nr(self) -> int:
        """Columns per panel of B."""
        return self.lanes * self.nv


_TARGETS = {  # isa -> LLVM CPU name, feature string
    "avx512": ("skylake-avx512", "+avx512f,+avx512dq,+avx512bw,+avx512vl,+avx2,+fma,+avx,+f16c"),
    "avx2": ("haswell", "+avx2,+fma,+avx,+f16c,-avx512f"),
}
_SHAPES = {
    ("avx512", "float32"): Shape(lanes=16, mr=12, nv=2, kc=384, kc_strided=32, mc=96),
    ("avx512", "float64"): Shape(lanes=8, mr=12, nv=2, kc=384, kc_strided=32, mc=96),
    ("avx2", "float32"): Shape(lanes=8, mr=6, nv=2, kc=384, kc_strided=32, mc=96),
    ("avx2", "float64"): Shape(lanes=4, mr=6, nv=2, kc=384, kc_strided=32, mc=96),
}

_lock = threading.Lock()
_kernels: dict[tuple[str, str], Any] = {}
_host: dict[str, str] = {}
_pools: dict[int, Any] = {}
_fork_hook: list[bool] = []
_PARALLEL_WORK = 1 << 22
"""Multiply-adds below which a product runs on one thread whatever `threads` says."""


def _pool(size: int) -> Any:
    """A thread pool of `size` workers, made once."""
    from concurrent.futures import ThreadPoolExecutor

    with _lock:
        if not _fork_hook:  # registered with the first pool, not on import
            os.register_at_fork(after_in_child=_after_fork_in_child)
            _fork_hook.append(True)
        if size not in _pools:
            _pools[size] = ThreadPoolExecutor(max_workers=size, thread_name_prefix="fma_gemm")
        return _pools[size]


def _after_fork_in_child() -> None:
    """A forked child has none of its parent's pool threads, and the lock may have been held at the fork: start anew."""
    global _lock
    _lock = threading.Lock()
    _pools.clear()


_engines: list[Any] = []  # the JIT engines own the machine code: kept alive for the process


def host_isa() -> str:
    """The widest instruction set this CPU runs the kernels with ('avx512' or 'avx2'), or $CLODS_BENCH_GEMM_ISA."""
    forced = os.environ.get(ISA_ENV, "").strip().lower()
    if forced:
        if forced not in _TARGETS:
            raise ValueError(f"{ISA_ENV}={forced!r}: expected one of {', '.join(_TARGETS)}")
        return forced
    if "host" not in _host:
        import llvmlite.binding as llvm

        features = llvm.get_host_cpu_features()
        _host["host"] = "avx512" if all(features.get(f, False) for f in ("avx512f", "avx512dq", "avx512bw", "avx512vl")) else "avx2"
    return _host["host"]


def _build_ir(dtype_name: str, shape: Shape) -> str:
    """LLVM IR of `gemm(batch, M, N, K, A, sab, sam, sak, B, sbb, sbk, sbn, C, scb, ldc, kc, mc, scratch)`: strides
    in elements; C has N rounded up to NR columns; `scratch` holds kc x N-rounded-up elements (B's packed panels)."""
    from llvmlite import ir

    fty = ir.FloatType() if dtype_name == "float32" else ir.DoubleType()
    vty = ir.VectorType(fty, shape.lanes)
    vptr = vty.as_pointer()
    i64, i32 = ir.IntType(64), ir.IntType(32)
    ptr = fty.as_pointer()
    module = ir.Module(name=f"fma_gemm_{dtype_name}")
    suffix = f"v{shape.lanes}{'f32' if dtype_name == 'float32' else 'f64'}"
    fma = ir.Function(module, ir.FunctionType(vty, [vty, vty, vty]), name=f"llvm.fma.{suffix}")
    args = [i64, i64, i64, i64, ptr, i64, i64, i64, ptr, i64, i64, i64, ptr, i64, i64, i64, i64, ptr, ptr, i64]
    fn = ir.Function(module, ir.FunctionType(ir.VoidType(), args), name="gemm")
    batch, m, n, k, a, sab, sam, sak, bmat, sbb, sbk, sbn, c, scb, ldc, kc_max, mc, scratch, row, has_row = fn.args
    for arg in (a, bmat, c, scratch, row):
        arg.add_attribute("noalias")
    b = ir.IRBuilder(fn.append_basic_block("entry"))
    zero, one = ir.Constant(i64, 0), ir.Constant(i64, 1)
    c_nr, c_mr = ir.Constant(i64, shape.nr), ir.Constant(i64, shape.mr)
    vzero = ir.Constant(vty, None)
    # stack slots for the accumulators (promoted to registers by the optimiser)
    slots = [[b.alloca(vty, name=f"acc{r}_{v}") for v in range(shape.nv)] for r in range(shape.mr)]

    def loop(start: Any, stop: Any, step: Any, body: Any, name: str) -> None:
        """for (i = start; i < stop; i += step) body(i)"""
        head = fn.append_basic_block(f"{name}.head")
        inner = fn.append_basic_block(f"{name}.body")
        done = fn.append_basic_block(f"{name}.done")
        pre = b.block
        b.branch(head)
        b.position_at_end(head)
        i = b.phi(i64, name=name)
        i.add_incoming(start, pre)
        b.cbranch(b.icmp_signed("<", i, stop), inner, done)
        b.position_at_end(inner)
        body(i)
        nxt = b.add(i, step)
        i.add_incoming(nxt, b.block)
        b.branch(head)
        b.position_at_end(done)

    def smin(x: Any, y: Any) -> Any:
        return b.select(b.icmp_signed("<", x, y), x, y)

    def at(base: Any, offset: Any) -> Any:
        return b.gep(base, [offset])

    n_panels = b.sdiv(b.add(n, ir.Constant(i64, shape.nr - 1)), c_nr)

    def pack(b_rows: Any, kc: Any) -> None:
        """scratch[p][kk][0:NR] = B[k0 + kk][p*NR : p*NR + NR], zero past column N (vector copies where B's rows
        are contiguous and the panel is whole)."""

        def per_panel(p: Any) -> None:
            j0 = b.mul(p, c_nr)
            dest = at(scratch, b.mul(p, b.mul(kc, c_nr)))
            whole = b.and_(b.icmp_signed("==", sbn, one), b.icmp_signed("<=", b.add(j0, c_nr), n))
            fast, slow, done = fn.append_basic_block("pack.fast"), fn.append_basic_block("pack.slow"), fn.append_basic_block("pack.done")
            b.cbranch(whole, fast, slow)
            b.position_at_end(fast)

            def fast_row(kk: Any) -> None:
                src = at(b_rows, b.add(b.mul(kk, sbk), j0))
                for v in range(shape.nv):
                    value = b.load(b.bitcast(at(src, ir.Constant(i64, v * shape.lanes)), vptr), align=1)
                    b.store(value, b.bitcast(at(dest, b.add(b.mul(kk, c_nr), ir.Constant(i64, v * shape.lanes))), vptr), align=1)

            loop(zero, kc, one, fast_row, "packf")
            b.branch(done)
            b.position_at_end(slow)

            def slow_row(kk: Any) -> None:
                def element(col: Any) -> None:
                    j = b.add(j0, col)
                    inside, outside, joined = fn.append_basic_block("el.in"), fn.append_basic_block("el.out"), fn.append_basic_block("el.join")
                    b.cbranch(b.icmp_signed("<", j, n), inside, outside)
                    b.position_at_end(inside)
                    value = b.load(at(b_rows, b.add(b.mul(kk, sbk), b.mul(j, sbn))))
                    b.branch(joined)
                    b.position_at_end(outside)
                    b.branch(joined)
                    b.position_at_end(joined)
                    phi = b.phi(fty)
                    phi.add_incoming(value, inside)
                    phi.add_incoming(ir.Constant(fty, 0.0), outside)
                    b.store(phi, at(dest, b.add(b.mul(kk, c_nr), col)))

                loop(zero, c_nr, one, element, "packcol")

            loop(zero, kc, one, slow_row, "packs")
            b.branch(done)
            b.position_at_end(done)

        loop(zero, n_panels, one, per_panel, "pack")

    def tile(rows: int, a_tile: Any, b_panel: Any, c_tile: Any, kc: Any, first: Any, last: Any, row_panel: Any) -> None:
        """`rows` x NR tile of C: start from 0 (first block of k) or from C, add kc products in k order, store."""
        c_rows = [[b.bitcast(at(c_tile, b.add(b.mul(ir.Constant(i64, r), ldc), ir.Constant(i64, v * shape.lanes))), vptr)
                   for v in range(shape.nv)] for r in range(rows)]
        for r in range(rows):
            for v in range(shape.nv):
                b.store(vzero, slots[r][v])
        resume, go = fn.append_basic_block("resume"), fn.append_basic_block("go")
        b.cbranch(first, go, resume)
        b.position_at_end(resume)
        for r in range(rows):
            for v in range(shape.nv):
                b.store(b.load(c_rows[r][v], align=1), slots[r][v])
        b.branch(go)
        b.position_at_end(go)
        splat_mask = ir.Constant(ir.VectorType(i32, shape.lanes), None)

        def step(kk: Any) -> None:
            bvecs = [b.load(b.bitcast(at(b_panel, b.add(b.mul(kk, c_nr), ir.Constant(i64, v * shape.lanes))), vptr), align=1)
                     for v in range(shape.nv)]
            a_col = at(a_tile, b.mul(kk, sak))
            for r in range(rows):
                scalar = b.load(at(a_col, b.mul(ir.Constant(i64, r), sam)))
                splat = b.shuffle_vector(b.insert_element(ir.Constant(vty, ir.Undefined), scalar, ir.Constant(i32, 0)),
                                         ir.Constant(vty, ir.Undefined), splat_mask)
                for v in range(shape.nv):
                    b.store(b.call(fma, [splat, bvecs[v], b.load(slots[r][v])]), slots[r][v])

        loop(zero, kc, one, step, f"k{rows}")
        add_row, store = fn.append_basic_block("addrow"), fn.append_basic_block("store")
        b.cbranch(b.and_(last, b.icmp_signed("!=", has_row, zero)), add_row, store)
        b.position_at_end(add_row)  # the row added after the last product: round(chain + row), as a separate add
        for v in range(shape.nv):
            value = b.load(b.bitcast(at(row_panel, ir.Constant(i64, v * shape.lanes)), vptr), align=1)
            for r in range(rows):
                b.store(b.fadd(b.load(slots[r][v]), value), slots[r][v])
        b.branch(store)
        b.position_at_end(store)
        for r in range(rows):
            for v in range(shape.nv):
                b.store(b.load(slots[r][v]), c_rows[r][v], align=1)

    def per_batch(ib: Any) -> None:
        a_b, b_b, c_b = at(a, b.mul(ib, sab)), at(bmat, b.mul(ib, sbb)), at(c, b.mul(ib, scb))

        def per_kblock(k0: Any) -> None:
            kc = smin(kc_max, b.sub(k, k0))
            first = b.icmp_signed("==", k0, zero)
            last = b.icmp_signed(">=", b.add(k0, kc), k)
            pack(at(b_b, b.mul(k0, sbk)), kc)

            def per_mblock(i0: Any) -> None:
                i_end = smin(b.add(i0, mc), m)

                def per_panel(p: Any) -> None:
                    b_panel = at(scratch, b.mul(p, b.mul(kc, c_nr)))

                    def per_tile(i: Any) -> None:
                        a_tile = at(a_b, b.add(b.mul(i, sam), b.mul(k0, sak)))
                        c_tile = at(c_b, b.add(b.mul(i, ldc), b.mul(p, c_nr)))
                        blocks = {rows: fn.append_basic_block(f"rows{rows}") for rows in range(1, shape.mr + 1)}
                        after = fn.append_basic_block("tile.done")
                        switch = b.switch(smin(b.sub(i_end, i), c_mr), after)
                        for rows, block in blocks.items():
                            switch.add_case(ir.Constant(i64, rows), block)
                            b.position_at_end(block)
                            tile(rows, a_tile, b_panel, c_tile, kc, first, last, at(row, b.mul(p, c_nr)))
                            b.branch(after)
                        b.position_at_end(after)

                    loop(i0, i_end, c_mr, per_tile, "tile")

                loop(zero, n_panels, one, per_panel, "panel")

            loop(zero, m, mc, per_mblock, "mblock")

        loop(zero, k, kc_max, per_kblock, "kblock")

    loop(zero, batch, one, per_batch, "batch")
    b.ret_void()
    return str(module)


def _optimise(llvm: Any, module: Any, machine: Any) -> None:
    """LLVM's -O3 pipeline (registers for the accumulators, unrolling); an llvmlite older than 0.44 lacks the bindings
    and the kernel runs unoptimised: slower, the same bits (each fused multiply-add is an explicit intrinsic)."""
    if hasattr(llvm, "create_pass_builder"):
        builder = llvm.create_pass_builder(machine, llvm.create_pipeline_tuning_options(speed_level=3))
        builder.getModulePassManager().run(module, builder)


def _cache_dir() -> Path:
    """Where compiled kernels are kept between processes: $CLODS_BENCH_KERNEL_CACHE, else ~/.cache/clods-bench."""
    return Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "clods-bench" / "fma_gemm")


def _compile(isa: str, dtype_name: str) -> Any:
    """The ctypes function of one kernel: built once per process, its machine code kept on disk for the next (a
    cache that cannot be read or written only costs the compilation, about a second)."""
    key = (isa, dtype_name)
    with _lock:
        if key in _kernels:
            return _kernels[key]
        import llvmlite
        import llvmlite.binding as llvm

        llvm.initialize_native_target()
        llvm.initialize_native_asmprinter()
        cpu, features = _TARGETS[isa]
        machine = llvm.Target.from_default_triple().create_target_machine(cpu=cpu, features=features, opt=3,
                                                                          reloc="default", codemodel="jitdefault")
        source = _build_ir(dtype_name, _SHAPES[key])
        tag = hashlib.sha256(f"{source}|{cpu}|{features}|{llvmlite.__version__}|{machine.triple}".encode()).hexdigest()[:24]
        cached = _cache_dir() / f"{isa}-{dtype_name}-{tag}.o"
        try:
            code: bytes | None = cached.read_bytes()
        except OSError:
            code = None
        module = llvm.parse_assembly(source)
        module.verify()
        if code is None:
            _optimise(llvm, module, machine)
        engine = llvm.create_mcjit_compiler(module, machine)

        def keep(_module: Any, buffer: bytes) -> None:
            try:
                cached.parent.mkdir(parents=True, exist_ok=True)
                with atomic_path(cached) as tmp:
                    tmp.write_bytes(buffer)
            except OSError:
                pass

        engine.set_object_cache(keep if code is None else None, (lambda _module: code) if code is not None else None)
        engine.finalize_object()
        _engines.append(engine)
        ptr, i64 = ctypes.c_void_p, ctypes.c_int64
        signature = ctypes.CFUNCTYPE(None, i64, i64, i64, i64, ptr, i64, i64, i64, ptr, i64, i64, i64, ptr, i64, i64, i64, i64, ptr, ptr, i64)
        kernel = signature(engine.get_function_address("gemm"))
        _kernels[key] = kernel
        return kernel


def machine_code(isa: str, dtype: Any = np.float32) -> str:
    """The kernel's assembly (for inspection: which vector instructions it uses)."""
    import llvmlite.binding as llvm

    llvm.initialize_native_target()
    llvm.initialize_native_asmprinter()
    name = np.dtype(dtype).name
    cpu, features = _TARGETS[isa]
    machine = llvm.Target.from_default_triple().create_target_machine(cpu=cpu, features=features, opt=3)
    module = llvm.parse_assembly(_build_ir(name, _SHAPES[(isa, name)]))
    _optimise(llvm, module, machine)
    return machine.emit_assembly(module)


def matmul(a: np.ndarray, b: np.ndarray, row: np.ndarray | None = None, isa: str | None = None, threads: int = 1) -> np.ndarray:
    """`a @ b (+ row)` for float32 or float64 matrices (2-D) or equal-length batches of them (3-D): each element one
    k-ordered chain of fused multiply-adds, then `row` (length N, the same dtype) added once, as a separate addition
    would. A new array; `isa` (default `host_isa()`) and `threads` (row blocks side by side) change the speed only."""
    if a.dtype != b.dtype or a.dtype.type not in DTYPES:
        raise TypeError(f"fma_gemm.matmul: float32 or float64 operands of one dtype expected, got {a.dtype} and {b.dtype}")
    if a.ndim != b.ndim or a.ndim not in (2, 3) or a.shape[-1] != b.shape[-2] or (a.ndim == 3 and a.shape[0] != b.shape[0]):
        raise ValueError(f"fma_gemm.matmul: shapes {a.shape} and {b.shape} cannot be multiplied")
    if row is not None and (row.dtype != a.dtype or row.shape != (b.shape[-1],)):
        raise ValueError(f"fma_gemm.matmul: the added row must be {a.dtype} of shape ({b.shape[-1]},), got {row.dtype} {row.shape}")
    isa = isa or host_isa()
    name = a.dtype.name
    shape = _SHAPES[(isa, name)]
    a3 = a if a.ndim == 3 else a[None]
    b3 = b if b.ndim == 3 else b[None]
    batch, m, k = a3.shape
    n = b3.shape[2]
    if batch == 0 or m == 0 or n == 0 or k == 0:
        out = np.zeros(a.shape[:-1] + (n,), dtype=a.dtype)
        return out if row is None else out + row
    n_pad = -(-n // shape.nr) * shape.nr
    itemsize = a.dtype.itemsize
    if any(x % itemsize for x in a3.strides):  # a view at an odd byte offset: copied
        a3 = np.ascontiguousarray(a3)
    if any(x % itemsize for x in b3.strides):
        b3 = np.ascontiguousarray(b3)
    sab, sam, sak = (x // itemsize for x in a3.strides)
    sbb, sbk, sbn = (x // itemsize for x in b3.strides)
    # k per block: long where A's rows are contiguous, short where they are not, so that the A values a tile reads
    # over one block stay in L1 (the bits are the same for any block length)
    kc = min(shape.kc if sak == 1 else shape.kc_strided, k)
    padded_row = np.zeros(n_pad, dtype=a.dtype)
    if row is not None:
        padded_row[:n] = row
    out = np.empty((batch, m, n_pad), dtype=a.dtype)
    kernel = _compile(isa, name)

    def rows(first: int, count: int) -> None:
        """Rows first..first+count of every matrix (ctypes lets go of the GIL: row blocks run side by side)."""
        scratch = np.empty(kc * n_pad, dtype=a.dtype)
        kernel(batch, count, n, k, a3.ctypes.data + first * sam * itemsize, sab, sam, sak, b3.ctypes.data, sbb, sbk, sbn,
               out.ctypes.data + first * n_pad * itemsize, m * n_pad, n_pad, kc, shape.mc, scratch.ctypes.data,
               padded_row.ctypes.data, int(row is not None))

    parts = max(1, min(int(threads), m // (4 * shape.mr), batch * m * n * k // _PARALLEL_WORK))
    if parts == 1:
        rows(0, m)
    else:
        step = -(-m // parts // shape.mr) * shape.mr
        starts = list(range(0, m, step))
        list(_pool(len(starts)).map(lambda s: rows(s, min(step, m - s)), starts))
    out = out[:, :, :n]
    return out[0] if a.ndim == 2 else out
