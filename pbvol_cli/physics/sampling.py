"""Random numbers and warps shared by every kernel.

The generator is SplitMix64 with one 64-bit state per path: a path's stream depends only on
(seed, pixel, sample index), never on thread scheduling, so images are reproducible bit for bit.
"""

import math

import numpy as np
from numba import njit, prange

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_INV_2_53 = 1.0 / 9007199254740992.0


@njit(inline="always", cache=True)
def mix64(z):
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@njit(cache=True)
def seed_state(seed, stream, index):
    """Initial state for the path `index` of stream `stream` (e.g. pixel, sample) under `seed`."""
    z = mix64(np.uint64(seed) * _GOLDEN + np.uint64(0x632BE59BD9B4E019))
    z = mix64(z ^ (np.uint64(stream) * _M1))
    return mix64(z ^ (np.uint64(index) * _M2 + _GOLDEN))


@njit(inline="always", cache=True)
def rand(state, i):
    """Uniform double in [0, 1) from state[i], advancing it."""
    s = state[i] + _GOLDEN
    state[i] = s
    return (mix64(s) >> np.uint64(11)) * _INV_2_53


@njit(inline="always", cache=True)
def coordinate_system(nx, ny, nz):
    """Two unit vectors completing (nx, ny, nz) to an orthonormal frame (Duff et al. 2017)."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return (1.0 + sign * nx * nx * a, sign * b, -sign * nx), (b, sign + ny * ny * a, -ny)


@njit(inline="always", cache=True)
def to_world(lx, ly, lz, nx, ny, nz):
    """Direction (lx, ly, lz) given in the frame whose z axis is n, in world coordinates."""
    s, t = coordinate_system(nx, ny, nz)
    return (
        lx * s[0] + ly * t[0] + lz * nx,
        lx * s[1] + ly * t[1] + lz * ny,
        lx * s[2] + ly * t[2] + lz * nz,
    )


@njit(inline="always", cache=True)
def around(cos_t, phi, nx, ny, nz):
    """Unit direction at angle acos(cos_t) from n, azimuth phi."""
    sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
    return to_world(sin_t * math.cos(phi), sin_t * math.sin(phi), cos_t, nx, ny, nz)


@njit(inline="always", cache=True)
def uniform_sphere(u1, u2):
    z = 1.0 - 2.0 * u1
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = 2.0 * math.pi * u2
    return r * math.cos(phi), r * math.sin(phi), z


@njit(inline="always", cache=True)
def cosine_hemisphere(u1, u2, nx, ny, nz):
    """Cosine-weighted direction around n; pdf = cos / pi."""
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    return to_world(r * math.cos(phi), r * math.sin(phi), math.sqrt(max(0.0, 1.0 - u1)), nx, ny, nz)


@njit(inline="always", cache=True)
def cosine_around(u1, u2, nx, ny, nz):
    """Cosine-weighted direction around n, in the frame (a x n, n x (a x n), n) with a = y when |n_x| > 0.9, else
    x: the same distribution as cosine_hemisphere, another mapping of (u1, u2) (the point-based samples' own)."""
    r, phi = math.sqrt(u1), 2.0 * math.pi * u2
    ax, ay, az = (0.0, 1.0, 0.0) if abs(nx) > 0.9 else (1.0, 0.0, 0.0)
    t1x, t1y, t1z = ay * nz - az * ny, az * nx - ax * nz, ax * ny - ay * nx
    ln = math.sqrt(t1x * t1x + t1y * t1y + t1z * t1z)
    t1x, t1y, t1z = t1x / ln, t1y / ln, t1z / ln
    t2x, t2y, t2z = ny * t1z - nz * t1y, nz * t1x - nx * t1z, nx * t1y - ny * t1x
    a, b, c = r * math.cos(phi), r * math.sin(phi), math.sqrt(max(0.0, 1.0 - u1))
    return a * t1x + b * t2x + c * nx, a * t1y + b * t2y + c * ny, a * t1z + b * t2z + c * nz


@njit(parallel=True, cache=True)
def cosine_directions(normals, u1, u2, out):
    """cosine_around for each row of normals (n, 3) with the uniform numbers u1[k], u2[k], into out (n, 3)."""
    for k in prange(normals.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = cosine_around(u1[k], u2[k], normals[k, 0], normals[k, 1], normals[k, 2])


@njit(inline="always", cache=True)
def depth_of_fraction(u, s):
    """The depth d at which a share u of a beam is extinguished, 1 - e^(-s d) = u (s > 0): with u uniform on
    [0, 1 - e^(-s d_max)) (stratified, or in equal steps), d has the truncated exponential's density
    s e^(-s d) / (1 - e^(-s d_max)) on [0, d_max]."""
    return -math.log1p(-u) / s


@njit(inline="always", cache=True)
def stratified_depth(k, n, xi, s, dmax, frac):
    """Point k of n stratified along a segment of length dmax in a medium whose smallest extinction is s (s = 0:
    uniform): u = (k + xi) / n of the extinguished share frac = 1 - e^(-s dmax). Returns (depth, its pdf); a
    segment of no length (a ray meeting a surface where it starts: Embree can return t = 0) gives depth 0 with an
    infinite pdf, so that its points weigh nothing, where a division by zero stopped the render."""
    if not (dmax > 0.0 and frac > 0.0):
        return 0.0, np.inf
    u = (k + xi) / n * frac
    if s > 0.0:
        d = depth_of_fraction(u, s)
        return d, s * math.exp(-s * d) / frac
    return u * dmax, 1.0 / dmax


MFP_PER_POINT = 1.0  # a segment's smooth terms take a point per this many mean free paths of its length (its least
# dense channel's), up to kmax_scattered: one point in an optically thin segment, where the terms change little
# along it and the surfaces' noise dominates; more in a dense one, where they fall steeply from the lit boundary
# and the depth of a lone point was most of the medium's noise (docs/pbl.md, "Points along a dense segment")


@njit(inline="always", cache=True)
def points_on_segment(kmax, s, dmax):
    """Points for the smooth terms on a segment of length dmax in a medium whose smallest extinction is s: one per
    MFP_PER_POINT mean free paths (s dmax of them), at least 1, at most kmax (also for an unbounded segment)."""
    tau = s * dmax
    if not tau < kmax * MFP_PER_POINT:  # (also inf and NaN)
        return kmax
    return max(1, int(math.ceil(tau / MFP_PER_POINT)))


@njit(inline="always", cache=True)
def power_heuristic(pa, pb):
    a2 = pa * pa
    return a2 / (a2 + pb * pb) if a2 > 0.0 else 0.0
