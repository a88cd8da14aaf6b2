"""Dataset identity: a changed scene definition or generator is never mistaken for the data already on disk."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from clods_bench.datasets.data_config import DATA_GENERATOR_VERSION, DataConfig
from clods_bench.datasets.generate import generate, scene_fingerprint
from clods_bench.datasets.scenes import get_scene
from clods_bench.errors import ClodsError


def test_edited_scene_is_a_clear_error_and_prose_is_not(tmp_path: Path) -> None:
    d = DataConfig(resolution=[4, 3], num_train=2, num_test=1, num_steps=4, interp_steps=2, render_frames=False, root=str(tmp_path))
    flag = get_scene("flag")
    generate(d, flag, progress=False)
    assert d.identity()["generator_version"] == DATA_GENERATOR_VERSION
    reworded = dataclasses.replace(flag, description="the same flag, described differently")
    assert scene_fingerprint(reworded) == scene_fingerprint(flag)
    generate(d, reworded, progress=False)  # same data: resumes (nothing to do)
    windier = dataclasses.replace(flag, wind_speed_range=(9.0, 9.0))
    with pytest.raises(ClodsError, match="different config: .*scene_spec"):
        generate(d, windier, progress=False)


def test_texture_decides_the_dataset_dir(tmp_path: Path) -> None:
    """Named textures and a file texture's bytes (not only its path) change the dataset directory; the default
    texture keeps the directory it had before named textures (computed with main's code)."""
    assert DataConfig(seed=5).dataset_dir() == Path("data/flag-e820d43b33")
    dirs = {name: DataConfig(texture=name).dataset_dir() for name in ("procedural", "stripes", "weave")}
    assert len(set(dirs.values())) == 3
    img = tmp_path / "cloth.png"
    img.write_bytes(b"first version")
    d = DataConfig(texture=f"file:{img}")
    before = d.dataset_dir()
    assert before == DataConfig(texture=f"file:{img}").dataset_dir() and before not in dirs.values()
    img.write_bytes(b"second version")
    assert d.dataset_dir() != before
    with pytest.raises(ClodsError, match="cannot read texture file") as err:
        DataConfig(texture=f"file:{tmp_path / 'gone.png'}").dataset_dir()
    assert err.value.where == "data.texture"


def test_file_texture_dataset_stores_the_files_pixels(tmp_path: Path) -> None:
    """A generated dataset with a file texture stores that texture (texture.png equals the file's pixels)."""
    import imageio.v3 as iio
    import numpy as np

    from clods_bench.datasets.generate import TEXTURE_FILE

    pixels = np.random.default_rng(1).integers(0, 256, (32, 48, 3), dtype=np.uint8)
    iio.imwrite(tmp_path / "cloth.png", pixels)
    d = DataConfig(resolution=[4, 3], num_train=2, num_test=1, num_steps=4, interp_steps=2, image_size=16,
                   num_cameras=2, num_views_test=1, texture=f"file:{tmp_path / 'cloth.png'}", root=str(tmp_path / "data"))  # fmt: skip
    generate(d, get_scene("flag"), progress=False)
    np.testing.assert_array_equal(iio.imread(d.dataset_dir() / TEXTURE_FILE), pixels)
