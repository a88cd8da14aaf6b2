"""Renderer `device`: config checks, moving fitted tensors, and (on a CUDA machine) a GPU fit agreeing with the CPU."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from clods_bench.errors import ClodsError
from clods_bench.plugins.renderers.device import check_device_config, leaf_to, tensors_to
from clods_bench.plugins.renderers.games import GamesConfig, GamesRenderer
from clods_bench.plugins.renderers.gs3d import Gs3dConfig, Gs3dRenderer
from clods_bench.plugins.renderers.losses import render_loss
from clods_bench.plugins.renderers.smgs import SmgsConfig, SmgsRenderer
from clods_bench.splatting.gsplat_backend import gsplat_available

from .conftest import grid_mesh, rig
from .test_games import fitted, randomise

CONFIGS = [GamesConfig, SmgsConfig, Gs3dConfig]


@pytest.mark.parametrize("cls", CONFIGS)
def test_unknown_device_names_the_field(cls) -> None:
    with pytest.raises(ClodsError, match=r"renderer_config\.x\.device.*unknown device 'tpu'"):
        cls(device="tpu").validate("renderer_config.x")


@pytest.mark.parametrize("cls", CONFIGS)
def test_gpu_device_needs_the_gsplat_backend(cls) -> None:
    with pytest.raises(ClodsError, match="device 'cuda' needs backend 'gsplat'"):
        cls(device="cuda", backend="cpu").validate("renderer_config.x")
    cls(device="cuda:1", backend="gsplat").validate("renderer_config.x")  # valid as configuration


def test_fitting_on_cuda_without_a_gpu_says_so(mesh, monkeypatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)  # the same answer on GPU machines
    cams = rig(1, 8)
    with pytest.raises(ClodsError, match="torch sees no CUDA GPU"):
        fitted(mesh, GamesConfig(iterations=0, device="cuda", backend="gsplat"), cams)


def test_tensors_to_moves_nested_tensors_and_leaf_to_keeps_leaves() -> None:
    meta = torch.device("meta")
    obj = {"a": (torch.ones(2), [torch.zeros(1), 3]), "b": "text"}
    moved = tensors_to(obj, meta)
    assert moved["a"][0].device == meta and moved["a"][1][0].device == meta and moved["a"][1][1] == 3 and moved["b"] == "text"
    p = (torch.ones(3) * 2).requires_grad_()
    q = leaf_to(p, meta)
    assert q.is_leaf and q.requires_grad and q.device == meta
    assert not leaf_to(torch.ones(1), meta).requires_grad


def test_cpu_fit_keeps_everything_on_the_cpu(mesh) -> None:
    r = fitted(mesh, SmgsConfig(iterations=2), rig(1, 8), cls=SmgsRenderer)
    assert r.device == torch.device("cpu") and all(p.device.type == "cpu" for p in r.params.values())
    assert all(p.is_leaf for p in r.params.values())


def _target(mesh, cams) -> np.ndarray:
    """(1,N,H,W,3) images of a randomised GaMeS on the CPU: something with structure to fit."""
    r = fitted(mesh, GamesConfig(iterations=0), cams)
    randomise(r, seed=3)
    return r.render(torch.tensor(mesh[0]), cams).detach().numpy()[None].astype(np.float32)


@pytest.mark.skipif(not gsplat_available()[0], reason=f"runs only where gsplat and CUDA are: {gsplat_available()[1]} (ran on an H100, README 'On a GPU')")
@pytest.mark.parametrize("renderer, config", [(GamesRenderer, GamesConfig), (SmgsRenderer, SmgsConfig), (Gs3dRenderer, Gs3dConfig)])
def test_a_fit_on_the_gpu_matches_the_cpu_fit(renderer, config) -> None:
    mesh, cams = grid_mesh(6, 4), rig(3, 32)
    images = _target(mesh, cams)
    verts, cells, mesh_pos = mesh
    results = {}
    for device, backend in (("cpu", "cpu"), ("cuda", "gsplat")):
        r = renderer(config(iterations=60, device=device, backend=backend), seed=0)
        stats = r.fit(verts[None], cells, mesh_pos, images, cams)
        v = torch.tensor(verts, dtype=torch.float32, requires_grad=True)
        out = r.render(v, cams)
        assert out.device.type == "cpu"  # images come back where the vertices were
        if renderer is not Gs3dRenderer:
            assert all(p.device.type == device for p in r.params.values())
            out.sum().backward()
            assert v.grad is not None and torch.isfinite(v.grad).all() and v.grad.abs().max() > 0
        results[device] = (stats, out.detach())
    (s_cpu, img_cpu), (s_gpu, img_gpu) = results["cpu"], results["cuda"]
    assert s_gpu["loss_final"] == pytest.approx(s_cpu["loss_final"], rel=0.05, abs=2e-3)
    assert float((img_gpu - img_cpu).abs().mean()) < 5e-3


@pytest.mark.parametrize("inputs", ["both", "world", "mesh", "none"])
@pytest.mark.parametrize("mesh_grid", [0, 8])
def test_every_tensor_of_a_moved_renderer_follows_it(mesh, inputs: str, mesh_grid: int) -> None:
    """Move a fitted SMGS to the 'meta' device: building its Gaussians and the loss there must not mix in a CPU
    tensor (the code path of CUDA, checked without a GPU: meta refuses CPU operands like CUDA does)."""
    r = fitted(mesh, SmgsConfig(iterations=0, inputs=inputs, mesh_grid=mesh_grid, sh_degree=1), rig(1, 8), cls=SmgsRenderer)
    meta = torch.device("meta")
    r._move_to(meta)
    means, covars, opac, colors = r.gaussians(torch.tensor(mesh[0], dtype=torch.float32).to(meta))
    loss = render_loss(torch.zeros(2, 11, 11, 3, device=meta), torch.zeros(2, 11, 11, 3, device=meta), 0.2)
    assert {t.device for t in (means, covars, opac, colors, loss)} == {meta}


def test_a_cached_fit_loaded_on_the_cpu_goes_back_to_its_device(mesh, tmp_path, monkeypatch) -> None:
    """Stage 1's cache loads a pickled fit with map_location='cpu'; `relocate` puts its tensors back on the device
    the fit names (meta stands in for CUDA: without it, Gaussians built for vertices on that device mix devices,
    the error a cached paper-size run on a GPU hit)."""
    r = fitted(mesh, SmgsConfig(iterations=0, sh_degree=1), rig(1, 8), cls=SmgsRenderer)
    torch.save(r, tmp_path / "r.pt")
    loaded = torch.load(tmp_path / "r.pt", map_location="cpu", weights_only=False)
    meta = torch.device("meta")
    loaded.device = meta  # as after a GPU fit: the attribute names the device, the tensors came back on the CPU
    v = torch.tensor(mesh[0], dtype=torch.float32).to(meta)
    with pytest.raises(RuntimeError, match="device"):
        loaded.gaussians(v)
    loaded.relocate()
    assert {t.device for t in loaded.gaussians(v)} == {meta} and all(p.is_leaf for p in loaded.params.values())
    cuda = torch.load(tmp_path / "r.pt", map_location="cpu", weights_only=False)
    cuda.device = torch.device("cuda")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ClodsError, match="torch sees no CUDA GPU") as e:
        cuda.relocate()
    assert e.value.where == "renderer_config.smgs.device"


def test_meta_refuses_a_cpu_operand() -> None:
    """What the test above relies on: an operation mixing meta and CPU tensors raises."""
    with pytest.raises(RuntimeError, match="device"):
        _ = torch.ones(4, 1, 2, device="meta") * torch.arange(3.0)[None, :, None]
