"""Blue-noise (Poisson-disk) samples on surfaces, each with an area (Wang et al. 2016, sec. 3.4; Jensen & Buhler).

Dart throwing: many uniform, area-weighted candidates in random order; a candidate is kept when no kept sample lies
within the radius (a uniform grid of cells of that size, a few slots per cell, makes the test O(1)). Every kept
sample represents total_area / count.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.scene_build import SPH_CENTER, SPH_RADIUS, SPH_SURFACE
from pbvol_cli.physics.sampling import rand, seed_state, uniform_sphere

SLOTS = 8  # a cube of side r holds at most 8 points at mutual distance >= r
SHARING_RADIUS = 2.5  # share_among_neighbours's radius, in the samples' minimum distances


LIGHT_SAMPLE_STREAM = 0xB1  # the light samples' surface points (light_samples.py)
BOUNDARY_STREAM = 0xB200  # the bounced light's boundary points (bounced.py), + its generation: with the light
# samples' stream they were the same points wherever the medium's boundary is the outer layer (docs/pbl.md)


@njit(cache=True)
def _candidates(V, F, tri_normals, cum_area, spheres, sphere_cum, n, seed, stream, pos, nrm, surf_idx, tri_surface,
                gnrm):
    """n candidates, area-weighted over triangles (cum_area) then spheres (sphere_cum, continuing the sums), from
    the random stream (seed, stream); nrm the shading normal, gnrm the geometric one (both exterior)."""
    st = np.empty(1, np.uint64)
    st[0] = seed_state(seed, stream, 0)
    total = sphere_cum[-1] if sphere_cum.shape[0] > 0 else cum_area[-1]
    ntri = cum_area.shape[0]
    for k in range(n):
        u = rand(st, 0) * total
        if ntri > 0 and u < cum_area[-1]:
            t = np.searchsorted(cum_area, u, side="right")
            t = min(t, ntri - 1)
            a, b = rand(st, 0), rand(st, 0)
            if a + b > 1.0:
                a, b = 1.0 - a, 1.0 - b
            w = 1.0 - a - b
            for c in range(3):
                pos[k, c] = w * V[F[t, 0], c] + a * V[F[t, 1], c] + b * V[F[t, 2], c]
                nrm[k, c] = w * tri_normals[t, 0, c] + a * tri_normals[t, 1, c] + b * tri_normals[t, 2, c]
            ln = math.sqrt(nrm[k, 0] ** 2 + nrm[k, 1] ** 2 + nrm[k, 2] ** 2)
            for c in range(3):
                nrm[k, c] /= ln
            a0, a1, a2 = V[F[t, 1], 0] - V[F[t, 0], 0], V[F[t, 1], 1] - V[F[t, 0], 1], V[F[t, 1], 2] - V[F[t, 0], 2]
            b0, b1, b2 = V[F[t, 2], 0] - V[F[t, 0], 0], V[F[t, 2], 1] - V[F[t, 0], 1], V[F[t, 2], 2] - V[F[t, 0], 2]
            g0, g1, g2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
            lg = max(math.sqrt(g0 * g0 + g1 * g1 + g2 * g2), 1e-300)
            if g0 * nrm[k, 0] + g1 * nrm[k, 1] + g2 * nrm[k, 2] < 0.0:
                lg = -lg  # the winding's normal oriented as the shading normal (exterior)
            gnrm[k, 0], gnrm[k, 1], gnrm[k, 2] = g0 / lg, g1 / lg, g2 / lg
            surf_idx[k] = tri_surface[t]
        else:
            s = np.searchsorted(sphere_cum, u, side="right")
            s = min(s, sphere_cum.shape[0] - 1)
            d = uniform_sphere(rand(st, 0), rand(st, 0))
            for c in range(3):
                nrm[k, c] = d[c]
                gnrm[k, c] = d[c]
                pos[k, c] = spheres[s, SPH_CENTER + c] + spheres[s, SPH_RADIUS] * d[c]
            surf_idx[k] = int(spheres[s, SPH_SURFACE])


@njit(cache=True)
def _dart_throw(pos, radius, lo, dims, keep):
    """Greedy acceptance in candidate order; keep[k] = True for accepted candidates. Returns the count."""
    grid = np.full((dims[0], dims[1], dims[2], SLOTS), -1, np.int64)
    r2 = radius * radius
    count = 0
    for k in range(pos.shape[0]):
        i = min(max(int((pos[k, 0] - lo[0]) / radius), 0), dims[0] - 1)
        j = min(max(int((pos[k, 1] - lo[1]) / radius), 0), dims[1] - 1)
        m = min(max(int((pos[k, 2] - lo[2]) / radius), 0), dims[2] - 1)
        ok = True
        for a in range(max(i - 1, 0), min(i + 2, dims[0])):
            for b in range(max(j - 1, 0), min(j + 2, dims[1])):
                for c in range(max(m - 1, 0), min(m + 2, dims[2])):
                    for s in range(SLOTS):
                        q = grid[a, b, c, s]
                        if q < 0:
                            break
                        dx, dy, dz = pos[q, 0] - pos[k, 0], pos[q, 1] - pos[k, 1], pos[q, 2] - pos[k, 2]
                        if dx * dx + dy * dy + dz * dz < r2:
                            ok = False
                            break
                    if not ok:
                        break
                if not ok:
                    break
            if not ok:
                break
        if ok:
            for s in range(SLOTS):
                if grid[i, j, m, s] < 0:
                    grid[i, j, m, s] = k
                    break
            keep[k] = True
            count += 1
    return count


def poisson_disk(V, F, tri_normals, tri_surface, spheres, target: int, seed: int, oversample: int = 8,
                 stream: int = LIGHT_SAMPLE_STREAM, geometric: bool = False):
    """About `target` blue-noise samples on the given triangles and analytic spheres, from the random stream
    (seed, stream): point sets of one surface that must not coincide (the light samples and the bounced light's
    boundary points) take different streams.

    Returns (positions (n,3), normals (n,3) pointing to the exterior, surface ids (n,), area per sample, radius),
    and with `geometric` the surfaces' geometric normals (n,3) (exterior) last.
    The radius is chosen so that dart throwing saturates near the target (random close packing of disks covers
    about 0.55 of the plane: radius = sqrt(0.55 A / (pi N / 4))... with 2r the disk diameter).
    """
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64).reshape(-1, 3)
    tri_area = (0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1) if len(F)
                else np.zeros(0))
    cum = np.cumsum(tri_area)
    sph = np.asarray(spheres, np.float64).reshape(-1, 5)
    sph_area = 4 * np.pi * sph[:, SPH_RADIUS] ** 2
    total_tri = float(cum[-1]) if len(cum) else 0.0
    sph_cum = total_tri + np.cumsum(sph_area)
    area = total_tri + float(sph_area.sum())
    if area <= 0 or target < 1:
        raise ValueError("no surface to sample")
    # disks of diameter r (the minimum distance) at saturation cover ~0.547 of the area (random sequential
    # adsorption); solve N pi (r/2)^2 = 0.547 A for r
    radius = math.sqrt(0.547 * area / (target * math.pi / 4.0))
    n = max(target * oversample, 64)
    pos, nrm, gnrm = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    sid = np.zeros(n, np.int64)
    _candidates(V, F, np.asarray(tri_normals, np.float64).reshape(-1, 3, 3) if len(F) else np.zeros((0, 3, 3)),
                cum if len(cum) else np.zeros(0), sph, sph_cum if len(sph) else np.zeros(0), n, seed, stream, pos, nrm,
                sid,
                np.asarray(tri_surface, np.int64) if len(F) else np.zeros(0, np.int64), gnrm)
    lo = pos.min(0) - radius
    dims = np.maximum(np.ceil((pos.max(0) + radius - lo) / radius).astype(np.int64), 1)
    keep = np.zeros(n, np.bool_)
    count = _dart_throw(pos, radius, lo, dims, keep)
    out = pos[keep], nrm[keep], sid[keep], area / count, radius
    return (*out, gnrm[keep]) if geometric else out


@njit(parallel=True, cache=True)
def share_among_neighbours(pos, val, radius, out):
    """Each point's value (n, 3) shared equally among the points within `radius` of it (itself included), added
    into out: the sum is kept, and one point's outlier (a single gather ray meeting a volume sample close by, a
    path that found a light by chance) is spread over its neighbours."""
    n = pos.shape[0]
    count = np.zeros(n)
    r2 = radius * radius
    for i in prange(n):
        k = 0
        for j in range(n):
            if (pos[i, 0] - pos[j, 0]) ** 2 + (pos[i, 1] - pos[j, 1]) ** 2 + (pos[i, 2] - pos[j, 2]) ** 2 <= r2:
                k += 1
        count[i] = k
    for j in prange(n):
        for i in range(n):
            if (pos[i, 0] - pos[j, 0]) ** 2 + (pos[i, 1] - pos[j, 1]) ** 2 + (pos[i, 2] - pos[j, 2]) ** 2 <= r2:
                for c in range(3):
                    out[j, c] += val[i, c] / count[i]
