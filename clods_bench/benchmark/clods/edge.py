"""The edge-length loss of stage 2 (paper eq. 7): keep every mesh edge at its first-frame length."""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from clods_bench.datasets.types import edges_from_cells


def mesh_edges(cells: np.ndarray) -> Tensor:
    """(E,2) int64 unique undirected edges of the triangles `cells` (F,3)."""
    return torch.from_numpy(edges_from_cells(np.asarray(cells)))


def edge_lengths(verts: Tensor, edges: Tensor) -> Tensor:
    """(E,) Euclidean lengths of `edges` (E,2) on vertex positions `verts` (V,3)."""
    return torch.linalg.vector_norm(verts[edges[:, 0]] - verts[edges[:, 1]], dim=1)


def edge_loss(verts: Tensor, edges: Tensor, rest_lengths: Tensor) -> Tensor:
    """L_edge = sum over edges |d(x_i, x_j) - d0_ij| (eq. 7, each undirected edge counted once)."""
    return (edge_lengths(verts, edges) - rest_lengths).abs().sum()
