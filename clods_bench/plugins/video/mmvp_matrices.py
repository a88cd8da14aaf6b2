"""MMVP's motion matrices and how they move features (Zhong et al. ICCV 2023, as in the authors' code).

A motion matrix of two frames is the (hw x hw) matrix of cosine similarities between the feature vectors at each
position of the earlier frame (rows, sources) and of the later one (columns, targets). Before composing, every
matrix gets one softmax over all of its hw*hw entries (a global softmax: the entries of a matrix sum to 1).
Future frame t is composed from all P observed frames: frame k's features travel through the chain
M_k M_{k+1} ... M_{P-2} Pred_t (the observed matrices after it, then the predicted matrix from the last observed
frame to frame t), and each target position takes the sum over frames and sources of chain weight x feature,
divided by the sum of the chain weights plus 1e-6.
"""

from __future__ import annotations

import torch
from torch.nn import functional as F

NORM_EPS = 1e-6
"""Added to a feature vector's norm before dividing by it (MMVP: norm + 1e-6, not max(norm, eps))."""
WEIGHT_EPS = 1e-6
"""Added to the summed chain weights of a target position before dividing by them (MMVP: 1e-6)."""


def similarity_matrices(feats: torch.Tensor) -> torch.Tensor:
    """(B,T-1,hw,hw) cosine similarities of consecutive frames' features (B,T,c,h,w): entry [k, i, j] compares
    position i of frame k with position j of frame k+1."""
    b, t, c, h, w = feats.shape
    v = feats.flatten(3)  # (B,T,c,hw)
    v = v / (v.norm(dim=2, keepdim=True) + NORM_EPS)
    return v[:, :-1].transpose(2, 3) @ v[:, 1:]


def global_softmax(matrices: torch.Tensor) -> torch.Tensor:
    """(B,T,hw,hw) matrices, each one softmaxed over all of its hw*hw entries at once."""
    b, t = matrices.shape[:2]
    return torch.softmax(matrices.reshape(b, t, -1), dim=-1).reshape(matrices.shape)


def resize_matrices(matrices: torch.Tensor, size: tuple[int, int], new_size: tuple[int, int]) -> torch.Tensor:
    """(B,T,hw,hw) matrices over an h x w grid -> (B,T,h'w',h'w') over an h' x w' grid: bilinear over the target
    positions, then bicubic over the source positions (MMVP's `sim_matrix_interpolate`, on the logits)."""
    b, t = matrices.shape[:2]
    (h, w), (h2, w2) = size, new_size
    m = F.interpolate(matrices.reshape(-1, 1, h, w), size=(h2, w2), mode="bilinear")  # targets, per source
    m = m.reshape(b, t, h * w, h2 * w2).transpose(2, 3).reshape(-1, 1, h, w)
    m = F.interpolate(m, size=(h2, w2), mode="bicubic")  # sources, per target
    return m.reshape(b, t, h2 * w2, h2 * w2).transpose(2, 3)


def compose_chained(feats: torch.Tensor, past: torch.Tensor, future: torch.Tensor) -> torch.Tensor:
    """(B,F,c,h,w) future features from the P observed frames' features (B,P,c,h,w), the P-1 observed motion
    matrices (B,P-1,hw,hw) and the F predicted ones from frame P-1 (B,F,hw,hw), all already softmaxed.

    sum_k f_k M_k...M_{P-2} Pred_t is evaluated right to left by Horner's rule, G <- G M_k + f_{k+1}, with a
    channel of ones carried along for the weights: the same sums as multiplying out every chain, in
    (P-1) + F products of a (c+1) x hw block with a matrix instead of F (P-1) products of two matrices."""
    b, p, c, h, w = feats.shape
    v = torch.cat([feats.flatten(3), feats.new_ones(b, p, 1, h * w)], dim=2)  # (B,P,c+1,hw)
    acc = v[:, 0]
    for k in range(p - 1):
        acc = acc @ past[:, k] + v[:, k + 1]
    out = acc.unsqueeze(1) @ future  # (B,F,c+1,hw)
    return (out[:, :, :c] / (out[:, :, c:] + WEIGHT_EPS)).reshape(b, -1, c, h, w)
