"""Stage 2: a known deformation is recovered through the renderer, handles stay, the edge loss is exact."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from clods_bench.benchmark.clods.config import ClodsConfig
from clods_bench.benchmark.clods.edge import edge_loss, edge_lengths, mesh_edges
from clods_bench.benchmark.clods.extract import MeshPrior, extract_trajectory, fit_frame, start_guess
from clods_bench.datasets.types import NORMAL

from .conftest import smooth_deformation

FIT = ClodsConfig(iterations=30, min_iterations=30, learning_rate=0.003, lr_final_factor=0.1, gamma=0.0)


def rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - b) ** 2)))


def test_fit_frame_recovers_a_known_deformation(scene):
    r, cams, verts, nt = scene["renderer"], scene["cams"], scene["verts"], scene["node_type"]
    truth = smooth_deformation(verts, nt)
    with torch.no_grad():
        target = r.render(torch.from_numpy(truth), cams)
    prior = MeshPrior.from_mesh(verts, scene["cells"], nt)
    fit = fit_frame(r, cams, target, torch.from_numpy(verts), prior, FIT)
    before, after = rms(verts, truth), rms(fit.verts, truth)
    assert before > 0.005
    assert after < 0.3 * before, (before, after)
    np.testing.assert_array_equal(fit.verts[nt != NORMAL], verts[nt != NORMAL])  # handles unchanged, bit for bit


class BlankRenderer:
    """Renders white whatever the mesh (differentiable, zero gradient): the pixels carry no information."""

    def render(self, verts: torch.Tensor, cameras) -> torch.Tensor:
        return torch.ones(len(cameras), 4, 4, 3, dtype=verts.dtype) + 0.0 * verts.sum()


def test_edge_loss_restores_first_frame_lengths_when_pixels_say_nothing(scene):
    """With no image information only L_edge acts: the edge lengths go back towards the initial mesh's; handles stay."""
    verts, nt = scene["verts"], scene["node_type"]
    rng = np.random.default_rng(0)
    start = verts + np.where((nt == NORMAL)[:, None], rng.normal(0, 0.01, verts.shape), 0).astype(np.float32)
    prior = MeshPrior.from_mesh(verts, scene["cells"], nt)
    cams = scene["cams"]
    target = torch.ones(len(cams), 4, 4, 3)
    cfg = dataclasses.replace(FIT, gamma=1.0, iterations=200, min_iterations=200, learning_rate=0.002)
    fit = fit_frame(BlankRenderer(), cams, target, torch.from_numpy(start), prior, cfg)
    e = prior.edges
    before = float((edge_lengths(torch.from_numpy(start), e) - prior.rest_lengths).abs().mean())
    after = float((edge_lengths(torch.from_numpy(fit.verts), e) - prior.rest_lengths).abs().mean())
    assert after < 0.3 * before, (before, after)
    np.testing.assert_array_equal(fit.verts[nt != NORMAL], verts[nt != NORMAL])


def test_edge_loss_gradient_matches_finite_differences():
    rng = np.random.default_rng(1)
    cells = np.array([[0, 1, 2], [1, 3, 2], [2, 3, 4]])
    edges = mesh_edges(cells)
    assert edges.shape == (7, 2)  # 3 triangles sharing 2 edges
    rest = torch.from_numpy(rng.uniform(0.5, 1.5, 7))
    x0 = rng.normal(size=(5, 3))
    x = torch.tensor(x0, requires_grad=True)
    edge_loss(x, edges, rest).backward()
    h, fd = 1e-6, np.zeros_like(x0)
    for i in range(5):
        for k in range(3):
            dx = np.zeros_like(x0)
            dx[i, k] = h
            fd[i, k] = (float(edge_loss(torch.from_numpy(x0 + dx), edges, rest)) - float(edge_loss(torch.from_numpy(x0 - dx), edges, rest))) / (2 * h)
    np.testing.assert_allclose(x.grad.numpy(), fd, rtol=1e-6, atol=1e-8)
    # and the value itself, longhand
    expected = sum(abs(np.linalg.norm(x0[a] - x0[b]) - float(rest[n])) for n, (a, b) in enumerate(edges.tolist()))
    assert abs(float(edge_loss(torch.from_numpy(x0), edges, rest)) - expected) < 1e-12


def test_start_guess_extrapolates_free_nodes_only():
    done = np.zeros((2, 3, 3), np.float32)
    done[1] = 1.0
    free = np.array([True, False, True])
    vel = start_guess(done, ClodsConfig(start="velocity"), free)
    np.testing.assert_array_equal(vel, [[2, 2, 2], [1, 1, 1], [2, 2, 2]])
    np.testing.assert_array_equal(start_guess(done, ClodsConfig(start="previous"), free), done[1])


@pytest.mark.slow
def test_trajectory_tracks_a_moving_cloth(scene):
    """Two frames of growing deformation: every extracted frame is far closer to the truth than doing nothing."""
    r, cams, verts, nt = scene["renderer"], scene["cams"], scene["verts"], scene["node_type"]
    truth = np.stack([verts] + [smooth_deformation(verts, nt, 0.02 * k) for k in (1, 2)])
    with torch.no_grad():
        video = np.stack([(r.render(torch.from_numpy(t), cams).numpy() * 255).round().astype(np.uint8) for t in truth])
    ext = extract_trajectory(r, cams, video, verts, scene["cells"], nt, dataclasses.replace(FIT, iterations=25, min_iterations=25))
    assert ext.world_pos.shape == truth.shape
    np.testing.assert_array_equal(ext.world_pos[0], verts)
    for t in (1, 2):
        assert rms(ext.world_pos[t], truth[t]) < 0.35 * rms(verts, truth[t]), t
    assert (ext.iterations[1:] == 25).all() and ext.iterations[0] == 0


def test_frame_target_on_the_cpu_is_the_hosts_float32_division_and_the_device_is_the_renderers():
    """Stage 2 runs where the renderer is: a renderer without a `device` is on the CPU, and there the target is the
    numpy float32 division stage 2 always used (bit for bit, so CPU results do not move)."""
    from types import SimpleNamespace

    from clods_bench.benchmark.clods.extract import frame_target, renderer_device

    frame = np.random.default_rng(0).integers(0, 256, size=(2, 5, 7, 3), dtype=np.uint8)
    got = frame_target(frame, torch.device("cpu"))
    assert got.dtype == torch.float32 and np.array_equal(got.numpy(), np.asarray(frame, dtype=np.float32) / 255.0)
    assert renderer_device(SimpleNamespace()) == torch.device("cpu")
    assert renderer_device(SimpleNamespace(device=torch.device("meta"))) == torch.device("meta")
    assert renderer_device(SimpleNamespace(device="cuda")) == torch.device("cpu")  # not a torch.device: not trusted


class LinearRenderer:
    """An 'image' that is the vertex coordinates themselves: the L1 loss is the mean distance to the target mesh."""

    def render(self, verts: torch.Tensor, cameras) -> torch.Tensor:
        return verts[None, None]


def _overshoot_case():
    """Start 1 mm from the target on every coordinate, step 3 mm: Adam's first step overshoots and the next few
    iterations stay worse than the start (the fast-motion failure of stage 2 in miniature)."""
    cells = np.array([[0, 1, 2], [1, 3, 2]])
    nt = np.full(4, NORMAL)
    start = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    signs = np.array([[1, -1, 1], [-1, 1, 1], [1, 1, -1], [-1, -1, -1]], np.float32)
    target = torch.from_numpy(start + 0.001 * signs)[None, None]
    prior = MeshPrior.from_mesh(start, cells, nt)
    cfg = ClodsConfig(iterations=40, min_iterations=2, patience=2, learning_rate=0.003, gamma=0.0)
    return start, target, prior, cfg


def test_default_early_stop_keeps_the_unfitted_start_when_the_first_steps_overshoot():
    start, target, prior, cfg = _overshoot_case()
    fit = fit_frame(LinearRenderer(), [None], target, torch.from_numpy(start), prior, cfg)
    assert fit.iterations == 3  # min_iterations 2, then two iterations without progress: stopped
    np.testing.assert_array_equal(fit.verts, start)  # the start guess itself is what is kept
    assert fit.loss == pytest.approx(0.001, rel=1e-4)


def test_stop_requires_progress_fits_the_frame_instead():
    start, target, prior, cfg = _overshoot_case()
    cfg = dataclasses.replace(cfg, stop_requires_progress=True)
    fit = fit_frame(LinearRenderer(), [None], target, torch.from_numpy(start), prior, cfg)
    truth = target[0, 0].numpy()
    assert 3 < fit.iterations < cfg.iterations  # went on past the overshoot, then converged by the usual test
    assert fit.loss < 0.8 * 0.001, fit.loss  # better than the start (0.001), which the default rule keeps
    assert rms(fit.verts, truth) < 0.8 * rms(start, truth)
    # an ordinary frame (the first step already helps) stops exactly as without the option
    far = torch.from_numpy(start + 0.05)[None, None]
    a = fit_frame(LinearRenderer(), [None], far, torch.from_numpy(start), prior, dataclasses.replace(cfg, stop_requires_progress=False))
    b = fit_frame(LinearRenderer(), [None], far, torch.from_numpy(start), prior, cfg)
    assert a.iterations == b.iterations
    np.testing.assert_array_equal(a.verts, b.verts)
