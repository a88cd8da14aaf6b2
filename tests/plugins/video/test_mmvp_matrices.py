"""MMVP's motion matrices against their definitions: cosine similarities, the softmax over a whole matrix, the
resize of a matrix's grid, and the chained composition against a brute-force loop over frames and chains."""

from __future__ import annotations

import torch

from clods_bench.plugins.video.mmvp_matrices import WEIGHT_EPS, compose_chained, global_softmax, resize_matrices, similarity_matrices


def softmaxed(*shape: int, generator: torch.Generator) -> torch.Tensor:
    return global_softmax(3.0 * torch.randn(*shape, generator=generator, dtype=torch.float64))


def test_similarity_matrices_are_cosines_of_consecutive_frames_positions() -> None:
    g = torch.Generator().manual_seed(0)
    feats = torch.randn(2, 3, 5, 2, 3, generator=g, dtype=torch.float64)  # (B,T,c,h,w)
    sims = similarity_matrices(feats)
    assert sims.shape == (2, 2, 6, 6)
    for b in range(2):
        for k in range(2):
            for i in range(6):
                for j in range(6):
                    u, v = feats[b, k, :, i // 3, i % 3], feats[b, k + 1, :, j // 3, j % 3]
                    expected = (u / (u.norm() + 1e-6)) @ (v / (v.norm() + 1e-6))
                    assert abs(sims[b, k, i, j].item() - expected.item()) < 1e-14


def test_one_pixel_shift_is_the_most_similar_source_of_every_target() -> None:
    g = torch.Generator().manual_seed(1)
    feats = torch.randn(1, 16, 5, 6, generator=g, dtype=torch.float64)
    pair = torch.stack([feats, torch.roll(feats, shifts=1, dims=3)], dim=1)  # every feature moves one pixel right
    source = similarity_matrices(pair)[0, 0].argmax(dim=0)
    ys, xs = torch.arange(30) // 6, torch.arange(30) % 6
    assert torch.equal(source, ys * 6 + (xs - 1) % 6)


def test_global_softmax_normalises_each_whole_matrix() -> None:
    g = torch.Generator().manual_seed(2)
    logits = torch.randn(2, 3, 4, 4, generator=g, dtype=torch.float64)
    out = global_softmax(logits)
    e = logits.exp()
    torch.testing.assert_close(out, e / e.sum(dim=(2, 3), keepdim=True), rtol=1e-14, atol=0)
    torch.testing.assert_close(out.sum(dim=(2, 3)), torch.ones(2, 3, dtype=torch.float64), rtol=1e-14, atol=0)
    assert out.sum(dim=2).max() < 0.9 and out.sum(dim=3).max() < 0.9  # no column (or row) sums to 1 on its own


def test_resize_keeps_a_matrix_on_the_same_grid_and_constants_constant() -> None:
    g = torch.Generator().manual_seed(3)
    m = torch.randn(1, 2, 16, 16, generator=g, dtype=torch.float64)
    torch.testing.assert_close(resize_matrices(m, (4, 4), (4, 4)), m, rtol=0, atol=1e-15)
    const = resize_matrices(torch.full((1, 1, 64, 64), 0.25, dtype=torch.float64), (8, 8), (4, 4))
    assert const.shape == (1, 1, 16, 16)
    torch.testing.assert_close(const, torch.full_like(const, 0.25), rtol=0, atol=1e-15)


def test_resize_is_bilinear_over_targets_then_bicubic_over_sources() -> None:
    g = torch.Generator().manual_seed(4)
    m = torch.randn(1, 1, 16, 16, generator=g, dtype=torch.float64)  # 4x4 grid -> 2x2
    out = resize_matrices(m, (4, 4), (2, 2))
    f = torch.nn.functional
    for i in range(4):
        for j in range(4):  # entry [i, j]: a source position i' of the new grid, a target position j
            by_target = torch.stack([f.interpolate(m[0, 0, s].reshape(1, 1, 4, 4), size=(2, 2), mode="bilinear").flatten() for s in range(16)])
            column = by_target[:, j].reshape(1, 1, 4, 4)  # (old source grid) for this new target
            assert abs(out[0, 0, i, j].item() - f.interpolate(column, size=(2, 2), mode="bicubic").flatten()[i].item()) < 1e-14


def brute_force_compose(feats: torch.Tensor, past: torch.Tensor, future: torch.Tensor) -> torch.Tensor:
    """Every frame k through the product M_k ... M_{P-2} Pred_t multiplied out, for every future t."""
    b, p, c, h, w = feats.shape
    out = torch.zeros(b, future.shape[1], c, h * w, dtype=feats.dtype)
    for t in range(future.shape[1]):
        num = torch.zeros(b, c, h * w, dtype=feats.dtype)
        den = torch.zeros(b, 1, h * w, dtype=feats.dtype)
        for k in range(p):
            chain = future[:, t]
            for j in reversed(range(k, p - 1)):
                chain = past[:, j] @ chain
            num += feats[:, k].flatten(2) @ chain
            den += chain.sum(dim=1, keepdim=True)
        out[:, t] = num / (den + WEIGHT_EPS)
    return out.reshape(b, -1, c, h, w)


def test_chained_composition_matches_the_brute_force_loop_over_frames() -> None:
    g = torch.Generator().manual_seed(5)
    for p, f in ((2, 1), (4, 3), (5, 5)):
        feats = torch.randn(2, p, 3, 3, 2, generator=g, dtype=torch.float64)
        past, future = softmaxed(2, p - 1, 6, 6, generator=g), softmaxed(2, f, 6, 6, generator=g)
        expected = brute_force_compose(feats, past, future)
        torch.testing.assert_close(compose_chained(feats, past, future), expected, rtol=1e-12, atol=1e-14)
        last_only = (feats[:, -1].flatten(2).unsqueeze(1) @ future) / (future.sum(dim=2, keepdim=True) + WEIGHT_EPS)
        assert (expected.flatten(3) - last_only).abs().max() > 1e-3  # all frames count, not only the last one


def test_composing_with_permutations_moves_the_features() -> None:
    g = torch.Generator().manual_seed(6)
    f0 = torch.randn(1, 4, 2, 3, generator=g, dtype=torch.float64)
    perm1, perm2 = torch.randperm(6, generator=g), torch.randperm(6, generator=g)
    move = lambda x, perm: x.flatten(2)[..., perm].reshape(x.shape)  # noqa: E731 - target j takes source perm[j]
    f1 = move(f0, perm1)
    eye = torch.eye(6, dtype=torch.float64)
    past, future = eye[:, perm1][None, None], eye[:, perm2][None, None]  # column j has its 1 at row perm[j]
    out = compose_chained(torch.stack([f0, f1], dim=1), past, future)
    torch.testing.assert_close(out[:, 0], move(f1, perm2) * 2 / (2 + WEIGHT_EPS), rtol=1e-14, atol=0)
