"""Sampling the lights' emission for light paths: a start point and a direction of travel with the flux they carry.

For each light type, a sample (x, w) with density p(x) p(w | x) carries the flux weight L_e(x, w) cos / (p(x) p(w))
(W, RGB): summed over N samples and divided by N it estimates any integral of the emitted light. Lights at infinity
(directional, environment) are started on a plane upstream of the scene, on a disc of the scene's bounding sphere
or (half of them) of the media's, so that walks meet the media without losing the rest. Radiance and intensity as
in physics/lights.py.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from pbvol_cli.physics.lights import (DIRECTIONAL, LIGHT_AREA, LIGHT_E1, LIGHT_E2, LIGHT_P0, LIGHT_RADIUS,
                                      LIGHT_RGB, LIGHT_TWO_SIDED, LIGHT_TYPE, POINT, QUAD, SPHERE)
from pbvol_cli.physics.sampling import coordinate_system, cosine_around, rand, uniform_sphere


def light_powers(lights: np.ndarray, radius: float) -> np.ndarray:
    """Each light's emitted flux (W, the mean of its RGB); lights at infinity: through a disc of the given radius
    (the media's)."""
    out = np.zeros(len(lights))
    for li, row in enumerate(lights):
        e = float(np.mean(row[LIGHT_RGB:LIGHT_RGB + 3]))
        kind = int(row[LIGHT_TYPE])
        if kind == POINT:
            out[li] = 4 * math.pi * e
        elif kind in (SPHERE, QUAD):
            out[li] = math.pi * e * row[LIGHT_AREA] * (2.0 if row[LIGHT_TWO_SIDED] > 0 else 1.0)
        elif kind == DIRECTIONAL:
            out[li] = e * math.pi * radius ** 2
        else:
            out[li] = e * 4 * math.pi * math.pi * radius ** 2
    return out


def light_choice(lights: np.ndarray, centre, radius: float) -> np.ndarray:
    """The probability with which a walk starts on each light: half in proportion to its flux, half to the flux it
    sends toward the media's bounding sphere (centre, radius; a finite light's flux times the fraction of
    directions from its centre that meet the sphere). Any positive choice is unbiased; the defensive mixture keeps
    a lamp whose light reaches the media through a floor from being starved by a sky, and a sky that bathes a
    small medium from being starved by a lamp that shines mostly elsewhere."""
    power = light_powers(lights, radius)
    toward = power.copy()
    for li, row in enumerate(lights):
        kind = int(row[LIGHT_TYPE])
        if kind in (POINT, SPHERE, QUAD):
            c = row[LIGHT_P0:LIGHT_P0 + 3] + (0.5 * (row[LIGHT_E1:LIGHT_E1 + 3] + row[LIGHT_E2:LIGHT_E2 + 3])
                                             if kind == QUAD else 0.0)
            d2 = float(np.sum((np.asarray(centre) - c) ** 2))
            toward[li] *= 1.0 if d2 <= radius * radius else 0.5 * (1.0 - math.sqrt(1.0 - radius * radius / d2))
    p = np.zeros(len(lights))
    for w in (power, toward):
        if w.sum() > 0:
            p += 0.5 * w / w.sum()
    return p / p.sum() if p.sum() > 0 else np.full(len(lights), 1.0 / max(len(lights), 1))


@njit(cache=True)
def _disc_start(cx, cy, cz, radius, mx, my, mz, m_radius, m_share, dx, dy, dz, u0, u1, u2):
    """A start for a ray of direction d from a light at infinity, on the plane P tangent to the scene's bounding
    sphere (centre c, radius) upstream of it: with probability m_share uniform on the disc of the media's bounding
    sphere (centre m, m_radius) projected onto P, otherwise uniform on the scene's disc. Returns (x, y, z, area):
    area = 1 / (the start's density per unit area of P), the mixture's (every ray that meets the scene has a
    positive density: unbiased; most walks meet the media)."""
    s, b = coordinate_system(dx, dy, dz)
    px, py, pz = cx - radius * dx, cy - radius * dy, cz - radius * dz  # P's point nearest c
    h = (mx - px) * dx + (my - py) * dy + (mz - pz) * dz
    qx, qy, qz = mx - h * dx, my - h * dy, mz - h * dz  # the media's centre projected onto P
    if u0 < m_share:
        ox, oy, oz, rad = qx, qy, qz, m_radius
    else:
        ox, oy, oz, rad = px, py, pz, radius
    r = rad * math.sqrt(u1)
    a = 2.0 * math.pi * u2
    ca, sa = r * math.cos(a), r * math.sin(a)
    x = ox + ca * s[0] + sa * b[0]
    y = oy + ca * s[1] + sa * b[1]
    z = oz + ca * s[2] + sa * b[2]
    density = 0.0
    if m_share > 0.0 and (x - qx) ** 2 + (y - qy) ** 2 + (z - qz) ** 2 <= m_radius * m_radius:
        density += m_share / (math.pi * m_radius * m_radius)
    if (x - px) ** 2 + (y - py) ** 2 + (z - pz) ** 2 <= radius * radius:
        density += (1.0 - m_share) / (math.pi * radius * radius)
    return x, y, z, 1.0 / density


@njit(cache=True)
def emit_one(lights, li, bounds, rng, i):
    """A light-path start on light li: (x, y, z, dx, dy, dz, Wr, Wg, Wb), the flux weight W as in the module's
    docstring (not yet divided by the light's choice probability). bounds: the scene's bounding sphere (centre,
    radius), the media's (centre, radius) and the share of the walks from lights at infinity aimed at the media
    (_disc_start)."""
    cx, cy, cz, radius, mx, my, mz, m_radius, m_share = (bounds[0], bounds[1], bounds[2], bounds[3], bounds[4],
                                                         bounds[5], bounds[6], bounds[7], bounds[8])
    kind = int(lights[li, LIGHT_TYPE])
    Lr, Lg, Lb = lights[li, LIGHT_RGB], lights[li, LIGHT_RGB + 1], lights[li, LIGHT_RGB + 2]
    u1, u2, u3, u4 = rand(rng, i), rand(rng, i), rand(rng, i), rand(rng, i)
    if kind == POINT:
        w = uniform_sphere(u1, u2)
        s = 4.0 * math.pi
        return lights[li, LIGHT_P0], lights[li, LIGHT_P0 + 1], lights[li, LIGHT_P0 + 2], w[0], w[1], w[2], \
            Lr * s, Lg * s, Lb * s
    if kind == SPHERE:
        n = uniform_sphere(u1, u2)
        rad = lights[li, LIGHT_RADIUS]
        w = cosine_around(u3, u4, n[0], n[1], n[2])
        s = math.pi * lights[li, LIGHT_AREA]
        eps = 1e-7 * rad
        return (lights[li, LIGHT_P0] + (rad + eps) * n[0], lights[li, LIGHT_P0 + 1] + (rad + eps) * n[1],
                lights[li, LIGHT_P0 + 2] + (rad + eps) * n[2], w[0], w[1], w[2], Lr * s, Lg * s, Lb * s)
    if kind == QUAD:
        e1x, e1y, e1z = lights[li, LIGHT_E1], lights[li, LIGHT_E1 + 1], lights[li, LIGHT_E1 + 2]
        e2x, e2y, e2z = lights[li, LIGHT_E2], lights[li, LIGHT_E2 + 1], lights[li, LIGHT_E2 + 2]
        nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
        nx, ny, nz = nx * inv, ny * inv, nz * inv
        s = math.pi * lights[li, LIGHT_AREA]
        if lights[li, LIGHT_TWO_SIDED] > 0.0:
            s *= 2.0
            if u3 < 0.5:
                nx, ny, nz = -nx, -ny, -nz
                u3 = 2.0 * u3
            else:
                u3 = 2.0 * u3 - 1.0
        w = cosine_around(u3, u4, nx, ny, nz)
        x = lights[li, LIGHT_P0] + u1 * e1x + u2 * e2x
        y = lights[li, LIGHT_P0 + 1] + u1 * e1y + u2 * e2y
        z = lights[li, LIGHT_P0 + 2] + u1 * e1z + u2 * e2z
        return x, y, z, w[0], w[1], w[2], Lr * s, Lg * s, Lb * s
    if kind == DIRECTIONAL:
        dx, dy, dz = lights[li, LIGHT_E1], lights[li, LIGHT_E1 + 1], lights[li, LIGHT_E1 + 2]
        x, y, z, area = _disc_start(cx, cy, cz, radius, mx, my, mz, m_radius, m_share, dx, dy, dz, u3, u1, u2)
        return x, y, z, dx, dy, dz, Lr * area, Lg * area, Lb * area
    # ENVIRONMENT: radiance from every direction: a uniform direction of travel, through a disc facing it
    w = uniform_sphere(u1, u2)
    x, y, z, area = _disc_start(cx, cy, cz, radius, mx, my, mz, m_radius, m_share, w[0], w[1], w[2], rand(rng, i),
                                u3, u4)
    s = 4.0 * math.pi * area
    return x, y, z, w[0], w[1], w[2], Lr * s, Lg * s, Lb * s


@njit(parallel=True, cache=True)
def emit(lights, cdf, bounds, rng, pos, dirs, flux):
    """Light-path starts for every i: a light chosen by the cumulative probabilities cdf, then emit_one; flux
    divided by the choice's probability."""
    for i in prange(pos.shape[0]):
        u = rand(rng, i)
        li = 0
        while li < cdf.shape[0] - 1 and u >= cdf[li]:
            li += 1
        p = cdf[li] - (cdf[li - 1] if li > 0 else 0.0)
        x, y, z, dx, dy, dz, wr, wg, wb = emit_one(lights, li, bounds, rng, i)
        pos[i, 0], pos[i, 1], pos[i, 2] = x, y, z
        dirs[i, 0], dirs[i, 1], dirs[i, 2] = dx, dy, dz
        flux[i, 0], flux[i, 1], flux[i, 2] = wr / p, wg / p, wb / p
