"""The JPEG-LS frame codec: bit-exact on every kind of image, malformed chunks refused, stores of the earlier
codec pipeline still read, and new stores name the codec in their zarr.json and manifest record."""

import json
import struct
import warnings

import numpy as np
import pytest

from clods_bench.datasets.frame_store import CODEC_NAME, LEGACY_CODEC_NAME, LazyFrames, frames_record, write_frames
from clods_bench.datasets.jpegls_codec import MAGIC, decode_images, encode_images
from clods_bench.errors import ClodsError


def images(k: int = 3, h: int = 17, w: int = 23) -> np.ndarray:
    """(k, 1, h, w, 3): noise, flat, a ramp with wrap-around, extremes 0/255 side by side, single-pixel edges."""
    rng = np.random.default_rng(7)
    out = rng.integers(0, 256, (k, 1, h, w, 3), dtype=np.uint8)
    out[:, :, : h // 3] = 128
    out[:, :, h // 3 : h // 2] = (np.arange(w, dtype=np.int64)[None, None, None, :, None] * 37 % 256).astype(np.uint8)
    out[:, :, -2, ::2] = 0
    out[:, :, -2, 1::2] = 255
    out[0, 0, 0, 0] = (255, 0, 255)
    return out


def test_encode_decode_is_bit_exact():
    x = images()
    data = encode_images(x)
    assert data[:4] == MAGIC and struct.unpack_from("<I", data, 4)[0] == 3
    np.testing.assert_array_equal(decode_images(data, x.shape), x)
    flat = np.full((2, 1, 64, 64, 3), 200, np.uint8)
    assert len(encode_images(flat)) < flat.nbytes / 50  # a flat image costs almost nothing


@pytest.mark.parametrize("damage", ["magic", "count", "truncate", "trailing"])
def test_malformed_chunks_are_refused(damage):
    x = images()
    data = bytearray(encode_images(x))
    if damage == "magic":
        data[:4] = b"XXXX"
    elif damage == "count":
        data[4:8] = struct.pack("<I", 2)
    elif damage == "truncate":
        data = data[:-10]
    else:
        data += b"\0\0"
    with pytest.raises(ValueError):
        decode_images(bytes(data), x.shape)


def test_store_round_trip_and_records_the_codec(tmp_path):
    rng = np.random.default_rng(1)
    x = rng.integers(0, 256, (7, 2, 9, 11, 3), dtype=np.uint8)
    x[:, :, :4] = 30
    record = write_frames(tmp_path / "f.zarr", x, chunk_frames=3)  # last time chunk partial (zarr pads it)
    assert record["codec"] == CODEC_NAME
    codecs = [c["name"] for c in json.loads((tmp_path / "f.zarr" / "zarr.json").read_text())["codecs"]]
    assert codecs == ["clods_bench.jpegls", "crc32c"]
    lazy = LazyFrames(tmp_path / "f.zarr")
    np.testing.assert_array_equal(lazy[:], x)
    np.testing.assert_array_equal(lazy[5:7, 1], x[5:7, 1])


def write_legacy(path, x: np.ndarray, k: int) -> None:
    """A frame array as clods-bench wrote them before 2026-11-27: planar transpose, byte delta, blosc-zstd5, crc32c."""
    import zarr
    from zarr.codecs import BloscCodec, BytesCodec, Crc32cCodec, TransposeCodec
    from zarr.codecs.numcodecs import Delta

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        arr = zarr.create_array(store=str(path), shape=x.shape, dtype="uint8", chunks=(k, 1, *x.shape[2:]),
                                filters=[TransposeCodec(order=(0, 1, 4, 2, 3)), Delta(dtype="u1")], serializer=BytesCodec(),
                                compressors=[BloscCodec(cname="zstd", clevel=5, shuffle="noshuffle"), Crc32cCodec()],
                                fill_value=0, chunk_key_encoding={"name": "default", "separator": "."})  # fmt: skip
        arr[:] = x


def test_stores_of_the_earlier_codec_still_read(tmp_path):
    x = images(k=5)[:, 0][:, None].repeat(2, axis=1)  # (5, 2, h, w, 3)
    write_legacy(tmp_path / "old.zarr", x, k=2)
    lazy = LazyFrames(tmp_path / "old.zarr")
    np.testing.assert_array_equal(lazy[:], x)
    assert frames_record(tmp_path / "old.zarr", x.shape)["codec"] == LEGACY_CODEC_NAME
    chunk = tmp_path / "old.zarr" / "c.1.0.0.0.0"
    chunk.write_bytes(chunk.read_bytes()[:-3])  # a damaged legacy chunk still fails naming its file
    with pytest.raises(ClodsError, match="c.1.0.0.0.0"):
        lazy[:, 0]


def test_missing_imagecodecs_is_one_clear_error(tmp_path, monkeypatch):
    from clods_bench.datasets import jpegls_codec

    write_frames(tmp_path / "f.zarr", images(k=2).repeat(2, axis=1), chunk_frames=2)

    def missing():
        raise ImportError("frames stored with JPEG-LS need the 'imagecodecs' package: pip install imagecodecs")

    monkeypatch.setattr(jpegls_codec, "_imagecodecs", missing)
    with pytest.raises(ClodsError, match="imagecodecs") as info:
        LazyFrames(tmp_path / "f.zarr")[:, 0]
    assert "f.zarr" in str(info.value) and "crc32c" not in str(info.value)
