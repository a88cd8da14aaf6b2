"""Procedural texture (determinism, detail everywhere, distinct regions, seamless tiling) and file I/O."""

import numpy as np
import pytest

from clods_bench.datasets.textures import (
    STRIPE_PERIODS, TEXTURE_NAMES, load_texture, make_named_texture, procedural_texture, save_texture, texture_file,
)
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


# ---- named textures and file textures (data.texture)

LUMA = np.array([0.299, 0.587, 0.114])


def test_procedural_is_bit_identical_to_before() -> None:
    """sha256 of the float32 bytes, computed with main's code before named textures existed (same numpy)."""
    import hashlib

    want = {0: "45a01384884bafb6cc9a0e01a4bb95c915c387ec389bd1e63bae1d59952711c1",
            3: "70f16901d8db42a74a9097541dc3eb0ab7170939048366c64135111b64cf90b6"}  # fmt: skip
    for seed, digest in want.items():
        assert hashlib.sha256(make_named_texture("procedural", seed).tobytes()).hexdigest() == digest


def test_stripes_dominant_period_is_the_configured_one() -> None:
    """The FFT of the row luminance peaks at STRIPE_PERIODS cycles per side; nothing varies along a row."""
    tex = make_named_texture("stripes", seed=2)
    lum = tex @ LUMA
    assert lum.std(axis=1).max() == 0.0
    spectrum = np.abs(np.fft.rfft(lum[:, 0] - lum[:, 0].mean()))
    assert int(np.argmax(spectrum)) == STRIPE_PERIODS
    assert tex.shape[0] / np.argmax(spectrum) == 512 // STRIPE_PERIODS
    assert lum.std() > 0.05  # two clearly different colours


def test_weave_is_low_contrast_and_tiles() -> None:
    weave, multi = make_named_texture("weave", seed=1), make_named_texture("procedural", seed=1)
    lw, lm = weave @ LUMA, multi @ LUMA
    assert lw.std() < 0.03 and lw.std() < lm.std() / 5  # measured: 0.016 against 0.17
    assert lw.std() > 0.005  # still a pattern, not a flat colour
    # the wrap-around seam is a thread boundary like column 256's: the step across it is alike
    for tile in (weave, weave.transpose(1, 0, 2)):
        seam, inside = np.abs(tile[:, 0] - tile[:, -1]).mean(), np.abs(tile[:, 256] - tile[:, 255]).mean()
        assert seam < 1.5 * inside
    np.testing.assert_array_equal(weave, make_named_texture("weave", seed=1))
    assert np.abs(weave - make_named_texture("weave", seed=2)).mean() > 0.02


def test_file_texture_is_the_files_pixels(tmp_path) -> None:
    import imageio.v3 as iio

    pixels = np.random.default_rng(0).integers(0, 256, (24, 40, 3), dtype=np.uint8)
    iio.imwrite(tmp_path / "cloth.png", pixels)
    for spec in (f"file:{tmp_path / 'cloth.png'}", str(tmp_path / "cloth.png")):
        tex = make_named_texture(spec, seed=0)
        np.testing.assert_array_equal(tex, pixels.astype(np.float32) / 255.0)
    assert texture_file("file:a/b") is not None and texture_file("weave") is None


@pytest.mark.parametrize("case", ["missing", "empty", "garbage", "two_channels"])
def test_bad_file_texture_names_field_and_file(tmp_path, case: str) -> None:
    import imageio.v3 as iio

    path = tmp_path / f"{case}.png"
    if case == "empty":
        path.write_bytes(b"")
    elif case == "garbage":
        path.write_bytes(b"not an image at all")
    elif case == "two_channels":
        iio.imwrite(path, np.zeros((8, 8, 2), dtype=np.uint8))
    with pytest.raises(ClodsError) as err:
        make_named_texture(f"file:{path}", seed=0)
    assert err.value.where == "data.texture" and path.name in err.value.message
    assert {"missing": "not found", "empty": "is empty", "garbage": "cannot read", "two_channels": "shape"}[case] in err.value.what


def test_unknown_texture_name_lists_the_known_ones() -> None:
    with pytest.raises(ClodsError) as err:
        make_named_texture("strips", seed=0)
    assert err.value.where == "data.texture"
    assert all(name in err.value.what for name in TEXTURE_NAMES) and "stripes" in (err.value.hint or "")
