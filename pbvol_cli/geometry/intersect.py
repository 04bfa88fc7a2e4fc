"""Per-ray geometry helpers for the kernels: analytic spheres and lights, mesh shading normals.

Triangles are intersected by Embree in batches (geometry/raycast.py); whatever Embree returns is
merged here with the analytic primitives, which numba intersects itself (exactly: a sphere shape refracts
like a sphere).
"""

import math

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.scene_build import SPH_CENTER, SPH_RADIUS, SPH_SURFACE
from pbvol_cli.physics.lights import intersect_lights, sphere_hit

INF = np.inf


@njit(inline="always", cache=True)
def closest_sphere(spheres, ox, oy, oz, dx, dy, dz, tmax):
    """Closest analytic sphere hit before tmax: (t, sphere index) or (inf, -1)."""
    best, idx = tmax, -1
    for k in range(spheres.shape[0]):
        t, _ = sphere_hit(ox, oy, oz, dx, dy, dz, spheres[k, SPH_CENTER], spheres[k, SPH_CENTER + 1],
                          spheres[k, SPH_CENTER + 2], spheres[k, SPH_RADIUS], 0.0)
        if t < best:
            best, idx = t, k
    return (best, idx) if idx >= 0 else (INF, -1)


@njit(inline="always", cache=True)
def analytic_hit(spheres, lights, ox, oy, oz, dx, dy, dz, tmax, skip_light=-1):
    """Closest analytic hit: (t, kind, index) with kind 1 = sphere shape, 2 = area light, 0 = none.

    A shadow ray passes its target light as skip_light: the sampled point is on that light, and the
    offset origin can meet the light's silhouette a little before the sampled distance."""
    ts, ks = closest_sphere(spheres, ox, oy, oz, dx, dy, dz, tmax)
    tl, kl = intersect_lights(lights, ox, oy, oz, dx, dy, dz, min(tmax, ts), skip_light)
    if kl >= 0 and tl < ts:
        return tl, 2, kl
    if ks >= 0:
        return ts, 1, ks
    return INF, 0, -1


@njit(inline="always", cache=True)
def mesh_shading_normal(tri_normals, prim, u, v):
    w = 1.0 - u - v
    nx = w * tri_normals[prim, 0, 0] + u * tri_normals[prim, 1, 0] + v * tri_normals[prim, 2, 0]
    ny = w * tri_normals[prim, 0, 1] + u * tri_normals[prim, 1, 1] + v * tri_normals[prim, 2, 1]
    nz = w * tri_normals[prim, 0, 2] + u * tri_normals[prim, 1, 2] + v * tri_normals[prim, 2, 2]
    inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    return nx * inv, ny * inv, nz * inv


@njit(parallel=True, cache=True)
def _merge_hits(spheres, tri_surface, tri_normals, o, d, t_mesh, prim, u, v, ng_mesh, t_out, surf_out, ng_out, ns_out):
    for k in prange(o.shape[0]):
        ts, ks = closest_sphere(spheres, o[k, 0], o[k, 1], o[k, 2], d[k, 0], d[k, 1], d[k, 2], t_mesh[k])
        if ks >= 0:
            t_out[k] = ts
            surf_out[k] = int(spheres[ks, SPH_SURFACE])
            for c in range(3):
                ng_out[k, c] = (o[k, c] + ts * d[k, c] - spheres[ks, SPH_CENTER + c]) / spheres[ks, SPH_RADIUS]
                ns_out[k, c] = ng_out[k, c]
        elif prim[k] >= 0:
            t_out[k] = t_mesh[k]
            surf_out[k] = tri_surface[prim[k]]
            gx, gy, gz = float(ng_mesh[k, 0]), float(ng_mesh[k, 1]), float(ng_mesh[k, 2])
            inv = 1.0 / math.sqrt(gx * gx + gy * gy + gz * gz)
            ng_out[k, 0], ng_out[k, 1], ng_out[k, 2] = gx * inv, gy * inv, gz * inv
            ns_out[k, 0], ns_out[k, 1], ns_out[k, 2] = mesh_shading_normal(tri_normals, prim[k], float(u[k]),
                                                                           float(v[k]))
        else:
            t_out[k] = INF
            surf_out[k] = -1


def closest_surface_hits(caster, built, origins: np.ndarray, dirs: np.ndarray):
    """Closest surface (triangle or analytic sphere; lights ignored) along each ray, batched.

    Returns (t [inf = miss], surface id [-1], geometric normal (exterior), shading normal (exterior))."""
    t, prim, u, v, ng = caster.closest_hit(origins, dirs)
    n = len(origins)
    t_out, surf = np.empty(n), np.empty(n, np.int64)
    ng_out, ns_out = np.zeros((n, 3)), np.zeros((n, 3))
    _merge_hits(built.spheres, built.tri_surface, built.tri_normals, np.ascontiguousarray(origins, np.float64),
                np.ascontiguousarray(dirs, np.float64), t, prim, u, v, ng, t_out, surf, ng_out, ns_out)
    return t_out, surf, ng_out, ns_out


@njit(parallel=True, cache=True)
def light_hits(lights, pos, dirs, tmax, t_out, li_out, skip):
    """The closest emitter (sphere or quad light) along each ray before tmax, ignoring light skip[k] (-1: none):
    distance and index (-1: none)."""
    for k in prange(pos.shape[0]):
        t, li = intersect_lights(lights, pos[k, 0], pos[k, 1], pos[k, 2], dirs[k, 0], dirs[k, 1], dirs[k, 2], tmax[k],
                                 skip[k])
        t_out[k], li_out[k] = t, li


def visible(caster, built, origins: np.ndarray, dirs: np.ndarray, dist: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Shadow rays toward light target[k] (its sampled point at dist): True where neither a surface nor another
    emitter lies closer (emitters are opaque: a quad light in front of the sky hides it, as the path tracer sees
    it). The target itself is not a blocker: from the offset origin a ray near its silhouette meets it a little
    before dist (volpath skips it too)."""
    t, _, _, _ = closest_surface_hits(caster, built, origins, dirs)
    tl, li = np.empty(len(origins)), np.empty(len(origins), np.int64)
    light_hits(built.lights, origins, dirs, np.minimum(t, dist), tl, li, np.ascontiguousarray(target, np.int64))
    return (t >= dist) & ~(li >= 0)
