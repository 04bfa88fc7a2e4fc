"""How far the multiple-scattering table reaches for a body: as far as its light spreads, from the default 40 mean
free paths, so that a thick forward-scattering body keeps the light that diffuses past 40."""

import numpy as np
import pytest

from pbvol_cli.multiple_scattering.extent import (AUTO_EXTENT_MAX, DEFAULT_EXTENT, TABLE_REACH, auto_extent,
                                                  light_spread, table_extents)


def grey(albedo):
    """(sigma_a, sigma_s) of a grey medium of mean free path 1."""
    return np.full(3, 1.0 - albedo), np.full(3, albedo)


def test_light_spreads_over_two_diffusion_lengths_or_the_body_whichever_is_less():
    # isotropic, albedo 0.999: 1 / sigma_tr = 1 / sqrt(3 * 0.001 * 1) = 18.26 mean free paths
    assert light_spread(*grey(0.999), 0.0, 1e6)[0] == pytest.approx(TABLE_REACH * 18.257, rel=1e-4)
    assert light_spread(*grey(0.999), 0.0, 10.0)[0] == pytest.approx(10.0)
    # g 0.8 makes a transport mean free path five mean free paths: light diffuses sqrt(5) times farther
    ratio = light_spread(*grey(0.999), 0.8, 1e6)[0] / light_spread(*grey(0.999), 0.0, 1e6)[0]
    assert ratio == pytest.approx(np.sqrt(1.0 / (1.0 - 0.8 * 0.999)), rel=1e-9)
    # no absorption: as far as the body; no extinction: nowhere
    assert light_spread(np.zeros(3), np.ones(3), 0.0, 500.0)[0] == 500.0
    assert np.all(light_spread(np.zeros(3), np.zeros(3), 0.0, 500.0) == 0.0)
    # in mean free paths: a denser channel of the same albedo spreads over as many diffusion lengths, more mfp
    sa, ss = np.array([0.001, 0.002, 0.004]), np.array([0.999, 1.998, 3.996])
    assert np.allclose(light_spread(sa, ss, 0.0, 1e6), light_spread(sa, ss, 0.0, 1e6)[0])
    assert np.allclose(light_spread(sa, ss, 0.0, 20.0), [20.0, 36.51, 36.51], rtol=1e-3)


def test_auto_extent_is_at_least_the_default_a_multiple_of_its_step_and_bounded():
    assert [auto_extent(s) for s in (0.0, 12.0, 40.0, 40.5, 150.0, 160.0, 1e9)] == \
        [DEFAULT_EXTENT, 40.0, 40.0, 80.0, 160.0, 160.0, AUTO_EXTENT_MAX]


def test_a_number_is_taken_as_given_and_a_body_without_a_size_gets_the_default():
    sa, ss = grey(0.9998)
    assert np.all(table_extents(sa, ss, 0.8, 150.0, 12.5) == 12.5)
    assert np.all(table_extents(sa, ss, 0.8, None, "auto") == DEFAULT_EXTENT)
    # the forward-scattering sphere of docs/pbl.md (150 mean free paths across, g 0.8): 160
    assert np.all(table_extents(sa, ss, 0.8, 150.0, "auto") == 160.0)


def test_channels_that_share_an_albedo_share_the_wider_extent():
    """They read one table: it must hold the channel whose light spreads over more mean free paths."""
    sa = np.array([0.0002, 0.0004, 0.05])
    ss = np.array([0.9998, 1.9996, 0.95])  # R and G: albedo 0.9998, G twice as dense; B: 0.95
    e = table_extents(sa, ss, 0.8, 150.0, "auto")
    assert e[0] == e[1] == auto_extent(float(np.max(light_spread(sa, ss, 0.8, 150.0)[:2])))
    assert e[2] == DEFAULT_EXTENT
