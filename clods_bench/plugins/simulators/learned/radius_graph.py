"""Radius graphs over world positions, the edge set of particle simulators (GNS, Sanchez-Gonzalez et al. 2020).

A node i receives from every node j of the same sample with |x_j - x_i| < r_i (no self edges); with a cap of
k neighbours only its k nearest such senders are kept. Built from positions alone: no mesh edge is read.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree


def rest_spacing(mesh_pos: np.ndarray) -> float:
    """Median over nodes of the distance to the nearest other node in rest space (the point cloud's spacing, m)."""
    pts = np.asarray(mesh_pos, dtype=np.float64)
    if pts.shape[0] < 2:
        return float("nan")
    dist, _ = cKDTree(pts).query(pts, k=2)
    return float(np.median(dist[:, 1]))


def radius_edges(
    pos: torch.Tensor, sample: torch.Tensor, radius: torch.Tensor, max_neighbours: int | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """(senders, receivers) int64 of the radius graph: j -> i when i != j, sample[j] == sample[i] and
    |pos_j - pos_i| < radius[i]; with `max_neighbours` each receiver keeps its nearest ones only.

    `pos` (V,3), `sample` (V,) int64 with every sample's nodes contiguous (a batched disjoint union), `radius` (V,).
    """
    senders, receivers = [], []
    bounds = torch.nonzero(torch.diff(sample, prepend=sample[:1] - 1)).squeeze(1).tolist() + [int(sample.shape[0])]
    with torch.no_grad():  # the pairs are discrete; features built from them carry the gradient
        for lo, hi in zip(bounds[:-1], bounds[1:]):
            p = pos[lo:hi].detach()
            d = torch.cdist(p, p)  # (n, n): row = receiver, column = sender
            d.fill_diagonal_(float("inf"))
            d = torch.where(d < radius[lo:hi].unsqueeze(1), d, torch.full_like(d, float("inf")))
            if max_neighbours is not None and max_neighbours < d.shape[1]:
                vals, cols = torch.topk(d, max_neighbours, dim=1, largest=False)
                rows = torch.arange(d.shape[0], device=d.device).unsqueeze(1).expand_as(cols)
                keep = torch.isfinite(vals)
                r, s = rows[keep], cols[keep]
            else:
                r, s = torch.nonzero(torch.isfinite(d), as_tuple=True)
            senders.append(s + lo)
            receivers.append(r + lo)
    empty = torch.zeros(0, dtype=torch.int64, device=pos.device)
    return (torch.cat(senders) if senders else empty), (torch.cat(receivers) if receivers else empty)
