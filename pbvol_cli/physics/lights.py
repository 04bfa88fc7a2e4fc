"""Light sources as rows of a flat float64 table, and their sampling / pdf / intersection kernels.

Row layout (LIGHT_COLS columns, named below): LIGHT_TYPE, LIGHT_RGB (3), LIGHT_P0 (3), LIGHT_E1 (3), LIGHT_E2 (3),
LIGHT_RADIUS, LIGHT_TWO_SIDED, LIGHT_AREA.
  point:       P0 = position, RGB = intensity (W/sr)
  directional: E1 = unit direction of travel, RGB = irradiance (W/m^2) on a surface facing it
  sphere:      P0 = centre, RADIUS, RGB = radiance (emitted outward), AREA
  quad:        P0 = corner, E1, E2 edges, RGB = radiance on the side of E1 x E2 (both if TWO_SIDED), AREA
  environment: RGB = constant radiance arriving from every direction
Directions passed around are unit propagation directions; pdfs are per unit solid angle.
"""

import math

import numpy as np
from numba import njit

from pbvol_cli.physics.sampling import around, uniform_sphere

POINT, DIRECTIONAL, SPHERE, QUAD, ENVIRONMENT = 0, 1, 2, 3, 4  # LIGHT_TYPE values
LIGHT_TYPE, LIGHT_RGB, LIGHT_P0, LIGHT_E1, LIGHT_E2 = 0, 1, 4, 7, 10  # RGB and the vectors take 3 columns
LIGHT_RADIUS, LIGHT_TWO_SIDED, LIGHT_AREA = 13, 14, 15
LIGHT_COLS = 16
INF = np.inf


def light_rows(lights) -> np.ndarray:
    """Build the table from config light models (pbvol_cli.config)."""
    rows = np.zeros((len(lights), LIGHT_COLS))
    for i, L in enumerate(lights):
        r = rows[i]
        rgb, p0, e1, e2 = (slice(c, c + 3) for c in (LIGHT_RGB, LIGHT_P0, LIGHT_E1, LIGHT_E2))
        if L.type == "point":
            r[LIGHT_TYPE], r[rgb], r[p0] = POINT, L.intensity, L.position
        elif L.type == "directional":
            d = np.asarray(L.direction, float)
            r[LIGHT_TYPE], r[rgb], r[e1] = DIRECTIONAL, L.irradiance, d / np.linalg.norm(d)
        elif L.type == "sphere":
            r[LIGHT_TYPE], r[rgb], r[p0], r[LIGHT_RADIUS] = SPHERE, L.emitted_radiance(), L.center, L.radius
            r[LIGHT_AREA] = 4 * math.pi * L.radius**2
        elif L.type == "quad":
            r[LIGHT_TYPE], r[rgb], r[p0], r[e1], r[e2] = QUAD, L.emitted_radiance(), L.corner, L.edge1, L.edge2
            r[LIGHT_TWO_SIDED], r[LIGHT_AREA] = float(L.two_sided), L.area()
        else:
            r[LIGHT_TYPE], r[rgb] = ENVIRONMENT, L.radiance
    return rows


@njit(inline="always", cache=True)
def sphere_hit(ox, oy, oz, dx, dy, dz, cx, cy, cz, rad, tmin):
    """Nearest t > tmin where the ray meets the sphere, or inf. Returns (t, entering)."""
    lx, ly, lz = ox - cx, oy - cy, oz - cz
    b = lx * dx + ly * dy + lz * dz
    c = lx * lx + ly * ly + lz * lz - rad * rad
    disc = b * b - c
    if disc < 0.0:
        return INF, False
    s = math.sqrt(disc)
    # Numerically stable roots.
    q = -b - s if b > 0.0 else -b + s
    t0 = q if q != 0.0 else -b - s
    t1 = c / q if q != 0.0 else -b + s
    if t0 > t1:
        t0, t1 = t1, t0
    if t0 > tmin:
        return t0, True
    if t1 > tmin:
        return t1, False
    return INF, False


@njit(inline="always", cache=True)
def intersect_lights(lights, ox, oy, oz, dx, dy, dz, tmax, skip=-1):
    """Closest area light hit before tmax, ignoring light `skip`: (t, light index) or (inf, -1)."""
    best, idx = tmax, -1
    for li in range(lights.shape[0]):
        if li == skip:
            continue
        kind = lights[li, LIGHT_TYPE]
        if kind == SPHERE:
            t, _ = sphere_hit(ox, oy, oz, dx, dy, dz, lights[li, LIGHT_P0], lights[li, LIGHT_P0 + 1],
                              lights[li, LIGHT_P0 + 2], lights[li, LIGHT_RADIUS], 0.0)
            if t < best:
                best, idx = t, li
        elif kind == QUAD:
            t = _quad_hit(lights, li, ox, oy, oz, dx, dy, dz)
            if t < best:
                best, idx = t, li
    if idx < 0:
        return INF, -1
    return best, idx


@njit(inline="always", cache=True)
def quad_normal(lights, li):
    e1x, e1y, e1z = lights[li, LIGHT_E1], lights[li, LIGHT_E1 + 1], lights[li, LIGHT_E1 + 2]
    e2x, e2y, e2z = lights[li, LIGHT_E2], lights[li, LIGHT_E2 + 1], lights[li, LIGHT_E2 + 2]
    nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    return nx * inv, ny * inv, nz * inv


@njit(cache=True)
def _quad_hit(lights, li, ox, oy, oz, dx, dy, dz):
    nx, ny, nz = quad_normal(lights, li)
    den = dx * nx + dy * ny + dz * nz
    if abs(den) < 1e-12:
        return INF
    px, py, pz = lights[li, LIGHT_P0], lights[li, LIGHT_P0 + 1], lights[li, LIGHT_P0 + 2]
    t = ((px - ox) * nx + (py - oy) * ny + (pz - oz) * nz) / den
    if t <= 0.0:
        return INF
    hx, hy, hz = ox + t * dx - px, oy + t * dy - py, oz + t * dz - pz
    e1x, e1y, e1z = lights[li, LIGHT_E1], lights[li, LIGHT_E1 + 1], lights[li, LIGHT_E1 + 2]
    e2x, e2y, e2z = lights[li, LIGHT_E2], lights[li, LIGHT_E2 + 1], lights[li, LIGHT_E2 + 2]
    # Solve h = a e1 + b e2 in the plane via the Gram matrix.
    g11 = e1x * e1x + e1y * e1y + e1z * e1z
    g22 = e2x * e2x + e2y * e2y + e2z * e2z
    g12 = e1x * e2x + e1y * e2y + e1z * e2z
    h1 = hx * e1x + hy * e1y + hz * e1z
    h2 = hx * e2x + hy * e2y + hz * e2z
    det = g11 * g22 - g12 * g12
    a = (h1 * g22 - h2 * g12) / det
    b = (h2 * g11 - h1 * g12) / det
    if a < 0.0 or a > 1.0 or b < 0.0 or b > 1.0:
        return INF
    return t


@njit(cache=True)
def emitted_toward(lights, li, dx, dy, dz, ox, oy, oz, t):
    """Scale (0 or 1) of the light's radiance seen along a ray of direction d hitting it at distance t."""
    kind = lights[li, LIGHT_TYPE]
    if kind == SPHERE:
        hx = ox + t * dx - lights[li, LIGHT_P0]
        hy = oy + t * dy - lights[li, LIGHT_P0 + 1]
        hz = oz + t * dz - lights[li, LIGHT_P0 + 2]
        return 1.0 if hx * dx + hy * dy + hz * dz < 0.0 else 0.0
    if kind == QUAD:
        nx, ny, nz = quad_normal(lights, li)
        c = nx * dx + ny * dy + nz * dz
        return 1.0 if (c < 0.0 or lights[li, LIGHT_TWO_SIDED] > 0.0) else 0.0
    return 0.0


@njit(cache=True)
def light_pdf(lights, li, px, py, pz, dx, dy, dz, t):
    """Solid-angle pdf that light_sample from p returns direction d (hitting the light at distance t)."""
    kind = lights[li, LIGHT_TYPE]
    if kind == ENVIRONMENT:
        return 1.0 / (4.0 * math.pi)
    if kind == SPHERE:
        cx, cy, cz = lights[li, LIGHT_P0] - px, lights[li, LIGHT_P0 + 1] - py, lights[li, LIGHT_P0 + 2] - pz
        rad = lights[li, LIGHT_RADIUS]
        d2 = cx * cx + cy * cy + cz * cz
        if d2 <= rad * rad:
            return 0.0
        s2 = rad * rad / d2
        one_minus_cos = s2 / (1.0 + math.sqrt(1.0 - s2))
        return 1.0 / (2.0 * math.pi * one_minus_cos)
    if kind == QUAD:
        nx, ny, nz = quad_normal(lights, li)
        c = abs(nx * dx + ny * dy + nz * dz)
        if c <= 0.0:
            return 0.0
        return t * t / (lights[li, LIGHT_AREA] * c)
    return 0.0


@njit(cache=True)
def light_sample(lights, li, px, py, pz, u1, u2):
    """Sample light li from point p.

    Returns (dx, dy, dz, dist, Lr, Lg, Lb, pdf, delta): the unit direction toward the light, the distance
    to the sampled point (inf for directional / environment), the radiance arriving (for delta lights the
    irradiance-like factor intensity / dist^2 with pdf 1), and its solid-angle pdf (0 = no sample).
    """
    kind = lights[li, LIGHT_TYPE]
    Lr, Lg, Lb = lights[li, LIGHT_RGB], lights[li, LIGHT_RGB + 1], lights[li, LIGHT_RGB + 2]
    if kind == POINT:
        dx, dy, dz = lights[li, LIGHT_P0] - px, lights[li, LIGHT_P0 + 1] - py, lights[li, LIGHT_P0 + 2] - pz
        d2 = dx * dx + dy * dy + dz * dz
        d = math.sqrt(d2)
        return dx / d, dy / d, dz / d, d, Lr / d2, Lg / d2, Lb / d2, 1.0, True
    if kind == DIRECTIONAL:
        return -lights[li, LIGHT_E1], -lights[li, LIGHT_E1 + 1], -lights[li, LIGHT_E1 + 2], INF, Lr, Lg, Lb, 1.0, True
    if kind == ENVIRONMENT:
        w = uniform_sphere(u1, u2)
        return w[0], w[1], w[2], INF, Lr, Lg, Lb, 1.0 / (4.0 * math.pi), False
    if kind == SPHERE:
        cx, cy, cz = lights[li, LIGHT_P0] - px, lights[li, LIGHT_P0 + 1] - py, lights[li, LIGHT_P0 + 2] - pz
        rad = lights[li, LIGHT_RADIUS]
        d2 = cx * cx + cy * cy + cz * cz
        if d2 <= rad * rad:
            return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, False
        d = math.sqrt(d2)
        s2 = rad * rad / d2
        one_minus_cos_max = s2 / (1.0 + math.sqrt(1.0 - s2))
        cos_t = 1.0 - u1 * one_minus_cos_max
        w = around(cos_t, 2.0 * math.pi * u2, cx / d, cy / d, cz / d)
        t, _ = sphere_hit(px, py, pz, w[0], w[1], w[2], lights[li, LIGHT_P0], lights[li, LIGHT_P0 + 1],
                          lights[li, LIGHT_P0 + 2], rad, 0.0)
        if t == INF:  # grazing the silhouette in floating point: place it on the tangent point
            t = d * cos_t
        return w[0], w[1], w[2], t, Lr, Lg, Lb, 1.0 / (2.0 * math.pi * one_minus_cos_max), False
    # QUAD
    qx = lights[li, LIGHT_P0] + u1 * lights[li, LIGHT_E1] + u2 * lights[li, LIGHT_E2] - px
    qy = lights[li, LIGHT_P0 + 1] + u1 * lights[li, LIGHT_E1 + 1] + u2 * lights[li, LIGHT_E2 + 1] - py
    qz = lights[li, LIGHT_P0 + 2] + u1 * lights[li, LIGHT_E1 + 2] + u2 * lights[li, LIGHT_E2 + 2] - pz
    d2 = qx * qx + qy * qy + qz * qz
    d = math.sqrt(d2)
    dx, dy, dz = qx / d, qy / d, qz / d
    nx, ny, nz = quad_normal(lights, li)
    c = nx * dx + ny * dy + nz * dz
    if c >= 0.0 and lights[li, LIGHT_TWO_SIDED] == 0.0:
        return dx, dy, dz, d, 0.0, 0.0, 0.0, 0.0, False
    c = abs(c)
    if c < 1e-12:
        return dx, dy, dz, d, 0.0, 0.0, 0.0, 0.0, False
    return dx, dy, dz, d, Lr, Lg, Lb, d2 / (lights[li, LIGHT_AREA] * c), False
