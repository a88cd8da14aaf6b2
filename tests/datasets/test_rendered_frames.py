"""Frames rendered on demand (`data.frames=on_demand`) against the frames generation stores, byte for byte."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.core.config import load_config
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.running.run_data import ensure_dataset
from clods_bench.datasets.data_config import DataConfig
from clods_bench.datasets.rendered_frames import RENDER_SETUP, RenderedFrames, read_render_setup
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError

SMALL = ["data.num_train=2", "data.num_test=1", "data.num_steps=8", "data.interp_steps=5", "data.image_size=32", "data.num_cameras=4",
         "data.num_views_test=1"]  # fmt: skip


def _pair(root: Path, *extra: str) -> tuple[DatasetStore, DatasetStore]:
    reg = default_registry()
    stored = ensure_dataset(load_config("ci", overrides=[f"data.root={root}", *SMALL, *extra]), reg, progress=False)
    rendered = ensure_dataset(load_config("ci", overrides=[f"data.root={root}", *SMALL, *extra, "data.frames=on_demand"]), reg, progress=False)
    return stored, rendered


@pytest.mark.parametrize("scene", ["flag", "flag-lit", "sphere-drop"])  # textured, lit and shadowed, with a flat-coloured obstacle
def test_on_demand_frames_equal_the_stored_frames(tmp_path: Path, scene: str) -> None:
    stored, rendered = _pair(tmp_path, f"data.scene={scene}", *(["data.resolution=[8,6]"] if scene == "sphere-drop" else []))
    assert rendered.frames_on_demand and not stored.frames_on_demand
    assert stored.root != rendered.root and not list(rendered.root.glob("frames_*"))  # no frame arrays on disk
    for i in range(3):
        want = stored.frames(i).read(slice(None), slice(None))
        got = rendered.frames(i)
        assert isinstance(got, RenderedFrames) and got.shape == want.shape
        np.testing.assert_array_equal(got.read(slice(None), slice(None)), want)
        np.testing.assert_array_equal(got[2:5, [3, 0]], want[2:5][:, [3, 0]])
        np.testing.assert_array_equal(got[6, 1], want[6, 1])


def test_only_what_is_read_is_rendered_and_the_cache_is_bounded(tmp_path: Path) -> None:
    stored, rendered = _pair(tmp_path)
    frames = rendered.frames(0)
    frames.read([1, 2], [0, 3])
    assert frames.images_rendered == 4
    frames.read([2, 1], [3, 0, 0])  # all cached: nothing rendered again
    assert frames.images_rendered == 4
    small = RenderedFrames(rendered.load_trajectory(0), rendered.cameras(), read_render_setup(rendered.root / RENDER_SETUP),
                           rendered.root / RENDER_SETUP, cache_mb=2.5 * 32 * 32 * 3 / 2**20)  # fmt: skip
    assert small.capacity == 2
    want = stored.frames(0).read(slice(None), slice(None))
    np.testing.assert_array_equal(small.read(slice(None), slice(None)), want)  # correct while evicting all the time
    assert small.images_rendered == 8 * 4 and len(small._cache) == 2
    small.read([7], [3])  # the most recent image is still cached
    assert small.images_rendered == 32
    lazy = rendered.frames(1).select(slice(2, 8), [3, 1])  # what stage 2 walks: nothing rendered until a frame is read
    assert lazy.base.images_rendered == 0
    np.testing.assert_array_equal(lazy[4], stored.frames(1)[6, [3, 1]])
    assert lazy.base.images_rendered == 2


def test_on_demand_options_and_damage_are_clear_errors(tmp_path: Path) -> None:
    assert "frames" not in DataConfig().identity()  # the default leaves every earlier dataset's identity as it was
    reg = default_registry()
    with pytest.raises(ClodsError, match="unknown frames mode") as err:
        ensure_dataset(load_config("ci", overrides=[f"data.root={tmp_path}", *SMALL, "data.frames=lazy"]), reg, progress=False)
    assert "data.frames" in str(err.value)
    with pytest.raises(ClodsError, match="render_frames is off"):
        ensure_dataset(load_config("ci", overrides=[f"data.root={tmp_path}", *SMALL, "data.frames=on_demand", "data.render_frames=false"]),
                       reg, progress=False)  # fmt: skip
    _, rendered = _pair(tmp_path)
    setup = rendered.root / RENDER_SETUP
    setup.write_bytes(setup.read_bytes()[:100])
    with pytest.raises(ClodsError, match="truncated") as err:
        DatasetStore.open(rendered.root).frames(0)
    assert RENDER_SETUP in str(err.value)
