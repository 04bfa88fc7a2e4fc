"""The render stage refuses to pass off a failed image as a result, and work that cannot fit."""

import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import camera, write_scene
from pbvol_cli.errors import PbvolError
from pbvol_cli.main import app
from pbvol_cli.pipeline.render import ABSURD_FACTOR, implausible_pixels

runner = CliRunner()


def test_implausible_pixels_names_non_finite_and_absurd_values():
    img = np.full((4, 4, 3), 0.5)
    assert implausible_pixels(img) is None
    assert implausible_pixels(np.zeros((4, 4, 3))) is None  # black is a possible image
    bad = img.copy()
    bad[1, 2, 0] = np.nan
    assert "1 pixels with non-finite values" in implausible_pixels(bad)
    layers = {"bounced": img.copy()}
    layers["bounced"][0, 0] = np.inf
    assert "layer 'bounced'" in implausible_pixels(img, layers)
    bad = img.copy()
    bad[0, 0] = 0.5 * ABSURD_FACTOR * 10  # ten times beyond the bound
    assert "brighter than" in implausible_pixels(bad)
    # a light seen directly may be that bright: its radiance raises the bound
    assert implausible_pixels(bad, light_radiance=0.5 * 20) is None


def test_a_render_with_non_finite_pixels_exits_3_naming_the_file(tmp_path, monkeypatch):
    import pbvol_cli.render.volpath as volpath

    def broken(built, spp, *args, **kwargs):
        W, H = built.resolution
        img = np.full((H, W, 3), 0.1)
        img[0, 0] = np.nan
        return img, spp, {"time_s": 0.0}

    monkeypatch.setattr(volpath, "render_volpath", broken)
    scene = write_scene(tmp_path, {"camera": camera((4, 4)), "lights": [{"type": "environment", "radiance": 1.0}]})
    r = runner.invoke(app, ["render", str(scene), "-o", str(tmp_path / "o.exr"), "-q"])
    assert r.exit_code == 3, r.output  # EXIT_RENDER_FAILED: not bad input
    assert "o.exr" in r.stderr and "non-finite" in r.stderr and "\n" not in r.stderr.strip()


def test_an_image_or_light_samples_too_large_for_the_memory_are_refused_before_the_work():
    from pbvol_cli.config import PblSettings
    from pbvol_cli.pipeline.render import check_memory

    check_memory("pbl", 512, 512, available=1 << 30)  # fits
    with pytest.raises(PbvolError, match=r"--resolution 16384x16384: the pbl image buffers need about 200.0 GiB"):
        check_memory("pbl", 16384, 16384, available=8 << 30)
    # the defaults: 20k surface samples x 16 segments x 9 generations at 350 B, about 0.94 GiB at most
    check_memory("pbl", 512, 512, PblSettings(), available=2 << 30)
    with pytest.raises(PbvolError, match=r"s\.toml: render\.pbl\.surface_samples = 2000000: the light samples may "
                                         r"need up to about 93\.9 GiB, 7\.8 GiB is available"):
        check_memory("pbl", 512, 512, PblSettings(surface_samples=2_000_000), "s.toml", available=8 << 30)
