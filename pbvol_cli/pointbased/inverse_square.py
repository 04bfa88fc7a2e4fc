"""Double scattering's smoothed kernel: a point source's attenuated 1/r^2 averaged over a ball of the source's extent.

A volume sample stands for light scattered anywhere along its segment and across its beam: its 1/r^2 is averaged
over a ball of that extent instead of clamped, exactly (closed forms, with quadrature where they cancel).
"""

import math

import numpy as np
from numba import njit


@njit(inline="always", cache=True)
def inv_r2_ball(r, c):
    """Mean of 1/|P - x|^2 over x uniform in a ball of radius c, |P| = r: the 1/r^2 of a source smeared over its
    extent instead of a hard clamp (3/c^2 at the centre, continuous, -> 1/r^2 far away):
    3/(2 r c^3) [r c + (c^2 - r^2)/2 ln((c + r)/|c - r|)]."""
    if c <= 0.0 or r > 4.0 * c:
        return 1.0 / (r * r) if r > 0.0 else np.inf
    if r < 1e-6 * c:
        return 3.0 / (c * c)
    if abs(r - c) < 1e-9 * c:
        return 1.5 / (c * c)
    return 1.5 / (r * c ** 3) * (r * c + 0.5 * (c * c - r * r) * math.log((c + r) / abs(c - r)))


_GL_X = np.array([-0.9324695142031521, -0.6612093864662645, -0.2386191860831969, 0.2386191860831969,
                  0.6612093864662645, 0.9324695142031521])
_GL_W = np.array([0.1713244923791704, 0.3607615730481386, 0.4679139345726910, 0.4679139345726910,
                  0.3607615730481386, 0.1713244923791704])


@njit(inline="always", cache=True)
def _expint_e1(x):
    """E1(x) = int_x^inf e^-t / t dt, x > 0 (Abramowitz & Stegun 5.1.53 and 5.1.56: error < 2e-7)."""
    if x <= 1.0:
        return (-math.log(x) - 0.57721566 + x * (0.99999193 + x * (-0.24991055 + x * (0.05519968 + x * (
            -0.00976004 + x * 0.00107857)))))
    num = x * (x * (x * (x + 8.5733287401) + 18.0590169730) + 8.6347608925) + 0.2677737343
    den = x * (x * (x * (x + 9.5733223454) + 25.6329561486) + 21.0996530827) + 3.9584969228
    return num / den * math.exp(-x) / x


@njit(inline="always", cache=True)
def _exp_over_r(a, b, s):
    """int_a^b e^(-s t) / t dt, 0 < a < b, s >= 0: Gauss-Legendre where the interval is narrow (the difference of
    E1's would cancel), E1's otherwise."""
    if b < 4.0 * a:
        h, m = 0.5 * (b - a), 0.5 * (b + a)
        acc = 0.0
        for k in range(6):
            t = m + h * _GL_X[k]
            acc += _GL_W[k] * math.exp(-s * t) / t
        return h * acc
    if s * b < 1e-6:
        return math.log(b / a) - s * (b - a)
    return _expint_e1(s * a) - _expint_e1(s * b)


@njit(cache=True)
def attenuated_inv_r2_ball(r, c, s):
    """Mean of e^(-s |P - x|) / |P - x|^2 over x uniform in a ball of radius c, |P| = r (s: extinction, 1/length):
    a point source's attenuated 1/r^2 smeared over the source's extent. Unlike e^(-s r) inv_r2_ball(r, c), it
    keeps the kernel's integral over space (4 pi / s): smoothing 1/r^2 alone moves the near field's weight to
    where the attenuation at the centre distance is stronger (docs/pbl.md). Spherical shells about P: the shell of
    radius t holds 4 pi t^2 of ball
    for t < c - r, pi t (c^2 - (t - r)^2) / r for |c - r| < t < c + r."""
    if c <= 0.0 or r > 4.0 * c:
        return math.exp(-s * r) / (r * r) if r > 0.0 else np.inf
    if s * (r + c) < 1e-7:
        return inv_r2_ball(r, c)
    if r < 1e-4 * c:  # P at the centre: 4 pi int_0^c e^-st dt
        return 3.0 / (c ** 3) * (-math.expm1(-s * c)) / s
    inner = 4.0 * math.pi * (-math.expm1(-s * (c - r))) / s if r < c else 0.0
    a, b = abs(c - r), c + r
    if r > c and s * a > 2.0:
        # outside the ball and many mean free paths from it the closed form below cancels: with t = a + u,
        # c^2 - (t - r)^2 = u (2c - u), integrated over the part of [0, 2c] where e^-su matters (two panels)
        top = min(2.0 * c, 16.0 / s)
        acc = 0.0
        for lo_, hi_ in ((0.0, 0.25 * top), (0.25 * top, top)):
            h, m = 0.5 * (hi_ - lo_), 0.5 * (hi_ + lo_)
            for k in range(6):
                u = m + h * _GL_X[k]
                acc += h * _GL_W[k] * u * (2.0 * c - u) / (a + u) * math.exp(-s * u)
        shell = math.pi / r * math.exp(-s * a) * acc
        return 3.0 / (4.0 * math.pi * c ** 3) * shell
    ea, eb = math.exp(-s * a), math.exp(-s * b)
    # (pi / r) int_a^b [(c^2 - r^2)/t - t + 2 r] e^-st dt
    lin = (a / s + 1.0 / (s * s)) * ea - (b / s + 1.0 / (s * s)) * eb
    const = (ea - eb) / s
    cap = (c * c - r * r) * _exp_over_r(a, b, s) if a > 0.0 else 0.0
    shell = math.pi / r * (cap - lin + 2.0 * r * const)
    return 3.0 / (4.0 * math.pi * c ** 3) * (inner + shell)
