"""Phase functions: normalisation, mean cosine, and sampling against the pdf (chi-square); the truncated lobe and
the peak it takes out."""

import math

import numpy as np
import pytest
from numba import njit
from scipy import integrate, stats

from pbvol_cli.physics.phase import (
    KINDS,
    TRUNCATION_COS,
    mean_cosine,
    phase_eval,
    phase_sample,
    truncated_peak_cos,
    truncated_share,
)
from pbvol_cli.physics.sampling import rand, seed_state

CASES = [("isotropic", 0.0), ("hg", 0.0), ("hg", 0.9), ("hg", -0.5), ("schlick", 0.7), ("schlick", -0.3),
         ("rayleigh", 0.0), ("mie_hazy", 0.0), ("mie_murky", 0.0), ("hg_truncated", 0.9), ("hg_truncated", 0.5)]


@pytest.mark.parametrize("name,g", CASES)
def test_integrates_to_one(name, g):
    k = KINDS[name]
    val, _ = integrate.quad(lambda mu: 2 * math.pi * phase_eval(k, g, mu), -1, 1, limit=400, epsabs=1e-12)
    assert val == pytest.approx(1.0, abs=1e-7)


@pytest.mark.parametrize("g", [-0.5, 0.0, 0.3, 0.9])
def test_hg_mean_cosine_is_g(g):
    val, _ = integrate.quad(lambda mu: 2 * math.pi * mu * phase_eval(KINDS["hg"], g, mu), -1, 1, limit=400)
    assert val == pytest.approx(g, abs=1e-7)


@pytest.mark.parametrize("name,g", [(n, g) for n, g in CASES if n in ("isotropic", "hg", "rayleigh", "hg_truncated")])
def test_mean_cosine(name, g):
    """mean_cosine (the transport coefficient's) is the lobe's first moment (Schlick's k is only fitted to g, the Mie
    mixtures' lobes are taken as symmetric)."""
    k = KINDS[name]
    val, _ = integrate.quad(lambda mu: 2 * math.pi * mu * phase_eval(k, g, mu), -1, 1, limit=400, epsabs=1e-12)
    assert mean_cosine(k, g) == pytest.approx(val, abs=1e-9)


@pytest.mark.parametrize("g", [0.3, 0.8, 0.9, 0.99])
def test_truncated_lobe_is_henyey_greenstein_below_its_cap(g):
    """hg_truncated x its share is Henyey-Greenstein itself at every cosine up to TRUNCATION_COS and that value beyond:
    what the truncation takes out is only the peak above the cap, and the share is what is left."""
    hg, tr = KINDS["hg"], KINDS["hg_truncated"]
    share = truncated_share(g)
    for mu in np.linspace(-1.0, 1.0, 401):
        expected = phase_eval(hg, g, min(mu, TRUNCATION_COS))
        assert share * phase_eval(tr, g, mu) == pytest.approx(expected, rel=1e-12)
    peak, _ = integrate.quad(lambda mu: 2 * math.pi * (phase_eval(hg, g, mu) - phase_eval(hg, g, TRUNCATION_COS)),
                             TRUNCATION_COS, 1.0, limit=400, epsabs=1e-12)
    assert 1.0 - share == pytest.approx(peak, abs=1e-9)


@pytest.mark.parametrize("g", [0.05, 0.5, 0.9, 0.99])
def test_the_truncated_peak_is_drawn_by_its_own_distribution(g):
    """truncated_peak_cos inverts the peak's distribution: 2 pi (hg - hg(cap)) / f on [TRUNCATION_COS, 1]. Drawn at
    evenly spaced u, the share of draws below each of ten cosines equals the peak's integral up to it (to 1/n: the
    draws are the distribution's quantiles), and the mean is the peak's mean cosine."""
    hg = KINDS["hg"]
    f = 1.0 - truncated_share(g)
    n = 20000
    cos = np.array([truncated_peak_cos(g, (i + 0.5) / n) for i in range(n)])
    assert np.all(np.diff(cos) >= 0.0) and cos[0] >= TRUNCATION_COS and cos[-1] <= 1.0

    def density(mu):
        return 2 * math.pi * (phase_eval(hg, g, mu) - phase_eval(hg, g, TRUNCATION_COS)) / f

    for c in np.linspace(TRUNCATION_COS, 1.0, 12)[1:-1]:
        below, _ = integrate.quad(density, TRUNCATION_COS, c, limit=400, epsabs=1e-13)
        assert np.mean(cos < c) == pytest.approx(below, abs=2.0 / n)
    mean, _ = integrate.quad(lambda mu: mu * density(mu), TRUNCATION_COS, 1.0, limit=400, epsabs=1e-13)
    assert cos.mean() == pytest.approx(mean, abs=1e-5)


@njit(cache=True)
def _sample_many(kind, g, n, seed):
    out = np.empty((n, 4))
    st = np.empty(1, np.uint64)
    st[0] = seed_state(seed, 0, 0)
    for i in range(n):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = phase_sample(kind, g, 0.0, 0.0, 1.0, rand(st, 0), rand(st, 0),
                                                                 rand(st, 0))
    return out


@pytest.mark.parametrize("name,g", CASES)
def test_sampling_matches_pdf(name, g):
    """Chi-square over (cos theta, phi) bins; the expected counts come from integrating the pdf."""
    k = KINDS[name]
    n = 200_000
    s = _sample_many(k, g, n, 12345)
    # returned pdf equals the phase function at the sampled direction, and directions are unit
    assert np.allclose(np.linalg.norm(s[:, :3], axis=1), 1.0, atol=1e-12)
    assert np.allclose(s[:, 3], [phase_eval(k, g, c) for c in s[:200, 2]] + list(s[200:, 3]), rtol=1e-12)
    mu_edges = np.linspace(-1, 1, 21)
    phi_edges = np.linspace(-math.pi, math.pi, 7)
    counts, _, _ = np.histogram2d(s[:, 2], np.arctan2(s[:, 1], s[:, 0]), bins=[mu_edges, phi_edges])
    p_mu = np.array([integrate.quad(lambda m: 2 * math.pi * phase_eval(k, g, m), a, b, limit=200)[0]
                     for a, b in zip(mu_edges[:-1], mu_edges[1:])])
    expected = np.outer(p_mu, np.full(6, 1 / 6)) * n
    keep = expected > 5
    # pool the sparse bins so that the test statistic stays chi-square distributed
    obs = np.append(counts[keep], counts[~keep].sum())
    exp = np.append(expected[keep], expected[~keep].sum())
    if exp[-1] == 0:
        obs, exp = obs[:-1], exp[:-1]
    _, p = stats.chisquare(obs, exp * obs.sum() / exp.sum())
    assert p > 1e-4, f"chi-square p-value {p:.2e}"
