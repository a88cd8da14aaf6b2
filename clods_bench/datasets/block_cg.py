"""A fixed 3x3-block sparse pattern for cloth systems and a block-Jacobi preconditioned CG.

The pattern (node pairs sharing a triangle or a bending hinge) is built once; elements
scatter their 3x3 blocks through precomputed index maps, so no COO->CSR conversion happens
per step. Kinematic nodes are handled by the filter of Baraff & Witkin: their rows and
columns are projected out inside CG (residual and search directions are zero there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np


@dataclass
class BlockPattern:
    """Block-CSR structure over nodes plus maps from element corners to block indices."""

    indptr: np.ndarray  # (V+1,) int64
    indices: np.ndarray  # (nnzb,) int64 column node of each block
    diag: np.ndarray  # (V,) int64 block index of (i, i)
    tri_map: np.ndarray  # (F,3,3) int64 block index of (cells[f,a], cells[f,b])
    hinge_map: np.ndarray  # (H,4,4) int64 block index of (hinges[h,a], hinges[h,b])

    @property
    def nnzb(self) -> int:
        return int(self.indices.shape[0])


def build_pattern(num_nodes: int, cells: np.ndarray, hinges: np.ndarray) -> BlockPattern:
    """Block sparsity of all node pairs coupled by a triangle or a hinge, with scatter maps."""
    v = np.int64(num_nodes)
    tri_r = np.repeat(cells, 3, axis=1).astype(np.int64)
    tri_c = np.tile(cells, (1, 3)).astype(np.int64)
    hin_r = np.repeat(hinges, 4, axis=1).astype(np.int64)
    hin_c = np.tile(hinges, (1, 4)).astype(np.int64)
    diag = np.arange(v, dtype=np.int64)
    keys = np.unique(np.concatenate([(tri_r * v + tri_c).ravel(), (hin_r * v + hin_c).ravel(), diag * v + diag]))
    rows, cols = keys // v, keys % v
    indptr = np.zeros(num_nodes + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=num_nodes), out=indptr[1:])
    find = lambda r, c: np.searchsorted(keys, r * v + c)  # noqa: E731
    return BlockPattern(
        indptr=indptr,
        indices=cols.astype(np.int64),
        diag=find(diag, diag),
        tri_map=find(tri_r, tri_c).reshape(-1, 3, 3),
        hinge_map=find(hin_r, hin_c).reshape(-1, 4, 4),
    )


def hinge_scalars(pattern: BlockPattern, hinge_k: np.ndarray, hinge_w: np.ndarray) -> np.ndarray:
    """(nnzb,) scalar bending matrix Q on the block pattern (each block is Q_ij * I3)."""
    q = np.zeros(pattern.nnzb)
    vals = hinge_w[:, None, None] * hinge_k[:, :, None] * hinge_k[:, None, :]
    np.add.at(q, pattern.hinge_map.ravel(), vals.ravel())
    return q


@numba.njit(cache=True)
def block_matvec(indptr, indices, blocks, x, out):
    """out = A x for block-CSR A with (nnzb,3,3) blocks and x (V,3)."""
    for i in range(indptr.shape[0] - 1):
        s0 = s1 = s2 = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            b = blocks[k]
            x0, x1, x2 = x[j, 0], x[j, 1], x[j, 2]
            s0 += b[0, 0] * x0 + b[0, 1] * x1 + b[0, 2] * x2
            s1 += b[1, 0] * x0 + b[1, 1] * x1 + b[1, 2] * x2
            s2 += b[2, 0] * x0 + b[2, 1] * x1 + b[2, 2] * x2
        out[i, 0], out[i, 1], out[i, 2] = s0, s1, s2


@numba.njit(cache=True)
def scalar_matvec(indptr, indices, vals, x, out):
    """out = (Q kron I3) x for a scalar block-CSR Q and x (V,3)."""
    for i in range(indptr.shape[0] - 1):
        s0 = s1 = s2 = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            q = vals[k]
            s0 += q * x[j, 0]
            s1 += q * x[j, 1]
            s2 += q * x[j, 2]
        out[i, 0], out[i, 1], out[i, 2] = s0, s1, s2


@numba.njit(cache=True)
def _apply_pinv(pinv, r, z):
    """z = blockdiag(pinv) r, returning r . z."""
    rz = 0.0
    for i in range(r.shape[0]):
        p = pinv[i]
        r0, r1, r2 = r[i, 0], r[i, 1], r[i, 2]
        z0 = p[0, 0] * r0 + p[0, 1] * r1 + p[0, 2] * r2
        z1 = p[1, 0] * r0 + p[1, 1] * r1 + p[1, 2] * r2
        z2 = p[2, 0] * r0 + p[2, 1] * r1 + p[2, 2] * r2
        z[i, 0], z[i, 1], z[i, 2] = z0, z1, z2
        rz += r0 * z0 + r1 * z1 + r2 * z2
    return rz


@numba.njit(cache=True)
def inverse3(a, out):
    """out = a^-1 for a 3x3 matrix by cofactors, in a fixed order of operations.

    Not np.linalg.inv: inside numba that calls LAPACK (OpenBLAS), whose kernels are chosen per CPU and round
    differently, which made the generated cloth differ between hosts; this gives the same bits on every CPU.
    """
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    if det == 0.0 or not np.isfinite(det):
        raise ValueError("a preconditioner block is singular (or not finite): the cloth system has a degenerate node")
    out[0, 0] = c00 / det
    out[0, 1] = (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) / det
    out[0, 2] = (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) / det
    out[1, 0] = c01 / det
    out[1, 1] = (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) / det
    out[1, 2] = (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) / det
    out[2, 0] = c02 / det
    out[2, 1] = (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) / det
    out[2, 2] = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) / det


@numba.njit(cache=True)
def block_pcg(indptr, indices, diag, blocks, b, x, free, tol, max_iter):
    """Solve A x = b on free nodes (x fixed to 0 elsewhere), block-Jacobi PCG; returns (iters, rel. residual)."""
    n = b.shape[0]
    pinv = np.zeros((n, 3, 3))
    for i in range(n):
        if free[i]:
            inverse3(blocks[diag[i]], pinv[i])
        else:
            x[i, :] = 0.0
    r = np.empty((n, 3))
    ax = np.empty((n, 3))
    block_matvec(indptr, indices, blocks, x, ax)
    bnorm2 = 0.0
    rr = 0.0
    for i in range(n):
        for d in range(3):
            if free[i]:
                r[i, d] = b[i, d] - ax[i, d]
                bnorm2 += b[i, d] * b[i, d]
                rr += r[i, d] * r[i, d]
            else:
                r[i, d] = 0.0
    if bnorm2 == 0.0:
        x[:, :] = 0.0
        return 0, 0.0
    z = np.empty((n, 3))
    rz = _apply_pinv(pinv, r, z)
    p = z.copy()
    thresh = tol * tol * bnorm2
    it = 0
    while it < max_iter and rr > thresh:
        block_matvec(indptr, indices, blocks, p, ax)
        pap = 0.0
        for i in range(n):
            if free[i]:
                pap += p[i, 0] * ax[i, 0] + p[i, 1] * ax[i, 1] + p[i, 2] * ax[i, 2]
            else:
                ax[i, 0] = ax[i, 1] = ax[i, 2] = 0.0
        if not pap > 0.0:
            break
        alpha = rz / pap
        rr = 0.0
        for i in range(n):
            for d in range(3):
                x[i, d] += alpha * p[i, d]
                r[i, d] -= alpha * ax[i, d]
                rr += r[i, d] * r[i, d]
        rz_new = _apply_pinv(pinv, r, z)
        beta = rz_new / rz
        rz = rz_new
        for i in range(n):
            for d in range(3):
                p[i, d] = z[i, d] + beta * p[i, d]
        it += 1
    return it, np.sqrt(rr / bnorm2)
