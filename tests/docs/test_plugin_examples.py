"""The plugin guide's renderer and video-predictor examples run through the NVS and DVC tasks on the tiny dataset.

The simulator and scene examples are installable packages, run by tests/examples/. These two are single modules
of the guide (docs/plugins/examples/), registered in memory as a test of your own plugin would.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from clods_bench.benchmark.core.interfaces import FitContext
from clods_bench.benchmark.running.records import RECORD_FILE
from tests.conftest import tiny_config


def _metrics(rdir: Path) -> dict[str, float]:
    return {k: v["mean"] for k, v in json.loads((rdir / RECORD_FILE).read_text())["metrics"].items()}


def test_the_renderer_example_fits_renders_and_passes_gradients(tiny_root: Path, guide: Any) -> None:
    from clods_bench.datasets.store import DatasetStore

    renderer_mod = guide.modules["docs_example_vertex_splat"]
    store = DatasetStore.open(tiny_config(tiny_root).data.dataset_dir())
    traj, cams = store.load_trajectory(0), store.cameras()
    images = np.asarray(store.frames(0)[0:1], dtype=np.float32)[0] / 255.0  # frame 0: (N,H,W,3)
    train, held = list(range(len(cams) - 1)), [len(cams) - 1]  # fit on all cameras but one, score that one
    r = renderer_mod.VertexSplat(renderer_mod.VertexSplatConfig(), seed=0)
    verts = traj.world_pos[0].astype(np.float32)
    stats = r.fit(verts[None], traj.cells, traj.mesh_pos, images[train][None], [cams[i] for i in train])
    assert stats["num_gaussians"] == verts.shape[0]
    v = torch.tensor(verts, requires_grad=True)
    out = r.render(v, [cams[i] for i in held])
    assert out.shape == (len(held), *images.shape[1:])
    truth = torch.from_numpy(images[held])
    fitted_l1 = float((out.detach() - truth).abs().mean())
    white_l1 = float((1.0 - truth).abs().mean())  # what rendering nothing shows: the white background
    assert fitted_l1 < 0.9 * white_l1, (fitted_l1, white_l1)
    out.sum().backward()
    assert v.grad is not None and torch.isfinite(v.grad).all() and float(v.grad.abs().sum()) > 0


def test_the_renderer_example_runs_the_nvs_task(tmp_path: Path, tiny_root: Path, guide: Any) -> None:
    from clods_bench.benchmark.running.runner import run_task

    cfg = tiny_config(tmp_path, f"data.root={tiny_root / 'data'}", task="nvs", renderer="vertex-splat")
    m = _metrics(run_task(cfg, guide.registry))
    assert math.isfinite(m["psnr"]) and 0.0 < m["ssim"] <= 1.0


def _least_squares_gain(videos: list[np.ndarray]) -> float:
    """The gain g minimising sum (d[t+1] - g d[t])^2 over every pixel, by an explicit loop over videos and frames."""
    num = den = 0.0
    for video in videos:
        v = video.astype(np.float64)
        for t in range(2, v.shape[0]):
            prev, nxt = (v[t - 1] - v[t - 2]).ravel(), (v[t] - v[t - 1]).ravel()
            num += float(prev @ nxt)
            den += float(prev @ prev)
    return num / den


def test_the_predictor_example_fits_the_least_squares_gain(tmp_path: Path, guide: Any) -> None:
    mod = guide.modules["docs_example_momentum_predictor"]
    rng = np.random.default_rng(0)
    base = rng.uniform(0.2, 0.8, (1, 6, 5, 3))
    step = rng.normal(0, 0.02, (1, 6, 5, 3))
    videos = [np.clip(base + np.cumsum(np.repeat(step, 7, 0) * 0.7 ** np.arange(7)[:, None, None, None], 0), 0, 1).astype(np.float32)]
    videos.append(rng.uniform(0, 1, (5, 6, 5, 3)).astype(np.float32))  # noise: pulls the gain down
    pred = mod.MomentumPredictor(mod.MomentumConfig())
    stats = pred.fit(videos, FitContext(work_dir=tmp_path, seed=0))
    assert stats["gain"] == pytest.approx(min(max(_least_squares_gain(videos), 0.0), 1.0), rel=1e-9)
    context = np.stack([videos[0][:4], videos[0][1:5]])  # two views
    out = pred.predict(context, 3, [])
    g, last, change = stats["gain"], context[:, -1].astype(np.float64), (context[:, -1] - context[:, -2]).astype(np.float64)
    expected = np.clip(last[:, None] + np.array([g, g + g * g, g + g * g + g**3])[None, :, None, None, None] * change[:, None], 0, 1)
    np.testing.assert_allclose(out, expected, atol=1e-6)
    copy = mod.MomentumPredictor(mod.MomentumConfig(max_gain=0.0))
    copy.fit(videos, FitContext(work_dir=tmp_path, seed=0))
    assert np.array_equal(copy.predict(context, 3, []), np.repeat(context[:, -1:], 3, axis=1))


def test_the_predictor_example_runs_the_dvc_task_like_copy_last_at_gain_zero(tmp_path: Path, tiny_root: Path, guide: Any) -> None:
    from clods_bench.benchmark.running.runner import run_task

    registry = guide.registry
    base = [f"data.root={tiny_root / 'data'}"]

    def run(predictor: str, *extra: str) -> dict[str, float]:
        return _metrics(run_task(tiny_config(tmp_path, *base, *extra, task="dvc", predictor=predictor, label=predictor + "".join(extra)), registry))

    zero = run("momentum", "video_config.momentum.max_gain=0.0")
    copylast = run("copylast")
    assert {k: zero[k] for k in ("psnr", "ssim", "rmse")} == {k: copylast[k] for k in ("psnr", "ssim", "rmse")}
    fitted = run("momentum")
    assert math.isfinite(fitted["psnr"])
