"""The truncated peak's deflections along camera paths and photons: each medium's rate, and the draws (distances at
that rate, cosines from the peak, none where there is no truncated medium or the path has taken its share)."""

import math

import numpy as np
import pytest
from scipy import integrate

from conftest import medium_row
from pbvol_cli.physics.phase import KINDS, TRUNCATION_COS, phase_eval, truncated_share
from pbvol_cli.physics.sampling import seed_state
from pbvol_cli.pointbased.peak_deflections import MAX_TURNS, draw_deflections, peak_rates
from pbvol_cli.pointbased.similarity import truncated


def test_the_rate_is_the_peaks_share_of_the_given_medium_s_scattering():
    """A truncated medium's rate is f sigma_s of the medium as given (its least channel's); media the truncation
    leaves alone do not deflect, and a table without a truncated medium has no rates."""
    g = 0.9
    f = 1.0 - truncated_share(g)
    media = truncated(np.stack([medium_row("hg", g, [0.01, 0.1, 0.25], [0.21, 0.21, 0.21]),
                                medium_row("hg", g, [0.01, 0.1, 0.25], [0.3, 0.04, 0.5]),
                                medium_row("isotropic", 0.0, [0.1] * 3, [1.0] * 3)]))
    rates = peak_rates(media)
    np.testing.assert_allclose(rates, [f * 0.21, f * 0.04, 0.0], rtol=1e-12)
    assert peak_rates(media[2:]) is None
    assert peak_rates(medium_row("hg", g, [0.1] * 3, [1.0] * 3)[None]) is None  # the medium as given: no truncation


def _rays(n, medium=0, turns=0, tmax=1e30):
    dirs = np.tile([0.0, 0.6, 0.8], (n, 1))
    rng = np.array([seed_state(7, 3, i) for i in range(n)], np.uint64)
    return dirs, np.full(n, tmax), np.full(n, medium, np.int64), np.full(n, turns, np.int64), rng


def test_deflections_come_at_the_rate_with_the_peak_s_cosines():
    """Distances are exponential at the medium's rate (their mean 1 / rate; within a tmax, the share turned is
    1 - e^(-rate tmax)), the new directions unit vectors at the peak's cosines from the old (its mean cosine), and
    each turned ray's random state moves on (its next draws differ)."""
    g = 0.9
    media = truncated(medium_row("hg", g, [0.01, 0.1, 0.25], [0.21, 0.21, 0.21])[None])
    rates = peak_rates(media)
    n = 100_000
    dirs, tmax, medium, turns, rng = _rays(n)
    idx, d, new_dir, state = draw_deflections(rates, media, dirs, tmax, medium, turns, rng)
    assert len(idx) == n
    assert d.mean() == pytest.approx(1.0 / rates[0], rel=0.015)  # (its standard error: 0.3 %)
    np.testing.assert_allclose(np.linalg.norm(new_dir, axis=1), 1.0, atol=1e-12)
    cos = new_dir @ dirs[0]
    assert cos.min() >= TRUNCATION_COS - 1e-12
    f = 1.0 - truncated_share(g)
    mean, _ = integrate.quad(lambda mu: mu * 2 * math.pi * (phase_eval(KINDS["hg"], g, mu)
                                                            - phase_eval(KINDS["hg"], g, TRUNCATION_COS)) / f,
                             TRUNCATION_COS, 1.0, limit=400)
    assert cos.mean() == pytest.approx(mean, abs=3e-4)
    assert np.all(state != rng)
    # within tmax = one mean free path of the peak: 1 - 1/e of them
    dirs, tmax, medium, turns, rng = _rays(n, tmax=1.0 / rates[0])
    idx, d, _, _ = draw_deflections(rates, media, dirs, tmax, medium, turns, rng)
    assert len(idx) / n == pytest.approx(1.0 - math.exp(-1.0), abs=0.005)
    assert np.all(d < tmax[idx])


def test_no_deflection_outside_a_truncated_medium_or_past_the_path_s_share():
    """None outside a medium, in a medium that is not truncated, past MAX_TURNS, or on a ray that meets nothing (it
    left its medium through a crack of the mesh)."""
    media = np.stack([truncated(medium_row("hg", 0.9, [0.01] * 3, [0.2] * 3)[None])[0], medium_row("isotropic", 0.0, [0.1] * 3,
                                                                                    [1.0] * 3)])
    rates = peak_rates(media)
    for medium, turns, tmax_ in ((-1, 0, 1e30), (1, 0, 1e30), (0, MAX_TURNS, 1e30), (0, 0, np.inf)):
        dirs, tmax, med, tn, rng = _rays(1000, medium=medium, turns=turns, tmax=tmax_)
        assert len(draw_deflections(rates, media, dirs, tmax, med, tn, rng)[0]) == 0
