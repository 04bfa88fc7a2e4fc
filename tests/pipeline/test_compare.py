"""Tests for pbvol_cli.pipeline.compare."""

import json
import math

import numpy as np
import OpenImageIO as oiio
import pytest

from pbvol_cli.errors import PbvolError
from pbvol_cli.pipeline.compare import error_image_png, format_report, image_metrics


def _img(h=16, w=20, seed=0):
    return np.random.default_rng(seed).random((h, w, 3)).astype(np.float32)


def test_constant_offset_mse_and_psnr():
    a = _img()
    b = a + 0.1
    m = image_metrics(a, b)
    assert m["mse"] == pytest.approx(0.01, abs=1e-6)
    peak = float(b.max())
    assert m["peak"] == pytest.approx(peak)
    assert m["psnr"] == pytest.approx(10 * math.log10(peak**2 / m["mse"]), rel=1e-12)
    assert m["psnr"] == pytest.approx(10 * math.log10(peak**2 / 0.01), abs=1e-3)
    expected_rel = np.mean(0.01 / (b.astype(np.float64) ** 2 + 1e-2))
    assert m["rel_mse"] == pytest.approx(expected_rel, rel=1e-4)
    for ch in "RGB":
        assert m["per_channel"][ch]["mse"] == pytest.approx(0.01, abs=1e-6)
    assert m["max_abs_error"] == pytest.approx(0.1, abs=1e-6)
    assert (m["width"], m["height"], m["channels"]) == (20, 16, 3)


def test_difference_only_in_green():
    b = _img(seed=1)
    a = b.copy()
    a[:, :, 1] += 0.3
    m = image_metrics(a, b)
    pc = m["per_channel"]
    assert pc["R"]["mse"] == 0.0 and pc["B"]["mse"] == 0.0
    assert pc["R"]["psnr"] == "inf" and pc["B"]["psnr"] == "inf"
    assert pc["G"]["mse"] == pytest.approx(0.09, abs=1e-6)
    assert m["mse"] == pytest.approx(0.03, abs=1e-6)  # mean over the three channels
    assert isinstance(pc["G"]["psnr"], float)
    assert pc["G"]["rel_mse"] > 0 and pc["R"]["rel_mse"] == 0.0


def test_identical_images_and_json():
    a = _img(seed=2)
    m = image_metrics(a, a.copy())
    assert m["mse"] == 0.0 and m["rel_mse"] == 0.0 and m["psnr"] == "inf"
    text = json.dumps(m, allow_nan=False)  # no NaN/Infinity tokens
    assert json.loads(text) == m


def test_shape_mismatch():
    with pytest.raises(PbvolError, match="A is 256x256, B is 128x128"):
        image_metrics(np.zeros((256, 256, 3)), np.zeros((128, 128, 3)))
    with pytest.raises(PbvolError, match="A is 30x20, B is 20x30"):
        image_metrics(np.zeros((20, 30, 3)), np.zeros((30, 20, 3)))


def test_nonfinite_input():
    a = _img(seed=3)
    b = a.copy()
    b[0, 0, 0] = np.nan
    b[1, 1, :] = np.nan
    b[2, 2, 2] = np.inf
    with pytest.raises(PbvolError) as ei:
        image_metrics(a, b)
    msg = str(ei.value)
    assert "B has 3 non-finite pixel" in msg and "2 NaN" in msg and "1 inf" in msg
    assert "A has" not in msg and "\n" not in msg
    bad = a.copy()
    bad[5, 5, 1] = -np.inf
    with pytest.raises(PbvolError, match=r"A has 1 non-finite pixel\(s\) \(0 NaN, 1 inf\)"):
        image_metrics(bad, a)
    with pytest.raises(PbvolError):
        error_image_png(a, b, "/nonexistent/never-written.png")


def test_error_png(tmp_path):
    a = _img(12, 34, seed=4)
    b = a.copy()
    b[3:6, 10:20] += 0.5
    p = tmp_path / "diff.png"
    scale = error_image_png(a, b, p)
    assert p.exists() and scale > 0
    inp = oiio.ImageInput.open(str(p))
    spec = inp.spec()
    px = inp.read_image(oiio.UINT8)
    inp.close()
    assert (spec.width, spec.height, spec.nchannels) == (34, 12, 3)
    # zero-error pixels get the bottom colour, the changed block the top colour
    assert tuple(px[0, 0]) == (0x44, 0x01, 0x54)
    assert tuple(px[4, 15]) == (0xFD, 0xE7, 0x25)


def test_error_png_identical_and_mismatch(tmp_path):
    a = _img(seed=5)
    p = tmp_path / "same.png"
    assert error_image_png(a, a, p) == 0.0
    inp = oiio.ImageInput.open(str(p))
    px = inp.read_image(oiio.UINT8)
    inp.close()
    assert (px == np.array([0x44, 0x01, 0x54], np.uint8)).all()
    with pytest.raises(PbvolError, match="A is 20x16, B is 10x8"):
        error_image_png(a, a[::2, ::2], tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


def test_format_report():
    a = _img(seed=6)
    b = a.copy()
    b[:, :, 0] += 0.05
    m = image_metrics(a, b)
    text = format_report(m, "render.exr", "reference.exr")
    assert "render.exr" in text and "reference.exr" in text
    for token in ("MSE", "relMSE", "PSNR", "all", "R", "G", "B", "inf", "20x16"):
        assert token in text


def test_flip_grows_with_the_visible_difference():
    """HDR-FLIP: 0 for identical images, small for a 5 % exposure change, larger for strong noise, near 1 for
    black against grey (values measured: 0, 0.050, 0.22, 0.96)."""
    rng = np.random.default_rng(1)
    ref = rng.random((32, 32, 3)) * 5
    flip = [image_metrics(a, b)["flip"] for a, b in (
        (ref, ref), (ref * 1.05, ref), (ref + rng.normal(0, 0.5, ref.shape), ref),
        (np.zeros((8, 8, 3)), np.full((8, 8, 3), 0.1)))]
    assert flip[0] == 0.0 and 0.0 < flip[1] < 0.1 < flip[2] < 0.5 < flip[3] <= 1.0, flip


def test_pixel_failure_counts():
    a = np.zeros((4, 5, 3))
    b = a.copy()
    b[0, 0, 1] = 0.5
    b[3, 4] = 0.05
    m = image_metrics(a, b, pixel_threshold=0.1)
    assert m["pixels_over"] == 1 and m["pixels_over_percent"] == 5.0
    assert image_metrics(a, b, pixel_threshold=0.01)["pixels_over"] == 2
    assert "pixels_over" not in image_metrics(a, b)


def test_compare_gates_layers_and_channels(tmp_path):
    """--fail-above METRIC=VALUE, repeated; --layer and --channel; exit 0 (within), 2 (differs), 1 (cannot
    compare)."""
    from typer.testing import CliRunner

    from pbvol_cli.imageio import write_exr
    from pbvol_cli.main import app

    runner = CliRunner()
    base = np.full((6, 6, 3), 0.5, np.float32)
    red = base.copy()
    red[..., 0] += 0.2
    write_exr(tmp_path / "a.exr", base, layers={"single": base, "vpl": base})
    write_exr(tmp_path / "b.exr", red, layers={"single": base, "vpl": red})
    a, b = str(tmp_path / "a.exr"), str(tmp_path / "b.exr")

    def run(*args):
        return runner.invoke(app, ["compare", b, a, "-q", *args]).exit_code

    assert run("--fail-above", "mse=0.1", "--fail-above", "flip=0.9") == 0
    assert run("--fail-above", "rel-mse=1e-3") == 2
    assert run("--fail-above", "mse=0.1", "--fail-above", "flip=0.01") == 2
    assert run("--layer", "single", "--fail-above", "mse=0") == 0
    assert run("--layer", "vpl", "--fail-above", "mse=0") == 2
    assert run("--channel", "G", "--fail-above", "mse=0") == 0
    assert run("--channel", "R", "--fail-above", "mse=0") == 2
    assert run("--pixel-threshold", "0.1", "--fail-above", "pixels=36") == 0  # all 36 pixels differ by 0.2
    assert run("--pixel-threshold", "0.1", "--fail-above", "pixels-percent=50") == 2
    for bad in (["--layer", "nope"], ["--channel", "A"], ["--fail-above", "speed=3"], ["--fail-above", "mse=x"],
                ["--fail-above", "pixels=3"]):
        assert run(*bad) == 1, bad
