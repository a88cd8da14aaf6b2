"""Procedural texture (determinism, detail everywhere, distinct regions, seamless tiling) and file I/O."""

import numpy as np
import pytest

from clods_bench.datasets.textures import load_texture, procedural_texture, save_texture
from clods_bench.errors import ClodsError


@pytest.fixture(scope="module")
def tex() -> np.ndarray:
    return procedural_texture(256, seed=0)


def test_shape_range_and_determinism(tex):
    assert tex.shape == (256, 256, 3) and tex.dtype == np.float32
    assert tex.min() >= 0.0 and tex.max() <= 1.0
    np.testing.assert_array_equal(tex, procedural_texture(256, seed=0))
    assert np.abs(tex - procedural_texture(256, seed=1)).mean() > 0.1
    # colourful: channels differ (not grey) and hues cover the range
    assert np.abs(tex - tex.mean(-1, keepdims=True)).mean() > 0.05


def test_gradients_everywhere(tex):
    """Every 8x8 patch has visible variation, so photometric alignment has a signal everywhere."""
    patches = tex.reshape(32, 8, 32, 8, 3).transpose(0, 2, 1, 3, 4).reshape(32 * 32, 64, 3)
    assert patches.std(axis=1).max(axis=1).min() > 0.01


def test_no_two_regions_look_alike(tex):
    """32x32 patches on a 16 px grid (overlapping ones excluded) differ by > 0.07 RMS (~18/255) from each other."""
    starts = range(0, 256 - 32 + 1, 16)
    pos = [(r, c) for r in starts for c in starts]
    patches = np.stack([tex[r : r + 32, c : c + 32].ravel() for r, c in pos]).astype(np.float64)
    sq = (patches**2).sum(1)
    rms = np.sqrt(np.maximum(sq[:, None] + sq[None] - 2 * patches @ patches.T, 0) / patches.shape[1])
    p = np.array(pos)
    far = (np.abs(p[:, None] - p[None]).max(-1)) >= 32
    assert rms[far].min() > 0.07  # seeds 0-7 give 0.09-0.12


def test_tiles_seamlessly(tex):
    """Differences across the wrap-around seam are like those across the same structure inside:
    column 0 and column 128 both start a checker cell and a dark grid line."""
    seam_x = np.abs(tex[:, 0] - tex[:, -1]).mean()
    inside_x = np.abs(tex[:, 128] - tex[:, 127]).mean()
    seam_y = np.abs(tex[0] - tex[-1]).mean()
    inside_y = np.abs(tex[128] - tex[127]).mean()
    assert seam_x < 2.0 * inside_x and seam_y < 2.0 * inside_y
    # and away from cell/line boundaries the seam is as smooth as a plain interior step
    typical = np.abs(np.diff(tex, axis=1)).mean()
    assert seam_x < 10 * typical


def test_bad_size():
    with pytest.raises(ClodsError, match="size"):
        procedural_texture(4)


def test_save_load_round_trip(tmp_path, tex):
    path = tmp_path / "sub" / "tex.png"
    save_texture(path, tex)
    back = load_texture(path)
    assert back.shape == tex.shape and back.dtype == np.float32
    np.testing.assert_allclose(back, tex, atol=0.5 / 255 + 1e-6)
    assert [p.name for p in path.parent.iterdir()] == ["tex.png"]  # no temp file left


def test_load_grey_and_rgba(tmp_path):
    import imageio.v3 as iio

    grey = (np.arange(12, dtype=np.uint8) * 20).reshape(3, 4)
    iio.imwrite(tmp_path / "g.png", grey)
    g = load_texture(tmp_path / "g.png")
    assert g.shape == (3, 4, 3)
    np.testing.assert_allclose(g[..., 1], grey / 255.0, atol=1e-6)
    rgba = np.random.default_rng(0).integers(0, 256, (5, 6, 4), dtype=np.uint8)
    iio.imwrite(tmp_path / "a.png", rgba)
    np.testing.assert_allclose(load_texture(tmp_path / "a.png"), rgba[..., :3] / 255.0, atol=1e-6)
    ramp = np.linspace(0, 1, 32)
    smooth = np.stack(np.broadcast_arrays(ramp[None, :], ramp[:, None], 0.5 + 0 * ramp[None, :]), -1)
    iio.imwrite(tmp_path / "c.jpg", (smooth * 255).astype(np.uint8))
    assert np.abs(load_texture(tmp_path / "c.jpg") - smooth).max() < 0.05  # lossy, but smooth survives


def test_missing_or_unreadable_file_names_the_path(tmp_path):
    with pytest.raises(ClodsError) as info:
        load_texture(tmp_path / "nope.png")
    assert "nope.png" in str(info.value)
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not an image at all")
    with pytest.raises(ClodsError) as info:
        load_texture(junk)
    assert "junk.png" in str(info.value)
    with pytest.raises(ClodsError, match="shape"):
        save_texture(tmp_path / "x.png", np.zeros((4, 4)))
