"""The similarity transforms: what the delta-Eddington one keeps (absorption, the transport coefficient, the phase
function's mean cosine), what the truncation keeps (absorption, the scattering beyond its cone), and what both leave
alone."""

import numpy as np
import pytest

from conftest import medium_row
from pbvol_cli.geometry.scene_build import MED_G, MED_MAJORANT, MED_PHASE, MED_SIGMA_A, MED_SIGMA_S
from pbvol_cli.physics.phase import KINDS, TRUNCATION_COS, phase_eval
from pbvol_cli.pointbased.similarity import TRUNCATED_MIN_G, delta_eddington, truncated


@pytest.mark.parametrize("g", [0.3, 0.7, 0.9, 0.99])
def test_keeps_absorption_transport_and_mean_cosine(g):
    sigma_a, sigma_s = np.array([0.01, 0.1, 0.25]), np.array([0.21, 0.21, 0.21])
    out = delta_eddington(medium_row("hg", g, sigma_a, sigma_s)[None])[0]
    sa, ss, gs = out[MED_SIGMA_A:MED_SIGMA_A + 3], out[MED_SIGMA_S:MED_SIGMA_S + 3], out[MED_G]
    f = g * g
    np.testing.assert_array_equal(sa, sigma_a)
    np.testing.assert_allclose(ss * (1.0 - gs), sigma_s * (1.0 - g), rtol=1e-12)  # transport coefficient
    np.testing.assert_allclose(f + (1.0 - f) * gs, g, rtol=1e-12)  # the delta's and the lobe's mean cosine
    np.testing.assert_allclose(ss, (1.0 - f) * sigma_s, rtol=1e-12)
    assert out[MED_MAJORANT] == pytest.approx(np.max(sa + ss))
    assert 0.0 < gs < g


def test_leaves_other_media_and_the_input_alone():
    media = np.stack([medium_row("isotropic", 0.0, [0.1] * 3, [1.0] * 3), medium_row("hg", 0.0, [0.1] * 3, [1.0] * 3),
                      medium_row("hg", -0.5, [0.1] * 3, [1.0] * 3), medium_row("schlick", 0.8, [0.1] * 3, [1.0] * 3),
                      medium_row("hg", 0.9, [0.1] * 3, [1.0] * 3)])
    before = media.copy()
    out = delta_eddington(media)
    np.testing.assert_array_equal(media, before)
    np.testing.assert_array_equal(out[:4], media[:4])
    assert out[4, MED_G] == pytest.approx(0.9 / 1.9)


@pytest.mark.parametrize("g", [0.3, 0.7, 0.9, 0.99])
def test_truncation_keeps_absorption_and_the_scattering_beyond_its_cone(g):
    """sigma_s* p*(cos) equals sigma_s p(cos) wherever cos <= TRUNCATION_COS: outside the cone the truncated medium
    scatters exactly as the medium given; inside it, its forward peak goes on as unscattered light."""
    sigma_a, sigma_s = np.array([0.01, 0.1, 0.25]), np.array([0.21, 0.3, 0.5])
    out = truncated(medium_row("hg", g, sigma_a, sigma_s)[None])[0]
    sa, ss = out[MED_SIGMA_A:MED_SIGMA_A + 3], out[MED_SIGMA_S:MED_SIGMA_S + 3]
    np.testing.assert_array_equal(sa, sigma_a)
    assert out[MED_PHASE] == KINDS["hg_truncated"] and out[MED_G] == g
    assert out[MED_MAJORANT] == pytest.approx(np.max(sa + ss))
    for mu in np.linspace(-1.0, TRUNCATION_COS, 50):
        np.testing.assert_allclose(ss * phase_eval(KINDS["hg_truncated"], g, mu),
                                   sigma_s * phase_eval(KINDS["hg"], g, mu), rtol=1e-12)
    assert np.all(ss < sigma_s)


def test_truncation_leaves_other_media_and_the_input_alone():
    media = np.stack([medium_row("isotropic", 0.0, [0.1] * 3, [1.0] * 3), medium_row("hg", 0.0, [0.1] * 3, [1.0] * 3),
                      medium_row("hg", -0.5, [0.1] * 3, [1.0] * 3), medium_row("schlick", 0.8, [0.1] * 3, [1.0] * 3),
                      medium_row("hg", 0.5 * TRUNCATED_MIN_G, [0.1] * 3, [1.0] * 3), medium_row("hg", 0.9, [0.1] * 3, [1.0] * 3)])
    before = media.copy()
    out = truncated(media)
    np.testing.assert_array_equal(media, before)
    np.testing.assert_array_equal(out[:5], media[:5])
    assert out[5, MED_PHASE] == KINDS["hg_truncated"]
    assert out[5, MED_SIGMA_S] == pytest.approx(0.301, abs=0.001)  # f = 0.70 of g = 0.9's lobe lies above the cap
