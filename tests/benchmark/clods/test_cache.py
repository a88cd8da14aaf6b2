"""Stage-2 cache: a finished trajectory is read back without rendering, an interrupted one resumes mid-way."""

from __future__ import annotations

import dataclasses
import zipfile

import numpy as np
import pytest
import torch

from clods_bench.benchmark.clods.cache import ExtractionCache
from clods_bench.benchmark.clods.config import ClodsConfig
from clods_bench.benchmark.clods.extract import extract_trajectory
from clods_bench.benchmark.core.cache_keys import digest

from .conftest import smooth_deformation

CFG = ClodsConfig(iterations=4, min_iterations=4, gamma=0.001)


class Counting:
    """Wraps a renderer, counts render calls and raises after `fail_after` of them (a simulated interruption)."""

    def __init__(self, inner, fail_after: int | None = None) -> None:
        self.inner, self.calls, self.fail_after = inner, 0, fail_after

    def render(self, verts, cameras):
        if self.fail_after is not None and self.calls >= self.fail_after:
            raise KeyboardInterrupt("simulated interruption")
        self.calls += 1
        return self.inner.render(verts, cameras)


@pytest.fixture(scope="module")
def video(scene) -> np.ndarray:
    r, cams, verts, nt = scene["renderer"], scene["cams"], scene["verts"], scene["node_type"]
    truth = [verts] + [smooth_deformation(verts, nt, 0.01 * k) for k in (1, 2, 3)]
    with torch.no_grad():
        return np.stack([(r.render(torch.from_numpy(t), cams).numpy() * 255).round().astype(np.uint8) for t in truth])


def test_digest_changes_with_every_field():
    base = ClodsConfig().extraction_identity()
    assert digest(base) == digest(dict(base))
    for field, value in (("gamma", 0.0), ("iterations", 7), ("init_noise", "gaussian"), ("num_cameras", 1), ("start", "previous")):
        assert digest(dataclasses.replace(ClodsConfig(), **{field: value}).extraction_identity()) != digest(base), field
    # bookkeeping fields do not change what is extracted
    assert ClodsConfig(cache_dir="/x", num_threads=1, variant="finetune").extraction_identity() == base


def test_resume_after_interruption_and_reuse(scene, video, tmp_path):
    args = (scene["cams"], video, scene["verts"], scene["cells"], scene["node_type"], CFG)
    reference = extract_trajectory(Counting(scene["renderer"]), *args)  # uninterrupted, no cache

    cache = ExtractionCache(tmp_path, "k", {"test": 1})
    broken = Counting(scene["renderer"], fail_after=2 * CFG.iterations + 1)  # dies in frame 3's optimisation
    with pytest.raises(KeyboardInterrupt):
        extract_trajectory(broken, *args, cache=cache, index=5)
    partial = cache.load(5, partial=True)
    assert partial is not None and partial.num_frames == 3 and cache.load(5) is None
    with zipfile.ZipFile(cache.path(5, partial=True)) as z:  # rewritten every frame: stored, not deflated
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_STORED}

    resumed_renderer = Counting(scene["renderer"])
    resumed = extract_trajectory(resumed_renderer, *args, cache=cache, index=5)
    assert resumed_renderer.calls == CFG.iterations  # only the last frame was optimised again
    np.testing.assert_allclose(resumed.world_pos, reference.world_pos, atol=1e-6)
    assert cache.load(5, partial=True) is None and cache.path(5).exists()

    again = Counting(scene["renderer"])
    reused = extract_trajectory(again, *args, cache=cache, index=5)
    assert again.calls == 0
    np.testing.assert_array_equal(reused.world_pos, resumed.world_pos)
    np.testing.assert_array_equal(reused.iterations, [0, CFG.iterations, CFG.iterations, CFG.iterations])
