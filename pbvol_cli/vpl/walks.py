"""Random walks from the lights that leave virtual point lights (VPLs), seed 004 section 4.1.

A walk starts on a light (emission.py) with a flux weight and is traced through the scene: in a medium a free
flight is sampled (analytic with spectral MIS in a homogeneous medium, delta tracking with spectral-tracking weights
in a heterogeneous one: render/media.py, the path tracer's own estimators), and where it scatters a volume VPL is
left: its position, the direction the light travelled, its medium and its power beta (W: the walk's weight after
the flight's weight sigma_s T / p, before the phase function). On a diffuse surface a surface VPL is left (its
normal on the lit side and albedo). Smooth dielectrics reflect or refract the walk with the Fresnel probability
(the flux is unchanged: the eta^2 of radiance does not apply to flux), mirrors reflect it, null boundaries pass
it. After each VPL the walk goes on in a direction sampled from the phase function or the cosine (their weight is
the albedo), with Russian roulette on its weight relative to its start from `rr_depth` scattering events.

A VPL scatters toward a direction w_o the intensity (W/sr) beta f_p(w_in . w_o) (volume) or beta (albedo / pi)
max(0, n . w_o) (surface); a set of N walks estimates the scattered light as the sum over its VPLs divided by N.
Lights are assumed outside every medium (a walk starts in vacuum) and light paths pass through emitters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.intersect import closest_surface_hits
from pbvol_cli.geometry.scene_build import (DIELECTRIC, DIFFUSE, HOMOGENEOUS, MED_G, MED_KIND, MED_PHASE, MIRROR,
                                           NULL, SPH_SURFACE, SURF_ALBEDO, SURF_MEDIUM_IN, SURF_MEDIUM_OUT, SURF_TYPE,
                                           BuiltScene, sphere_bounds)
from pbvol_cli.physics.fresnel import reflect
from pbvol_cli.physics.phase import phase_sample
from pbvol_cli.physics.sampling import cosine_hemisphere, rand, seed_state
from pbvol_cli.render.interfaces import dielectric_choice, incident_side, medium_beyond
from pbvol_cli.render.media import flight_weight, free_flight, majorant_flight, tentative_collision
from pbvol_cli.vpl.emission import emit, light_choice

VOLUME, SURFACE = 0, 1  # VPL kinds
WALK_STREAM = 0x57A1  # the walks' random streams (physics/sampling.seed_state)


@dataclass
class VPLSet:
    """The VPLs of `walks` random walks, grouped by walk: walk w's are rows first[w]:first[w + 1]. Lengths in scene
    units, power in W (RGB)."""

    pos: np.ndarray  # (M, 3)
    incoming: np.ndarray  # (M, 3) unit direction the light travelled to the VPL
    power: np.ndarray  # (M, 3)
    kind: np.ndarray  # (M,) VOLUME or SURFACE
    medium: np.ndarray  # (M,) the medium a volume VPL is in (-1: surface)
    normal: np.ndarray  # (M, 3) a surface VPL's normal on its lit side
    albedo: np.ndarray  # (M, 3) a surface VPL's diffuse albedo
    first: np.ndarray  # (walks + 1,) int64
    walks: int

    def __len__(self) -> int:
        return len(self.pos)


@njit(parallel=True, cache=True)
def _walk_step(surfaces, media, density, idx, pos, dirs, beta, beta0, medium, depth, rng, tmaj, t, surf, ng, ns,
               eps, max_depth, rr_depth, v_pos, v_in, v_pow, v_kind, v_med, v_nrm, v_alb, alive):
    """Advance walks idx[k] to their next event (their closest surface at t[k]); a VPL left there goes to row k of
    the v_* arrays (v_kind[k] = -1: none); alive[k] False where the walk ended."""
    for k in prange(idx.shape[0]):
        _walk_one(np.int64(k), surfaces, media, density, idx, pos, dirs, beta, beta0, medium, depth, rng, tmaj, t,
                  surf, ng, ns, eps, max_depth, rr_depth, v_pos, v_in, v_pow, v_kind, v_med, v_nrm, v_alb, alive)


@njit(cache=True)
def _survives(beta, beta0, depth, rr_depth, rng, j):
    """Russian roulette on the walk's weight relative to its start (rescaled where it survives)."""
    q = max(beta[j, 0], max(beta[j, 1], beta[j, 2])) / beta0[j]
    if q <= 0.0:
        return False
    if depth[j] < rr_depth or q >= 1.0:
        return True
    if rand(rng, j) >= q:
        return False
    for c in range(3):
        beta[j, c] /= q
    return True


@njit(cache=True)
def _walk_one(k, surfaces, media, density, idx, pos, dirs, beta, beta0, medium, depth, rng, tmaj, t, surf, ng, ns,
              eps, max_depth, rr_depth, v_pos, v_in, v_pow, v_kind, v_med, v_nrm, v_alb, alive):
    j = idx[k]
    v_kind[k] = -1
    alive[k] = False
    dx, dy, dz = dirs[j, 0], dirs[j, 1], dirs[j, 2]
    m = medium[j]
    ts = t[k]
    if m >= 0:
        scattered = False
        if media[m, MED_KIND] == HOMOGENEOUS:
            tf = free_flight(media, m, beta, j, rng, density, pos, dirs, tmaj)
            if tf < ts:
                flight_weight(media, m, beta, j, tf, True)
                pos[j, 0] += tf * dx
                pos[j, 1] += tf * dy
                pos[j, 2] += tf * dz
                scattered = True
            else:
                flight_weight(media, m, beta, j, ts, False)
        else:
            s = 0.0
            while True:
                ds, mu = majorant_flight(media, density, m, pos[j, 0] + s * dx, pos[j, 1] + s * dy,
                                         pos[j, 2] + s * dz, dx, dy, dz, -math.log(1.0 - rand(rng, j)))
                if s + ds >= ts:
                    break
                s += ds
                real, _, _, _ = tentative_collision(media, density, m, beta, j, pos[j, 0] + s * dx,
                                                    pos[j, 1] + s * dy, pos[j, 2] + s * dz, rng, mu)
                if beta[j, 0] == 0.0 and beta[j, 1] == 0.0 and beta[j, 2] == 0.0:
                    return
                if real:
                    pos[j, 0] += s * dx
                    pos[j, 1] += s * dy
                    pos[j, 2] += s * dz
                    scattered = True
                    break
        if scattered:
            v_kind[k] = VOLUME
            v_med[k] = m
            for c in range(3):
                v_pos[k, c] = pos[j, c]
                v_pow[k, c] = beta[j, c]
            v_in[k, 0], v_in[k, 1], v_in[k, 2] = dx, dy, dz
            depth[j] += 1
            if depth[j] >= max_depth or not _survives(beta, beta0, depth, rr_depth, rng, j):
                return
            u1, u2, u3 = rand(rng, j), rand(rng, j), rand(rng, j)
            wx, wy, wz, _ = phase_sample(int(media[m, MED_PHASE]), media[m, MED_G], dx, dy, dz, u1, u2, u3)
            dirs[j, 0], dirs[j, 1], dirs[j, 2] = wx, wy, wz
            alive[k] = True
            return
    s = surf[k]
    if s < 0 or not math.isfinite(ts):
        return
    hx, hy, hz = pos[j, 0] + ts * dx, pos[j, 1] + ts * dy, pos[j, 2] + ts * dz
    inv = 1.0 / math.sqrt(ng[k, 0] ** 2 + ng[k, 1] ** 2 + ng[k, 2] ** 2)
    entering, gx, gy, gz, nx, ny, nz = incident_side(dx, dy, dz, ng[k, 0] * inv, ng[k, 1] * inv, ng[k, 2] * inv,
                                                     ns[k, 0], ns[k, 1], ns[k, 2])
    stype = surfaces[s, SURF_TYPE]
    side = 1.0  # 1: leave on the incident side, -1: beyond
    if stype == NULL:
        medium[j] = medium_beyond(surfaces, s, entering)
        side = -1.0
    elif stype == DIELECTRIC:
        depth[j] += 1
        dx, dy, dz, refracted, _, _ = dielectric_choice(surfaces, s, entering, dx, dy, dz, nx, ny, nz, rand(rng, j))
        if refracted:
            medium[j] = medium_beyond(surfaces, s, entering)
            side = -1.0
    elif stype == MIRROR:
        depth[j] += 1
        for c in range(3):
            beta[j, c] *= surfaces[s, SURF_ALBEDO + c]
        dx, dy, dz = reflect(dx, dy, dz, nx, ny, nz)
    elif stype == DIFFUSE:
        v_kind[k] = SURFACE
        v_med[k] = -1
        v_pos[k, 0], v_pos[k, 1], v_pos[k, 2] = hx + eps * gx, hy + eps * gy, hz + eps * gz
        v_in[k, 0], v_in[k, 1], v_in[k, 2] = dx, dy, dz
        v_nrm[k, 0], v_nrm[k, 1], v_nrm[k, 2] = nx, ny, nz
        for c in range(3):
            v_pow[k, c] = beta[j, c]
            v_alb[k, c] = surfaces[s, SURF_ALBEDO + c]
            beta[j, c] *= surfaces[s, SURF_ALBEDO + c]
        depth[j] += 1
        if depth[j] >= max_depth or not _survives(beta, beta0, depth, rr_depth, rng, j):
            return
        dx, dy, dz = cosine_hemisphere(rand(rng, j), rand(rng, j), nx, ny, nz)
        if dx * gx + dy * gy + dz * gz <= 0.0:
            return
    if depth[j] >= max_depth:
        return
    dirs[j, 0], dirs[j, 1], dirs[j, 2] = dx, dy, dz
    pos[j, 0], pos[j, 1], pos[j, 2] = hx + side * eps * gx, hy + side * eps * gy, hz + side * eps * gz
    alive[k] = True


@njit(parallel=True, cache=True)
def _seed_walks(seed, rng):
    for i in prange(rng.shape[0]):
        rng[i] = seed_state(seed, WALK_STREAM, i)


MEDIA_SHARE = 0.5  # walks from lights at infinity aimed at the media's bounding sphere (vpl/emission.py)


def emission_bounds(bs: BuiltScene) -> np.ndarray:
    """emission.emit_one's bounds: the scene's bounding sphere, the media's (their bounding shapes' boxes; the
    scene's when there is no medium) and MEDIA_SHARE."""
    def sphere(lo, hi):
        return 0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)), 1e-6)

    centre, radius = sphere(bs.bbox[0], bs.bbox[1])
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    bounding = (bs.surfaces[:, SURF_MEDIUM_IN] >= 0) | (bs.surfaces[:, SURF_MEDIUM_OUT] >= 0)
    tri = bounding[bs.tri_surface] if len(bs.faces) else np.zeros(0, bool)
    if tri.any():
        v = bs.vertices[bs.faces[tri].ravel()]
        lo, hi = np.minimum(lo, v.min(axis=0)), np.maximum(hi, v.max(axis=0))
    for row in bs.spheres:
        if bounding[int(row[SPH_SURFACE])]:
            b = sphere_bounds(row)
            lo, hi = np.minimum(lo, b[0]), np.maximum(hi, b[1])
    share = MEDIA_SHARE
    if not np.all(np.isfinite(lo)):
        m_centre, m_radius, share = centre, radius, 0.0
    else:
        m_centre, m_radius = sphere(lo, hi)
    return np.array([*centre, radius, *m_centre, m_radius, share], float)


def trace_walks(caster, bs: BuiltScene, walks: int, seed: int, max_depth: int = 256, rr_depth: int = 4) -> VPLSet:
    """The VPLs of `walks` random walks from the scene's lights (random streams from seed). max_depth: events
    (scattering, surfaces other than null boundaries) a walk takes at most; rr_depth: events before Russian
    roulette."""
    rng = np.zeros(walks, np.uint64)
    _seed_walks(np.uint64(seed), rng)
    pos, dirs, beta = np.zeros((walks, 3)), np.zeros((walks, 3)), np.zeros((walks, 3))
    bounds = emission_bounds(bs)
    cdf = np.cumsum(light_choice(bs.lights, bounds[4:7], bounds[7]))
    cdf[-1] = 1.0
    emit(bs.lights, cdf, bounds, rng, pos, dirs, beta)
    beta0 = np.maximum(beta.max(axis=1), 1e-300)
    medium = np.full(walks, -1, np.int64)
    depth = np.zeros(walks, np.int64)
    tmaj = np.zeros(walks)
    idx = np.flatnonzero(beta.max(axis=1) > 0)
    parts = []
    while len(idx):
        t, surf, ng, ns = closest_surface_hits(caster, bs, pos[idx], dirs[idx])
        n = len(idx)
        v_pos, v_in, v_pow = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
        v_nrm, v_alb = np.zeros((n, 3)), np.zeros((n, 3))
        v_kind, v_med = np.full(n, -1, np.int64), np.full(n, -1, np.int64)
        alive = np.zeros(n, np.bool_)
        _walk_step(bs.surfaces, bs.media, bs.density_data, idx, pos, dirs, beta, beta0, medium, depth, rng, tmaj, t,
                   surf, np.ascontiguousarray(ng, float), np.ascontiguousarray(ns, float), bs.eps, max_depth,
                   rr_depth, v_pos, v_in, v_pow, v_kind, v_med, v_nrm, v_alb, alive)
        left = v_kind >= 0
        parts.append((idx[left], v_pos[left], v_in[left], v_pow[left], v_kind[left], v_med[left], v_nrm[left],
                      v_alb[left]))
        idx = idx[alive]
    cols = [np.concatenate([p[c] for p in parts]) if parts else None for c in range(8)]
    if cols[0] is None or not len(cols[0]):
        z3 = np.zeros((0, 3))
        return VPLSet(z3, z3, z3, np.zeros(0, np.int64), np.zeros(0, np.int64), z3, z3, np.zeros(walks + 1, np.int64),
                      walks)
    order = np.argsort(cols[0], kind="stable")  # by walk, each walk's VPLs in the order it left them
    walk = cols[0][order]
    first = np.searchsorted(walk, np.arange(walks + 1)).astype(np.int64)
    return VPLSet(*(np.ascontiguousarray(c[order]) for c in cols[1:]), first=first, walks=walks)
