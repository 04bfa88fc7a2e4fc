"""Tests for pbvol_cli.imageio: EXR round trips, metadata, layers, PNG tone mapping, errors."""

import os

import numpy as np
import OpenImageIO as oiio
import pytest

from pbvol_cli.errors import PbvolError
from pbvol_cli.imageio import (
    read_exr,
    read_layers,
    tonemap_srgb,
    write_exr,
    write_png,
    write_preview_png,
)


def _rand(shape, seed=0):
    return np.random.default_rng(seed).random(shape, dtype=np.float32) * 10.0


def test_exr_round_trip_bit_exact(tmp_path):
    img = _rand((17, 23, 3))
    img[0, 0] = [0.0, 1e-30, 3.4e38]  # denormal-ish and huge values survive too
    meta = {"spp": 256, "name": "volpt 0.1", "sigma_t": 1.25, "albedo": 0.1, "empty": "",
            "seed": 2**40, "neg": -7}
    p = tmp_path / "out.exr"
    write_exr(p, img, meta)
    back, md = read_exr(p)
    assert back.dtype == np.float32 and back.shape == (17, 23, 3)
    assert np.array_equal(back.view(np.uint32), img.view(np.uint32))
    assert md == meta
    assert type(md["spp"]) is int and type(md["albedo"]) is float and type(md["name"]) is str
    assert read_layers(p) == {}


def test_exr_header_is_float_zip_with_prefixed_attributes(tmp_path):
    p = tmp_path / "out.exr"
    write_exr(p, _rand((4, 5, 3)), {"spp": 8})
    inp = oiio.ImageInput.open(str(p))
    spec = inp.spec()
    inp.close()
    assert spec.format == oiio.FLOAT
    assert tuple(spec.channelnames) == ("R", "G", "B")
    assert spec.getattribute("compression") == "zip"
    assert spec.getattribute("pbvol:spp") == 8


def test_exr_layers_round_trip(tmp_path):
    img = _rand((8, 9, 3), 1)
    layers = {"albedo": _rand((8, 9, 3), 2), "normal": _rand((8, 9, 3), 3) - 5.0}
    p = tmp_path / "aov.exr"
    write_exr(p, img, {"k": "v"}, layers=layers)

    inp = oiio.ImageInput.open(str(p))
    names = set(inp.spec().channelnames)
    inp.close()
    assert names == {"R", "G", "B", "albedo.R", "albedo.G", "albedo.B",
                     "normal.R", "normal.G", "normal.B"}

    back, md = read_exr(p)
    assert np.array_equal(back, img)
    assert md == {"k": "v"}
    got = read_layers(p)
    assert set(got) == {"albedo", "normal"}
    for k, v in layers.items():
        assert got[k].shape == (8, 9, 3) and got[k].dtype == np.float32
        assert np.array_equal(got[k], v)


def test_non_contiguous_input(tmp_path):
    base = _rand((10, 12, 4), 4)
    view = base[::2, ::-1, 2::-1]  # strided rows, reversed columns and channels
    assert not view.flags.c_contiguous
    p = tmp_path / "nc.exr"
    write_exr(p, view, layers={"x": base[::2, :, :3]})
    back, _ = read_exr(p)
    assert np.array_equal(back, view)
    assert np.array_equal(read_layers(p)["x"], base[::2, :, :3])
    # float64 input is converted
    write_exr(p, view.astype(np.float64))
    assert np.array_equal(read_exr(p)[0], view)
    # non-contiguous uint8 PNG
    u8 = tonemap_srgb(base[:, :, :3])[:, ::-1]
    q = tmp_path / "nc.png"
    write_png(q, u8)
    inp = oiio.ImageInput.open(str(q))
    px = inp.read_image(oiio.UINT8)
    inp.close()
    assert np.array_equal(px, u8)


def test_atomic_write_leaves_no_temp_files(tmp_path):
    write_exr(tmp_path / "a.exr", _rand((3, 3, 3)))
    write_preview_png(tmp_path / "a.png", _rand((3, 3, 3)))
    assert sorted(os.listdir(tmp_path)) == ["a.exr", "a.png"]
    # overwriting an existing file works
    write_exr(tmp_path / "a.exr", np.zeros((2, 2, 3)))
    assert read_exr(tmp_path / "a.exr")[0].shape == (2, 2, 3)
    assert sorted(os.listdir(tmp_path)) == ["a.exr", "a.png"]


def test_write_failure_raises_pbvol_error(tmp_path):
    missing_dir = tmp_path / "no" / "such" / "out.exr"
    with pytest.raises(PbvolError) as ei:
        write_exr(missing_dir, np.zeros((2, 2, 3)))
    msg = str(ei.value)
    assert "out.exr" in msg and "\n" not in msg
    with pytest.raises(PbvolError, match="x.unknownext"):
        write_png(tmp_path / "x.unknownext", np.zeros((2, 2, 3), np.uint8))
    assert os.listdir(tmp_path) == []


def test_read_missing_and_unreadable_files(tmp_path):
    with pytest.raises(PbvolError) as ei:
        read_exr(tmp_path / "missing.exr")
    assert "missing.exr" in str(ei.value) and "\n" not in str(ei.value)

    bad = tmp_path / "garbage.exr"
    bad.write_bytes(b"this is not an exr file at all")
    for fn in (read_exr, read_layers):
        with pytest.raises(PbvolError) as ei:
            fn(bad)
        assert "garbage.exr" in str(ei.value) and "\n" not in str(ei.value)


def test_read_one_and_four_channel_files(tmp_path):
    y = _rand((5, 6, 1), 5)
    p1 = tmp_path / "y.exr"
    out = oiio.ImageOutput.create(str(p1))
    spec = oiio.ImageSpec(6, 5, 1, oiio.FLOAT)
    assert out.open(str(p1), spec) and out.write_image(y) and out.close()
    img, md = read_exr(p1)
    assert img.shape == (5, 6, 3) and md == {}
    assert np.array_equal(img, np.repeat(y, 3, axis=2))

    rgba = _rand((5, 6, 4), 6)
    p4 = tmp_path / "rgba.exr"
    out = oiio.ImageOutput.create(str(p4))
    spec = oiio.ImageSpec(6, 5, 4, oiio.FLOAT)
    assert out.open(str(p4), spec) and out.write_image(rgba) and out.close()
    img, _ = read_exr(p4)
    assert np.array_equal(img, rgba[:, :, :3])

    # other formats OIIO reads: an 8-bit PNG comes back normalised to [0, 1]
    u8 = np.arange(5 * 6 * 3, dtype=np.uint8).reshape(5, 6, 3)
    write_png(tmp_path / "p.png", u8)
    img, _ = read_exr(tmp_path / "p.png")
    assert np.allclose(img, u8 / 255.0, atol=1e-6)


def test_tonemap_known_values():
    vals = np.array([0.0, 0.0031308, 0.5, 1.0, 2.0, -1.0, 0.18], dtype=np.float32)
    out = tonemap_srgb(np.repeat(vals[None, :, None], 3, axis=2))
    assert out.dtype == np.uint8 and out.shape == (1, 7, 3)
    got = out[0, :, 0].astype(int)
    assert got[0] == 0
    assert abs(got[1] - 10) <= 1
    assert got[2] == 188
    assert got[3] == 255 and got[4] == 255
    assert got[5] == 0
    assert got[6] == 118  # middle grey


def test_tonemap_exposure_and_nonfinite():
    img = np.full((2, 2, 3), 0.25, dtype=np.float32)
    assert (tonemap_srgb(img, exposure=1.0) == 188).all()  # 0.25 * 2 = 0.5
    assert (tonemap_srgb(img * 4.0, exposure=-1.0) == 188).all()
    bad = np.array([[[np.nan, np.inf, -np.inf]]], dtype=np.float32)
    assert tonemap_srgb(bad).tolist() == [[[0, 255, 0]]]


def test_preview_png_written(tmp_path):
    img = np.full((7, 11, 3), 0.5, dtype=np.float32)
    p = tmp_path / "prev.png"
    write_preview_png(p, img)
    inp = oiio.ImageInput.open(str(p))
    spec = inp.spec()
    px = inp.read_image(oiio.UINT8)
    inp.close()
    assert (spec.width, spec.height, spec.nchannels) == (11, 7, 3)
    assert (px == 188).all()
