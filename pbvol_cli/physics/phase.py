"""Phase functions: evaluate, sample, pdf. All are normalised over the sphere (1/sr).

Convention: cos_t is the cosine between the propagation direction before scattering and after
(cos_t = 1 is forward scattering), as for Henyey-Greenstein with g > 0 forward.

Kinds (ids used in the medium table):
  0 isotropic    1/(4 pi)
  1 hg           Henyey-Greenstein with asymmetry g
  2 schlick      (1 - k^2) / (4 pi (1 - k cos)^2), k = 1.55 g - 0.55 g^3 (Blasi et al.; the slides' k)
  3 rayleigh     3/(16 pi) (1 + cos^2)
  4 mie_hazy     (0.5 + 4.5 ((1 + cos)/2)^8) / (4 pi)      (Nishita et al., pbrt-v1)
  5 mie_murky    (0.5 + 16.5 ((1 + cos)/2)^32) / (4 pi)
  6 hg_truncated Henyey-Greenstein with asymmetry g capped at its value at cos = TRUNCATION_COS and renormalised:
                 what is left of the lobe once the forward peak above the cap is taken out (pbl's
                 [render.pbl] similarity = "truncated", pointbased/similarity.py; not a material's phase)
Every kind is sampled exactly (pdf == value).
"""

import math

from numba import njit

from pbvol_cli.physics.sampling import around

KINDS = {"isotropic": 0, "hg": 1, "schlick": 2, "rayleigh": 3, "mie_hazy": 4, "mie_murky": 5, "hg_truncated": 6}
INV_4PI = 1.0 / (4.0 * math.pi)
TRUNCATION_COS = 0.9  # hg_truncated's cap: the lobe's value 26 degrees off its axis. On the bumpy sphere (g 0.9)
# the peak within 37, 26, 18, 11.5 degrees taken out reads a bias of 0.00108, 0.00050, 0.00019, 0.00009 over 8 x 8
# blocks against the medium as given (the delta-Eddington transform 0.00119), and pbl's noise grows as the cone
# narrows: 26 degrees gave the least error at eight passes (docs/pbl.md, section 2, "Truncated")


@njit(inline="always", cache=True)
def _hg(g, cos_t):
    d = 1.0 + g * g - 2.0 * g * cos_t
    return INV_4PI * (1.0 - g * g) / (d * math.sqrt(d))


@njit(inline="always", cache=True)
def _hg_cdf(g, cos_t):
    """Henyey-Greenstein's share (g != 0) scattered at cosines below cos_t."""
    return (1.0 - g * g) / (2.0 * g) * (1.0 / math.sqrt(1.0 + g * g - 2.0 * g * cos_t) - 1.0 / (1.0 + g))


@njit(cache=True)
def truncated_share(g):
    """The share of a Henyey-Greenstein lobe (g > 0) left below its cap (kind 6): 1 - f, f the forward peak's."""
    return _hg_cdf(g, TRUNCATION_COS) + 2.0 * math.pi * _hg(g, TRUNCATION_COS) * (1.0 - TRUNCATION_COS)


@njit(cache=True)
def mean_cosine(kind, g):
    """The phase function's mean cosine: g for Henyey-Greenstein and Schlick (whose k is fitted to it), the
    capped lobe's own for hg_truncated, 0 for the others (the Mie mixtures' forward lobes taken as symmetric)."""
    if kind == 1 or kind == 2:
        return g
    if kind == 6:
        # the first moment of Henyey-Greenstein below the cap (closed form, u = 1 + g^2 - 2 g cos) and of the cap
        uc = 1.0 + g * g - 2.0 * g * TRUNCATION_COS
        below = (1.0 - g * g) / (4.0 * g * g) * ((1.0 + g * g) * (1.0 / math.sqrt(uc) - 1.0 / (1.0 + g))
                                                  - (1.0 + g - math.sqrt(uc)))
        cap = math.pi * _hg(g, TRUNCATION_COS) * (1.0 - TRUNCATION_COS * TRUNCATION_COS)
        return (below + cap) / truncated_share(g)
    return 0.0


@njit(inline="always", cache=True)
def schlick_k(g):
    return 1.55 * g - 0.55 * g * g * g


@njit(cache=True)
def phase_eval(kind, g, cos_t):
    """Value of the phase function (1/sr) at cosine cos_t."""
    if kind == 1:
        return _hg(g, cos_t)
    if kind == 0:
        return INV_4PI
    if kind == 6:
        return min(_hg(g, cos_t), _hg(g, TRUNCATION_COS)) / truncated_share(g)
    if kind == 2:
        k = schlick_k(g)
        d = 1.0 - k * cos_t
        return INV_4PI * (1.0 - k * k) / (d * d)
    if kind == 3:
        return 3.0 / (16.0 * math.pi) * (1.0 + cos_t * cos_t)
    x = 0.5 * (1.0 + cos_t)
    if kind == 4:
        return INV_4PI * (0.5 + 4.5 * x**8)
    return INV_4PI * (0.5 + 16.5 * x**32)


@njit(cache=True)
def phase_sample_cos(kind, g, u1):
    """Sample cos_t with density 2 pi * phase(cos_t) on [-1, 1] from u1 in [0, 1) (u2 picks a lobe)."""
    if kind == 1:
        if abs(g) < 1e-3:
            return 1.0 - 2.0 * u1
        s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u1)
        return min(1.0, max(-1.0, (1.0 + g * g - s * s) / (2.0 * g)))
    if kind == 0:
        return 1.0 - 2.0 * u1
    if kind == 6:  # the inverse of the capped lobe's distribution: Henyey-Greenstein's below the cap, flat above
        t = u1 * truncated_share(g)
        below = _hg_cdf(g, TRUNCATION_COS)
        if t >= below:
            return min(1.0, TRUNCATION_COS + (t - below) / (2.0 * math.pi * _hg(g, TRUNCATION_COS)))
        s = (1.0 - g * g) / (1.0 - g + 2.0 * g * t)
        return min(1.0, max(-1.0, (1.0 + g * g - s * s) / (2.0 * g)))
    if kind == 2:
        k = schlick_k(g)
        return min(1.0, max(-1.0, (2.0 * u1 + k - 1.0) / (2.0 * k * u1 - k + 1.0)))
    if kind == 3:
        # CDF (3/8)(mu + mu^3/3 + 4/3) = u  ->  mu^3 + 3 mu + 4 - 8u = 0 (Cardano, one real root).
        q = 4.0 - 8.0 * u1
        r = math.sqrt(q * q / 4.0 + 1.0)
        a = -q / 2.0 + r
        b = -q / 2.0 - r
        return math.copysign(abs(a) ** (1.0 / 3.0), a) + math.copysign(abs(b) ** (1.0 / 3.0), b)
    return 1.0 - 2.0 * u1  # isotropic half of the Mie mixtures; phase_sample picks the lobe


PEAK_STEPS = 40  # truncated_peak_cos's safeguarded Newton steps at most (5-7 taken; bisection took 48 halvings and
# 0.74 us a draw, a tenth of the bumpy sphere's deflected passes: docs/pbl.md, section 12)


@njit(cache=True)
def truncated_peak_cos(g, u):
    """The cosine at u in [0, 1) of the forward peak that hg_truncated takes out of a Henyey-Greenstein lobe of
    g > 0: the density 2 pi (hg(cos) - hg(TRUNCATION_COS)) / f on [TRUNCATION_COS, 1], f = 1 - truncated_share(g),
    by inverting its distribution F (no closed form). F - u f is increasing and convex in cos: Newton's steps from
    the Henyey-Greenstein inverse at the same share (which lies at or below the root), each kept within the
    bracket the signs so far give (bisected where a step would leave it), to a step under 1e-9 (an error of order
    1e-18 after it; within 3e-9 of 60 bisections, whose own sign tests are rounding-bound where the density
    vanishes at the cap)."""
    low = _hg_cdf(g, TRUNCATION_COS)
    cap = _hg(g, TRUNCATION_COS)
    flat = 2.0 * math.pi * cap
    target = u * (1.0 - truncated_share(g))
    s = (low + target) * 2.0 * g / (1.0 - g * g) + 1.0 / (1.0 + g)  # 1 / sqrt(1 + g^2 - 2 g c) at that share
    c = min(max((1.0 + g * g - 1.0 / (s * s)) / (2.0 * g), TRUNCATION_COS), 1.0)
    a, b = TRUNCATION_COS, 1.0
    for _ in range(PEAK_STEPS):
        f = _hg_cdf(g, c) - low - flat * (c - TRUNCATION_COS) - target
        if f < 0.0:
            a = c
        else:
            b = c
        slope = 2.0 * math.pi * (_hg(g, c) - cap)
        step = f / slope if slope > 0.0 else 0.0
        nxt = c - step
        if not (a < nxt < b):
            nxt = 0.5 * (a + b)
        elif abs(step) < 1e-9:  # converging quadratically: this step leaves an error of order step^2
            return nxt
        c = nxt
    return c


@njit(cache=True)
def phase_sample(kind, g, dx, dy, dz, u1, u2, u3):
    """Sample an outgoing direction around the propagation direction d. Returns (wx, wy, wz, pdf)."""
    if kind == 4 or kind == 5:
        # Equal-weight mixture of an isotropic part and the lobe ((1+cos)/2)^n, sampled by inversion.
        n = 8.0 if kind == 4 else 32.0
        if u3 < 0.5:
            cos_t = 1.0 - 2.0 * u1
        else:
            cos_t = 2.0 * u1 ** (1.0 / (n + 1.0)) - 1.0
    else:
        cos_t = phase_sample_cos(kind, g, u1)
    w = around(cos_t, 2.0 * math.pi * u2, dx, dy, dz)
    return w[0], w[1], w[2], phase_eval(kind, g, cos_t)
