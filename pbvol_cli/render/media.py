"""Heterogeneous and emissive media: density fields, and the null-collision tracking that renders them unbiased
(seed 003, "Heterogeneous media", "Emission"; Kutz et al. 2017, "Spectral and decomposition tracking").

A medium's coefficients are its material's sigma_a and sigma_s (RGB) times a density d(x) >= 0: a grid of voxels
(trilinear between voxel centres, 0 outside its box) or a * exp(-b h) with h the height along a direction. It may
emit: the source term sigma_a(x) L_e(x) per unit length, L_e the material's emission (times a second grid where the
material names one).

Tracking. Tentative collisions are sampled at a majorant mu >= sigma_t of every channel: piecewise constant over
a coarse grid of cells (MED_MAJ: each cell's bound, so that the empty parts of a sparse grid cost nothing), or
one value over the whole medium (MED_MAJORANT, a homogeneous emissive medium). At each one the emission
collected is beta sigma_a L_e / mu; the collision is real (scattering) with probability P_s or null with P_n, in
proportion to the largest channel of beta sigma_s and beta sigma_n (sigma_n = mu - sigma_t), the throughput
weighted by sigma_s / (mu P_s) or sigma_n / (mu P_n): unbiased for every channel at once (spectral tracking),
absorption folded into the weights. A path that reaches a surface needs
no weight. Shadow rays take the transmittance by ratio tracking: the product of (1 - sigma_t / mu) over tentative
collisions. Units: lengths in scene units, coefficients per scene unit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pbvol_cli.geometry.scene_build import (EXP_A, EXP_B, EXP_ORIGIN, EXP_UP, EXPONENTIAL, GRID, GRID_DIMS, HOMOGENEOUS,
                                           GRID_EMIT_OFFSET, GRID_HI, GRID_LO, GRID_OFFSET, MAJ_DIMS, MAJ_HI, MAJ_LO,
                                           MAJ_OFFSET, MED_EMIT, MED_FIELD, MED_KIND, MED_MAJ, MED_MAJORANT,
                                           MED_SIGMA_A, MED_SIGMA_S)
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
def majorant_flight(media, data, m, ox, oy, oz, dx, dy, dz, tau):
    """(t, mu): the distance along o + t d (d unit) at which the majorant's optical depth reaches tau, walking the
    medium's majorant cells (a 3D DDA), and the majorant there; (inf, 0) where the ray leaves the cells first."""
    g = MED_MAJ
    nx, ny, nz = int(media[m, g + MAJ_DIMS]), int(media[m, g + MAJ_DIMS + 1]), int(media[m, g + MAJ_DIMS + 2])
    if nx == 0:
        mu = media[m, MED_MAJORANT]
        return (tau / mu, mu) if mu > 0.0 else (np.inf, 0.0)
    lx, ly, lz = media[m, g + MAJ_LO], media[m, g + MAJ_LO + 1], media[m, g + MAJ_LO + 2]
    t0, t1 = _slab(ox, dx, lx, media[m, g + MAJ_HI], 0.0, np.inf)
    t0, t1 = _slab(oy, dy, ly, media[m, g + MAJ_HI + 1], t0, t1)
    t0, t1 = _slab(oz, dz, lz, media[m, g + MAJ_HI + 2], t0, t1)
    if t0 >= t1:
        return np.inf, 0.0
    wx = (media[m, g + MAJ_HI] - lx) / nx
    wy = (media[m, g + MAJ_HI + 1] - ly) / ny
    wz = (media[m, g + MAJ_HI + 2] - lz) / nz
    cx, sx, tnx, tdx = _dda_axis(ox, dx, lx, wx, nx, t0)
    cy, sy, tny, tdy = _dda_axis(oy, dy, ly, wy, ny, t0)
    cz, sz, tnz, tdz = _dda_axis(oz, dz, lz, wz, nz, t0)
    off = int(media[m, g + MAJ_OFFSET])
    t = t0
    while True:
        t_exit = min(min(tnx, tny), min(tnz, t1))
        mu = data[off + (cx * ny + cy) * nz + cz]
        if mu > 0.0 and mu * (t_exit - t) >= tau:
            return t + tau / mu, mu
        tau -= mu * max(t_exit - t, 0.0)
        t = t_exit
        if t >= t1:
            return np.inf, 0.0
        if tnx <= tny and tnx <= tnz:
            cx += sx
            tnx += tdx
            if cx < 0 or cx >= nx:
                return np.inf, 0.0
        elif tny <= tnz:
            cy += sy
            tny += tdy
            if cy < 0 or cy >= ny:
                return np.inf, 0.0
        else:
            cz += sz
            tnz += tdz
            if cz < 0 or cz >= nz:
                return np.inf, 0.0


@njit(inline="always", cache=True)
def _slab(o, d, lo, hi, t0, t1):
    """The ray's parameter interval [t0, t1] narrowed to the slab lo <= o + t d <= hi (empty: t0 >= t1)."""
    if d != 0.0:
        a, b = (lo - o) / d, (hi - o) / d
        return max(t0, min(a, b)), min(t1, max(a, b))
    if o < lo or o > hi:
        return 1.0, 0.0
    return t0, t1


@njit(inline="always", cache=True)
def _dda_axis(o, d, lo, w, n, t0):
    """A 3D DDA's state on one axis from parameter t0: (cell, step, parameter of the next cell boundary, parameter
    per cell)."""
    c = min(max(int((o + t0 * d - lo) / w), 0), n - 1)
    if d > 0.0:
        return c, 1, (lo + (c + 1) * w - o) / d, w / d
    if d < 0.0:
        return c, -1, (lo + c * w - o) / d, -w / d
    return c, 0, np.inf, np.inf


@njit(cache=True)
def tracked_flight(media, data, m, pos, dirs, rng, i):
    """(t, mu): path i's next tentative collision from pos[i] along dirs[i] and the majorant there."""
    tau = -math.log(1.0 - rand(rng, i))
    return majorant_flight(media, data, m, pos[i, 0], pos[i, 1], pos[i, 2], dirs[i, 0], dirs[i, 1], dirs[i, 2], tau)


@njit(cache=True)
def tentative_collision(media, data, m, beta, i, x, y, z, rng, mu):
    """A tentative collision of path i at (x, y, z) in medium m, sampled at majorant mu. Returns (real, emitted
    RGB): the emission collected there (beta sigma_a L_e / mu, with beta before this collision's weight) and
    whether the collision is real (scattering) or null; beta is weighted either way (all zero: absorbed)."""
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
    s = 0.0
    while True:
        ds, mu = majorant_flight(media, data, m, ox + s * dx, oy + s * dy, oz + s * dz, dx, dy, dz,
                                 -math.log(1.0 - rand(rng, i)))
        s += ds
        if s >= t:
            return
        d, _ = density_at(media, data, m, ox + s * dx, oy + s * dy, oz + s * dz)
        alive = False
        for c in range(3):
            C[i, c] *= 1.0 - d * (media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c]) / mu
            alive = alive or C[i, c] != 0.0
        if not alive:
            return


@njit(inline="always", cache=True)
def free_flight(media, m, beta, i, rng, density, pos, dirs, tmaj):
    """Free-flight distance in medium m from pos[i] along dirs[i], channel chosen in proportion to the
    throughput; in a tracked medium a tentative one, its majorant in tmaj[i]."""
    if media[m, MED_KIND] != HOMOGENEOUS:
        t, tmaj[i] = tracked_flight(media, density, m, pos, dirs, rng, i)
        return t
    b0, b1, b2 = beta[i, 0], beta[i, 1], beta[i, 2]
    s = b0 + b1 + b2
    if s <= 0.0:
        return np.inf
    u = rand(rng, i) * s
    c = 0 if u < b0 else (1 if u < b0 + b1 else 2)
    st = media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c]
    if st <= 0.0:
        return np.inf
    return -math.log(1.0 - rand(rng, i)) / st


@njit(inline="always", cache=True)
def flight_weight(media, m, beta, i, t, scatter):
    """Apply the spectral-MIS weight of a flight of length t ending in a scattering event or not."""
    b0, b1, b2 = beta[i, 0], beta[i, 1], beta[i, 2]
    s = b0 + b1 + b2
    pdf = 0.0
    tr0 = tr1 = tr2 = 0.0
    for c in range(3):
        st = media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c]
        tr = math.exp(-st * t)
        pc = (b0 if c == 0 else (b1 if c == 1 else b2)) / s
        pdf += pc * (st * tr if scatter else tr)
        if c == 0:
            tr0 = tr
        elif c == 1:
            tr1 = tr
        else:
            tr2 = tr
    if pdf <= 0.0:
        beta[i, 0] = beta[i, 1] = beta[i, 2] = 0.0
        return
    if scatter:
        beta[i, 0] *= media[m, MED_SIGMA_S] * tr0 / pdf
        beta[i, 1] *= media[m, MED_SIGMA_S + 1] * tr1 / pdf
        beta[i, 2] *= media[m, MED_SIGMA_S + 2] * tr2 / pdf
    else:
        beta[i, 0] *= tr0 / pdf
        beta[i, 1] *= tr1 / pdf
        beta[i, 2] *= tr2 / pdf
