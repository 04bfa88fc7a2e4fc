"""Heterogeneous and emissive media: density fields, and the null-collision tracking that renders them unbiased
(seed 003, "Heterogeneous media", "Emission"; Kutz et al. 2017, "Spectral and decomposition tracking").

A medium's coefficients are its material's sigma_a and sigma_s (RGB) times a density d(x) >= 0: a grid of voxels
(trilinear between voxel centres, 0 outside its box) or a * exp(-b h) with h the height along a direction. It may
emit: the source term sigma_a(x) L_e(x) per unit length, L_e the material's emission (times a second grid where the
material names one).

Tracking. Tentative collisions are sampled at the scalar majorant mu = max over space and channels of sigma_t (the
media table's MED_MAJORANT). At each one the emission collected is beta sigma_a L_e / mu; the collision is real
(scattering) with probability P_s or null with P_n, in proportion to the largest channel of beta sigma_s and beta
sigma_n (sigma_n = mu - sigma_t), the throughput weighted by sigma_s / (mu P_s) or sigma_n / (mu P_n): unbiased for
every channel at once (spectral tracking), absorption folded into the weights. A path that reaches a surface needs
no weight. Shadow rays take the transmittance by ratio tracking: the product of (1 - sigma_t / mu) over tentative
collisions. Units: lengths in scene units, coefficients per scene unit.
"""

from __future__ import annotations

import math
import numpy as np
from numba import njit

from pbvol_cli.geometry.scene_build import (EXP_A, EXP_B, EXP_ORIGIN, EXP_UP, EXPONENTIAL, GRID, GRID_DIMS,
                                           GRID_EMIT_OFFSET, GRID_HI, GRID_LO, GRID_OFFSET, MED_EMIT, MED_FIELD,
                                           MED_KIND, MED_MAJORANT, MED_SIGMA_A, MED_SIGMA_S)
from pbvol_cli.physics.sampling import rand

@njit(inline="always", cache=True)
def _trilinear(data, offset, nx, ny, nz, u, v, w):
    """The voxels data[offset:] (nx, ny, nz, C order) at fractional voxel coordinates (u, v, w): voxel i's centre
    is at i + 0.5; clamped to the border voxels."""
    x, y, z = u - 0.5, v - 0.5, w - 0.5
    x0, y0, z0 = int(math.floor(x)), int(math.floor(y)), int(math.floor(z))
    fx, fy, fz = x - x0, y - y0, z - z0
    out = 0.0
    for a in range(2):
        i = min(max(x0 + a, 0), nx - 1)
        wa = fx if a else 1.0 - fx
        for b in range(2):
            j = min(max(y0 + b, 0), ny - 1)
            wb = fy if b else 1.0 - fy
            for c in range(2):
                k = min(max(z0 + c, 0), nz - 1)
                wc = fz if c else 1.0 - fz
                out += wa * wb * wc * data[offset + (i * ny + j) * nz + k]
    return out


@njit(cache=True)
def density_at(media, data, m, x, y, z):
    """(density, emission scale) of medium m at (x, y, z): 1 and 1 for a homogeneous one."""
    kind = int(media[m, MED_KIND])
    f = MED_FIELD
    if kind == GRID:
        lo0, lo1, lo2 = media[m, f + GRID_LO], media[m, f + GRID_LO + 1], media[m, f + GRID_LO + 2]
        hi0, hi1, hi2 = media[m, f + GRID_HI], media[m, f + GRID_HI + 1], media[m, f + GRID_HI + 2]
        if x < lo0 or x > hi0 or y < lo1 or y > hi1 or z < lo2 or z > hi2:
            return 0.0, 0.0
        nx, ny, nz = int(media[m, f + GRID_DIMS]), int(media[m, f + GRID_DIMS + 1]), int(media[m, f + GRID_DIMS + 2])
        u, v, w = (x - lo0) / (hi0 - lo0) * nx, (y - lo1) / (hi1 - lo1) * ny, (z - lo2) / (hi2 - lo2) * nz
        d = _trilinear(data, int(media[m, f + GRID_OFFSET]), nx, ny, nz, u, v, w)
        e_off = int(media[m, f + GRID_EMIT_OFFSET])
        e = _trilinear(data, e_off, nx, ny, nz, u, v, w) if e_off >= 0 else 1.0
        return d, e
    if kind == EXPONENTIAL:
        h = ((x - media[m, f + EXP_ORIGIN]) * media[m, f + EXP_UP] + (y - media[m, f + EXP_ORIGIN + 1])
             * media[m, f + EXP_UP + 1] + (z - media[m, f + EXP_ORIGIN + 2]) * media[m, f + EXP_UP + 2])
        return media[m, f + EXP_A] * math.exp(-media[m, f + EXP_B] * h), 1.0
    return 1.0, 1.0


@njit(cache=True)
def tracked_flight(media, m, rng, i):
    """A tentative free-flight distance at the majorant (INF where the medium is empty)."""
    mu = media[m, MED_MAJORANT]
    u = rand(rng, i)
    if mu <= 0.0:
        return np.inf
    return -math.log(1.0 - u) / mu


@njit(cache=True)
def tentative_collision(media, data, m, beta, i, x, y, z, rng):
    """A tentative collision of path i at (x, y, z) in medium m. Returns (real, emitted RGB): the emission collected
    there (beta sigma_a L_e / mu, with beta before this collision's weight) and whether the collision is real
    (scattering) or null; beta is weighted either way (all zero: the path is absorbed)."""
    mu = media[m, MED_MAJORANT]
    d, e = density_at(media, data, m, x, y, z)
    ps = pn = 0.0
    e0 = beta[i, 0] * d * media[m, MED_SIGMA_A] * media[m, MED_EMIT] * e / mu
    e1 = beta[i, 1] * d * media[m, MED_SIGMA_A + 1] * media[m, MED_EMIT + 1] * e / mu
    e2 = beta[i, 2] * d * media[m, MED_SIGMA_A + 2] * media[m, MED_EMIT + 2] * e / mu
    for c in range(3):
        sa, ss = d * media[m, MED_SIGMA_A + c], d * media[m, MED_SIGMA_S + c]
        ps = max(ps, abs(beta[i, c] * ss))
        pn = max(pn, abs(beta[i, c] * max(mu - sa - ss, 0.0)))
    total = ps + pn
    u = rand(rng, i)
    if total <= 0.0:
        beta[i, 0] = beta[i, 1] = beta[i, 2] = 0.0
        return False, e0, e1, e2
    ps /= total
    real = u < ps
    for c in range(3):
        sa, ss = d * media[m, MED_SIGMA_A + c], d * media[m, MED_SIGMA_S + c]
        if real:
            beta[i, c] *= ss / (mu * ps)
        else:
            beta[i, c] *= max(mu - sa - ss, 0.0) / (mu * (1.0 - ps))
    return real, e0, e1, e2


@njit(cache=True)
def segment_transmittance(media, data, m, ox, oy, oz, dx, dy, dz, t, rng, i, C):
    """Multiply C[i] (RGB) by the transmittance of medium m along o + s d, 0 <= s < t: exactly in a homogeneous
    medium, by ratio tracking (random stream rng[i]) in a heterogeneous one."""
    kind = int(media[m, MED_KIND])
    if kind != GRID and kind != EXPONENTIAL:
        for c in range(3):
            C[i, c] *= math.exp(-(media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c]) * t)
        return
    mu = media[m, MED_MAJORANT]
    if mu <= 0.0:
        return
    s = 0.0
    while True:
        s -= math.log(1.0 - rand(rng, i)) / mu
        if s >= t:
            return
        d, _ = density_at(media, data, m, ox + s * dx, oy + s * dy, oz + s * dz)
        alive = False
        for c in range(3):
            C[i, c] *= 1.0 - d * (media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c]) / mu
            alive = alive or C[i, c] != 0.0
        if not alive:
            return
