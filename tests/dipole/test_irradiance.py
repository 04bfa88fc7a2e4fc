"""The dipole's irradiance samples: how many, and the power they let in."""

import numpy as np

from conftest import build, camera
from pbvol_cli.dipole.irradiance import place_irradiance_samples, sample_count
from pbvol_cli.dipole.profile import diffuse_fresnel


def slab_scene(eta=1.5, mfp=0.05):
    shape = {"type": "box", "size": [4.0, 1.0, 4.0], "interface": "dielectric", "eta": eta,
             "medium": {"albedo": 0.99, "mean_free_path": mfp, "g": 0.0}}
    return {"camera": camera((16, 16), position=(0.0, 3.0, 0.3), fov=8), "render": {"spp": 1},
            "lights": [{"type": "environment", "radiance": 1.0}], "shapes": [shape]}


def test_count_follows_the_mean_free_path(tmp_path):
    """0.5 mean free paths apart on the box's 48 square units: 0.547 x 48 / (pi 0.025^2 / 4) samples; the bounds."""
    bs = build(tmp_path, slab_scene())
    count, wanted = sample_count(bs, 0.5, 16, 10**8)
    assert count == wanted and abs(wanted - 0.547 * 48 / (np.pi * 0.025 ** 2 / 4)) < 2
    assert sample_count(bs, 0.5, 16, 1000) == (1000, wanted)
    assert sample_count(bs, 100.0, 4096, 10**8) == (4096, 4096)


def test_power_into_a_sky_lit_face(tmp_path):
    """Under a white sky of radiance 1 the top face lets in pi (1 - F_dr,out) per unit area (Fresnel of each
    direction). 8000 samples, one sky direction each (half of them face away: the sum's noise about 1.5 %)."""
    bs = build(tmp_path, slab_scene())
    s = place_irradiance_samples(bs, 8000, 8, 8, seed=3)
    top = s.normal[:, 1] > 0.5
    assert np.all(s.medium == 0) and np.all(s.area > 0)
    # where the light entered: on the face, a ray epsilon inside
    assert np.all(np.abs(s.pos[top, 1] - 0.5) < 1e-3) and np.all(np.abs(s.pos[top][:, [0, 2]]) <= 2.0)
    got = s.power[top].sum(0) / 16.0
    expected = np.pi * (1 - diffuse_fresnel(1.5))
    assert np.all(np.abs(got / expected - 1) < 0.05), (got, expected)
    # every face: the same per unit area (the sky is all around)
    np.testing.assert_allclose(s.power.sum(0) / 48.0, expected, rtol=0.05)
