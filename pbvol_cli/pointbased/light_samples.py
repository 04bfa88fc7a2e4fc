"""Light surface samples and light volume samples (Wang et al. 2016, sec. 3.4-3.5), read as photon beams.

Surface sample j (blue noise on the outer layer of a medium-holding object, area A_j) is connected to each light:
irradiance E_j (direct, with visibility). The transmitted part (Fresnel T) refracts inward and is followed through
transparent layers (transmitted branch, Fresnel-weighted) to the medium: a beam of power Phi_j = E_j A_j T, cross-
section A_perp = A_j |cos theta_t| (at the medium's entry). In the medium the beam is cut into segments, each a
volume sample (start, direction, length, RGB power at its start, cross-section); at the far side the Fresnel-
reflected part continues (internal reflection, total internal reflection included) until it is negligible.

Units: power in W (scene radiance units x scene area), lengths in scene units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.raycast import TriangleCaster
from pbvol_cli.geometry.scene_build import (DIELECTRIC, MED_SIGMA_A, MED_SIGMA_S, NULL, SPH_SURFACE, SURF_MEDIUM_IN,
                                           SURF_MEDIUM_OUT, SURF_TYPE, BuiltScene)
from pbvol_cli.physics.fresnel import fresnel_dielectric, reflect, refract
from pbvol_cli.physics.lights import light_sample
from pbvol_cli.physics.sampling import cosine_directions, depth_of_fraction, rand, seed_state
from pbvol_cli.pointbased.surface_samples import poisson_disk
from pbvol_cli.geometry.intersect import closest_surface_hits, visible
from pbvol_cli.render.interfaces import dielectric_fresnel, incident_side, indices, medium_beyond, shadow_ray_length


PLANE_COLS = 8  # v_plane's columns: the entry plane's n (3) and q, the exit plane's n (3) and q


@dataclass
class LightSamples:
    s_pos: np.ndarray  # (n, 3) surface samples on outer layers
    s_nrm: np.ndarray  # (n, 3) exterior normals
    s_surface: np.ndarray  # (n,) surface ids
    s_area: np.ndarray  # (n,) area each represents
    s_irradiance: np.ndarray  # (n, 3) irradiance (W / area): direct from the lights, visibility included, and indirect
    v_start: np.ndarray  # (m, 3) segment starts
    v_dir: np.ndarray  # (m, 3) propagation directions (unit)
    v_len: np.ndarray  # (m,) segment lengths
    v_power: np.ndarray  # (m, 3) beam power at the segment start (W)
    v_area: np.ndarray  # (m,) beam cross-section
    v_medium: np.ndarray  # (m,) medium ids
    v_ends: np.ndarray  # (m,) 1: the segment starts on the boundary, 2: it ends there (both: 3)
    v_plane: np.ndarray  # (m, 8) the boundary's tangent planes where the segment's beam enters and leaves,
    #                      (n, q) each: n . x = q on it, n pointing from the segment to it
    v_returned: np.ndarray  # (m,) int8: 1 where the light scattered in a medium before it reached the surface
    #                         sample (the medium's light that left it and a table sends back): the bounced layer's

    FIELDS = ("s_pos", "s_nrm", "s_surface", "s_area", "s_irradiance", "v_start", "v_dir", "v_len", "v_power",
              "v_area", "v_medium", "v_ends", "v_plane", "v_returned")

    def arrays(self) -> dict:
        return {k: getattr(self, k) for k in self.FIELDS}

    @classmethod
    def from_arrays(cls, d: dict) -> "LightSamples":
        ls = cls(**{k: d[k] for k in cls.FIELDS})
        n, m = len(ls.s_pos), len(ls.v_start)
        shapes_ok = (ls.s_nrm.shape == (n, 3) and ls.s_irradiance.shape == (n, 3) and ls.v_dir.shape == (m, 3)
                     and ls.v_power.shape == (m, 3) and len(ls.v_len) == m and len(ls.v_area) == m
                     and len(ls.v_ends) == m and ls.v_plane.shape == (m, PLANE_COLS) and len(ls.v_returned) == m)
        if not shapes_ok or not all(np.all(np.isfinite(getattr(ls, k))) for k in ("v_start", "v_power", "v_len")):
            raise ValueError("inconsistent light samples")
        return ls


def outer_layer_surfaces(bs: BuiltScene) -> np.ndarray:
    """Surfaces on the outside of medium-holding shapes: those of a shape that bounds a medium somewhere, with
    vacuum on their exterior (a glass of liquid: the glass's outside and the liquid's free surface)."""
    surf = bs.surfaces
    holds = {int(bs.surface_shape[k]) for k in range(len(surf)) if surf[k, SURF_MEDIUM_IN] >= 0 or surf[k, SURF_MEDIUM_OUT] >= 0}
    return np.array([k for k in range(len(surf)) if int(bs.surface_shape[k]) in holds and surf[k, SURF_MEDIUM_OUT] < 0
                     and surf[k, SURF_TYPE] in (DIELECTRIC, NULL)], np.int64)


# ----------------------------------------------------------------------------- kernels


@njit(parallel=True, cache=True)
def _connect(lights, li, pos, nrm, eps, seed, wdir, dist, E, ok):
    """Sample light li from each surface sample: direction, distance, irradiance; ok = faces the light."""
    for k in prange(pos.shape[0]):
        st = np.empty(1, np.uint64)
        st[0] = seed_state(seed, 0x11 + li, k)
        wx, wy, wz, d, Lr, Lg, Lb, pdf, delta = light_sample(lights, li, pos[k, 0], pos[k, 1], pos[k, 2],
                                                             rand(st, 0), rand(st, 0))
        c = wx * nrm[k, 0] + wy * nrm[k, 1] + wz * nrm[k, 2]
        ok[k] = pdf > 0.0 and c > 0.0
        if ok[k]:
            wdir[k, 0], wdir[k, 1], wdir[k, 2] = wx, wy, wz
            dist[k] = d
            E[k, 0], E[k, 1], E[k, 2] = Lr * c / pdf, Lg * c / pdf, Lb * c / pdf


@njit(inline="always", cache=True)
def _interface(surfaces, s, d, ng, ns, k):
    """A beam k meeting surface s: (entering, shading and geometric normals on the incident side, eta_i, eta_t,
    cos_i, Fresnel F, cos_t)."""
    dx, dy, dz = d[k, 0], d[k, 1], d[k, 2]
    entering, gx, gy, gz, nx, ny, nz = incident_side(dx, dy, dz, ng[k, 0], ng[k, 1], ng[k, 2], ns[k, 0], ns[k, 1],
                                                     ns[k, 2])
    eta_i, eta_t = indices(surfaces, s, entering)
    cos_i, F, cos_t = dielectric_fresnel(eta_i, eta_t, dx, dy, dz, nx, ny, nz)
    return entering, nx, ny, nz, gx, gy, gz, eta_i, eta_t, cos_i, F, cos_t


@njit(parallel=True, cache=True)
def _cross(surfaces, pos, d, power, medium, cosx, ng, ns, t, surf, eps, alive, bn, u):
    """Move each beam to its hit and take it through the interface; kill on anything else. With u[k] < 0 the
    beam is transmitted, its power times Fresnel T (the reflected part leaves); with u[k] in [0, 1) it is reflected
    with probability F (total internal reflection: always) and transmitted otherwise, its power unchanged (an
    unbiased choice): light inside a glass wall is guided by total internal reflection at its outside and leaks
    into the liquid (the rim lit from above glows down the wall; 10% of a milk glass's single scattering under a
    light above it). bn: the geometric normal where it crossed into a medium (its boundary plane there)."""
    for k in prange(pos.shape[0]):
        if not alive[k]:
            continue
        s = surf[k]
        if s < 0 or (surfaces[s, SURF_TYPE] != DIELECTRIC and surfaces[s, SURF_TYPE] != NULL):
            alive[k] = False
            continue
        dx, dy, dz = d[k, 0], d[k, 1], d[k, 2]
        entering, nx, ny, nz, gx, gy, gz, eta_i, eta_t, cos_i, F, cos_t = _interface(surfaces, s, d, ng, ns, k)
        if u[k] >= 0.0 and u[k] < F:  # reflected, staying on this side
            wx, wy, wz = reflect(dx, dy, dz, nx, ny, nz)
            for c in range(3):
                pos[k, c] = pos[k, c] + t[k] * d[k, c] + eps * (gx if c == 0 else (gy if c == 1 else gz))
            d[k, 0], d[k, 1], d[k, 2] = wx, wy, wz
            continue
        if F >= 1.0:
            alive[k] = False
            continue
        wx, wy, wz = refract(dx, dy, dz, nx, ny, nz, eta_t / eta_i, cos_i, cos_t)
        for c in range(3):
            if u[k] < 0.0:
                power[k, c] *= 1.0 - F
            pos[k, c] = pos[k, c] + t[k] * d[k, c] - eps * (gx if c == 0 else (gy if c == 1 else gz))
        d[k, 0], d[k, 1], d[k, 2] = wx, wy, wz
        bn[k, 0], bn[k, 1], bn[k, 2] = gx, gy, gz
        medium[k] = medium_beyond(surfaces, s, entering)
        cosx[k] = cos_t


@njit(parallel=True, cache=True)
def _into_layer(surfaces, pos, d, t, surf, ng, ns, eps, out_pos, out_dir, layer_eta, ok):
    """Beams k leaving through surface surf[k] at distance t[k] into a transparent layer (a dielectric side with no
    medium and eta != 1: the glass around a liquid): where they would continue in it (refracted)."""
    for k in prange(pos.shape[0]):
        ok[k] = False
        s = surf[k]
        if s < 0 or t[k] == np.inf or surfaces[s, SURF_TYPE] != DIELECTRIC:
            continue
        entering, nx, ny, nz, gx, gy, gz, eta_i, eta_t, cos_i, F, cos_t = _interface(surfaces, s, d, ng, ns, k)
        far_medium = medium_beyond(surfaces, s, entering)
        if F >= 1.0 or far_medium >= 0 or eta_t == 1.0:
            continue
        wx, wy, wz = refract(d[k, 0], d[k, 1], d[k, 2], nx, ny, nz, eta_t / eta_i, cos_i, cos_t)
        out_dir[k, 0], out_dir[k, 1], out_dir[k, 2] = wx, wy, wz
        for c in range(3):
            out_pos[k, c] = pos[k, c] + t[k] * d[k, c] - eps * (gx if c == 0 else (gy if c == 1 else gz))
        layer_eta[k] = eta_t
        ok[k] = True


@njit(parallel=True, cache=True)
def _layer_exit(surfaces, d, surf, ng, layer_eta, R2):
    """Fresnel reflectance where beams in a layer (index layer_eta) meet its far side (0 where it is not a
    smooth interface: the light that crosses a diffuse or mirror surface is not followed)."""
    for k in prange(d.shape[0]):
        s = surf[k]
        R2[k] = 0.0
        if s < 0 or (surfaces[s, SURF_TYPE] != DIELECTRIC and surfaces[s, SURF_TYPE] != NULL):
            continue
        c = d[k, 0] * ng[k, 0] + d[k, 1] * ng[k, 1] + d[k, 2] * ng[k, 2]
        eta_beyond = indices(surfaces, s, c < 0.0)[1]
        R2[k] = fresnel_dielectric(min(abs(c), 1.0), eta_beyond / layer_eta[k])[0]


def layer_reflectance(caster, bs: BuiltScene, pos, d, t, surf, ng, ns) -> np.ndarray:
    """For rays leaving a medium through surf at distance t into a thin transparent layer (a glass wall): the
    reflectance of the layer's far side, R2 (0 where there is no layer). With the near side's F the layer
    reflects F + (1 - F)^2 R2 / (1 - F R2) (a slab's inter-reflections; the displacement across the wall is
    ignored): light that the glass sends back into the liquid by total internal reflection at the glass-air
    side, which the liquid-glass Fresnel alone (eta 1.5 / 1.35) misses."""
    n = len(pos)
    R2 = np.zeros(n)
    lp, ld, le, ok = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n), np.zeros(n, np.bool_)
    _into_layer(bs.surfaces, pos, d, t, surf, ng, ns, bs.eps, lp, ld, le, ok)
    idx = np.flatnonzero(ok)
    if len(idx):
        _, s2, ng2, _ = closest_surface_hits(caster, bs, lp[idx], ld[idx])
        r = np.zeros(len(idx))
        _layer_exit(bs.surfaces, ld[idx], s2, ng2, le[idx], r)
        R2[idx] = r
    return R2


@njit(inline="always", cache=True)
def slab_reflectance(F, R2):
    """Reflectance of an interface (F) backed by a layer whose far side reflects R2, inter-reflections summed."""
    return F + (1.0 - F) * (1.0 - F) * R2 / (1.0 - F * R2) if R2 > 0.0 else F


@njit(parallel=True, cache=True)
def _segments(media, surfaces, pos, d, power, medium, area, t, surf, ng, ns, eps, nseg, p_min, bn, R2, seed, leg,
              o_start, o_dir, o_len, o_power, o_area, o_medium, o_ends, o_plane, alive):
    """Cut each beam's path to the boundary into nseg volume samples (equal fractions of 1 - exp(-sigma t) in the
    most penetrating channel), then reflect it internally (Fresnel F; below p_min by roulette) or end it. o_ends marks the segments that
    start (1) or end (2) on the boundary; o_plane holds the boundary's tangent planes where the beam starts
    (normal bn) and ends, as (n, q) each with n . x = q on it and n pointing from the segment to it."""
    for k in prange(pos.shape[0]):
        base = k * nseg
        m = medium[k]
        tex = t[k]
        if not alive[k] or tex == np.inf:
            alive[k] = False
            for q in range(nseg):
                o_len[base + q] = 0.0
            continue
        smin = np.inf
        for c in range(3):
            smin = min(smin, media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c])
        frac = -math.expm1(-smin * tex) if smin > 0.0 else 1.0
        t0 = 0.0
        for q in range(nseg):
            u = (q + 1.0) / nseg * frac
            t1 = depth_of_fraction(u, smin) if smin > 0.0 else tex * (q + 1.0) / nseg
            if q == nseg - 1:
                t1 = tex
            i = base + q
            for c in range(3):
                o_start[i, c] = pos[k, c] + t0 * d[k, c]
                o_dir[i, c] = d[k, c]
                o_power[i, c] = power[k, c] * math.exp(-(media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c]) * t0)
            o_len[i] = t1 - t0
            o_area[i] = area[k]
            o_medium[i] = m
            o_ends[i] = (1 if q == 0 else 0) | (2 if q == nseg - 1 else 0)
            # both tangent planes (each source point takes the nearer: estimators._source); outward normals
            cs = d[k, 0] * bn[k, 0] + d[k, 1] * bn[k, 1] + d[k, 2] * bn[k, 2]
            ce = d[k, 0] * ng[k, 0] + d[k, 1] * ng[k, 1] + d[k, 2] * ng[k, 2]
            sg = -1.0 if cs > 0.0 else 1.0
            se = 1.0 if ce > 0.0 else -1.0
            for c in range(3):
                o_plane[i, c] = sg * bn[k, c]
                o_plane[i, 4 + c] = se * ng[k, c]
            # the start lies eps inside the boundary
            o_plane[i, 3] = o_plane[i, 0] * pos[k, 0] + o_plane[i, 1] * pos[k, 1] + o_plane[i, 2] * pos[k, 2] + eps
            o_plane[i, 7] = (o_plane[i, 4] * (pos[k, 0] + tex * d[k, 0]) + o_plane[i, 5] * (pos[k, 1] + tex * d[k, 1])
                             + o_plane[i, 6] * (pos[k, 2] + tex * d[k, 2]))
            t0 = t1
        # internal reflection at the exit
        s = surf[k]
        if surfaces[s, SURF_TYPE] != DIELECTRIC:
            alive[k] = False
            continue
        dx, dy, dz = d[k, 0], d[k, 1], d[k, 2]
        entering, nx, ny, nz, gx, gy, gz, eta_i, eta_t, cos_i, F, _ = _interface(surfaces, s, d, ng, ns, k)
        F = slab_reflectance(F, R2[k])  # a glass wall behind the boundary reflects too (layer_reflectance)
        bn[k, 0], bn[k, 1], bn[k, 2] = ng[k, 0], ng[k, 1], ng[k, 2]
        pmax = 0.0
        for c in range(3):
            power[k, c] *= math.exp(-(media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c]) * tex) * F
            pmax = max(pmax, power[k, c])
        if pmax < p_min[k]:
            # Russian roulette on weak reflections (unbiased): a beam trapped by total internal reflection would
            # otherwise add max_reflections legs of little power each
            st = np.empty(1, np.uint64)
            st[0] = seed_state(seed, 0x5E6 + leg, k)
            if pmax <= 0.0 or rand(st, 0) * p_min[k] >= pmax:
                alive[k] = False
                continue
            for c in range(3):
                power[k, c] *= p_min[k] / pmax
        wx, wy, wz = reflect(dx, dy, dz, nx, ny, nz)
        for c in range(3):
            pos[k, c] = pos[k, c] + tex * d[k, c] + eps * (gx if c == 0 else (gy if c == 1 else gz))
        d[k, 0], d[k, 1], d[k, 2] = wx, wy, wz


# ----------------------------------------------------------------------------- driver


def _lit(caster, bs, li, pos, nrm, eps, seed, wdir, dist, E):
    """One sample of light li from each point (normal nrm): fills wdir, dist, E (irradiance); returns the
    indices of the points that face the light and see it."""
    ok = np.zeros(len(pos), np.bool_)
    _connect(bs.lights, li, pos, nrm, eps, seed, wdir, dist, E, ok)
    idx = np.flatnonzero(ok)
    return idx[visible(caster, bs, pos[idx] + eps * nrm[idx], wdir[idx], shadow_ray_length(dist[idx], eps),
                       np.full(len(idx), li, np.int64))]


def _indirect(caster, bs, pos, nrm, sid, eps, seed, returned_orders="1,2,3+"):
    """Indirect light at the surface samples (sec. 3.4), path traced: from each sample a cosine-weighted
    direction; where it first meets a surface that is not one of the sample's own object's transparent layers,
    the radiance leaving that surface toward the sample, by the reference path tracer (render/volpath.py:
    trace_radiance): every bounce, light through glass onto the table, and the media's own light that left them
    and comes back. Arriving with irradiance-equivalent pi L (cosine sampling). Not taken here: directions that
    meet a light or the environment first (the direct connections' part), and the object's own transparent
    layers (light through a glass's wall reaches the liquid as the beams of the samples on the glass's outside).

    Returns (sample indices, directions toward the light's origin, irradiance of the light that has not scattered
    in a medium on its way, irradiance of the light that has: the bounced layer's)."""
    from pbvol_cli.geometry.intersect import light_hits
    from pbvol_cli.render.volpath import trace_radiance

    n = len(pos)
    rng = np.random.default_rng([seed, 0x1D1])
    u1, u2 = rng.random(n), rng.random(n)
    wdir = np.zeros((n, 3))
    cosine_directions(np.ascontiguousarray(nrm), u1, u2, wdir)
    origin = pos + eps * nrm
    t, s, _, _ = closest_surface_hits(caster, bs, origin, wdir)
    hit = np.isfinite(t) & (s >= 0)
    sc = np.where(hit, s, 0)
    own_layer = (np.isin(bs.surfaces[sc, SURF_TYPE], (DIELECTRIC, NULL))
                 & (bs.surface_shape[sc] == bs.surface_shape[sid]))
    tl, li = np.empty(n), np.empty(n, np.int64)
    light_hits(bs.lights, origin, wdir, np.where(hit, t, np.inf), tl, li, np.full(n, -1, np.int64))
    idx = np.flatnonzero(hit & ~own_layer & (li < 0))
    E0 = np.pi * trace_radiance(bs, caster, origin[idx], wdir[idx], seed + 0x1D2, "0")
    E1 = np.pi * trace_radiance(bs, caster, origin[idx], wdir[idx], seed + 0x1D3, returned_orders)
    keep = (E0.max(axis=1) > 0) | (E1.max(axis=1) > 0)
    return idx[keep], wdir[idx[keep]], E0[keep], E1[keep]


RETURNED_BEAMS = 2000  # beams of returned light kept (thin_by_power) per light-sample set


def thin_by_power(power: np.ndarray, target: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Unbiased thinning of beams (n, 3) powers to about `target`: beam i is kept with probability
    q_i = min(1, p_i / tau) (p_i its largest channel) and its power divided by q_i, tau chosen so that the
    q_i sum to the target; a kept beam carries at least tau. Returns (kept indices, their powers)."""
    p = power.max(axis=1) if len(power) else np.zeros(0)
    if len(p) <= target or p.sum() <= 0:
        return np.arange(len(p)), power
    lo, hi = 0.0, float(p.max())
    for _ in range(60):  # bisection on tau: sum(min(1, p / tau)) = target
        tau = 0.5 * (lo + hi)
        if np.minimum(1.0, p / max(tau, 1e-300)).sum() > target:
            lo = tau
        else:
            hi = tau
    q = np.minimum(1.0, p / max(hi, 1e-300))
    keep = np.flatnonzero(rng.random(len(p)) < q)
    return keep, power[keep] / q[keep, None]


REFLECTION_ROULETTE = 1e-4  # reflected beams weaker than this share of their initial power play roulette (1e-2: 2x the
# relMSE on the bumpy sphere, whose beams reflect many times: sparse, heavy survivors)


def beam_segments(caster, bs: BuiltScene, bpos, bdir, bpow, bmed, barea, bnrm, segments: int, max_reflections: int,
                  seed: int, advance=None) -> dict:
    """Volume samples along beams (start, direction, power at the start in W, medium, cross-section, boundary
    normal at the start) followed through internal reflections (at most max_reflections; below
    REFLECTION_ROULETTE of the initial power by Russian roulette). Returns the arrays {start, dir, len, power,
    area, medium, ends, plane}; the beam arrays are consumed."""
    p_min = REFLECTION_ROULETTE * bpow.max(axis=1) if len(bpow) else np.zeros(0)
    out = {k: [] for k in ("start", "dir", "len", "power", "area", "medium", "ends", "plane")}
    alive = np.ones(len(bpos), np.bool_)
    for leg in range(max_reflections + 1):
        act = np.flatnonzero(alive)
        if len(act) == 0:
            break
        t, s, ng, ns = closest_surface_hits(caster, bs, bpos[act], bdir[act])
        m = len(act) * segments
        o = (np.zeros((m, 3)), np.zeros((m, 3)), np.zeros(m), np.zeros((m, 3)), np.zeros(m), np.zeros(m, np.int64),
             np.zeros(m, np.int64), np.zeros((m, PLANE_COLS)))
        p_, d_, w_, n_, a_ = bpos[act], bdir[act], bpow[act], bnrm[act], alive[act].copy()
        R2 = layer_reflectance(caster, bs, p_, d_, t, s, ng, ns)
        _segments(bs.media, bs.surfaces, p_, d_, w_, bmed[act], barea[act], t, s, ng, ns, bs.eps, segments,
                  p_min[act], n_, R2, seed, leg, *o, a_)
        bpos[act], bdir[act], bpow[act], bnrm[act], alive[act] = p_, d_, w_, n_, a_
        valid = o[2] > 0
        for key, arr in zip(out, o):
            out[key].append(arr[valid])
        if advance is not None:
            advance()
    empty = {"start": (0, 3), "dir": (0, 3), "power": (0, 3), "plane": (0, PLANE_COLS)}
    cat = {k: (np.concatenate(v) if v else np.zeros(empty.get(k, 0))) for k, v in out.items()}
    cat["medium"] = cat["medium"].astype(np.int64)
    cat["ends"] = cat["ends"].astype(np.int64)
    return cat


def place_light_samples(bs: BuiltScene, surface_samples: int, segments: int, max_reflections: int,
                        max_layers: int, seed: int, threads: int = 2, progress=None,
                        returned_orders: str = "1,2,3+") -> LightSamples:
    """Surface samples on every medium-holding object's outer layer, their beams and the volume samples.
    progress(done, total), if given, is called after each step (lights, indirect light, reflection passes).
    returned_orders: the scattering orders the returned light (v_returned) keeps (tests compare it with volpath
    --orders)."""
    steps = len(bs.lights) + 2 + max_reflections + 1
    step = [0]

    def advance():
        step[0] += 1
        if progress is not None:
            progress(min(step[0], steps), steps)

    outer = outer_layer_surfaces(bs)
    if len(outer) == 0:
        raise ValueError("no medium-holding object with a transparent boundary to place light samples on")
    tri = np.isin(bs.tri_surface, outer)
    sph = bs.spheres[np.isin(bs.spheres[:, SPH_SURFACE].astype(np.int64), outer)]
    advance()
    pos, nrm, sid, area, spacing = poisson_disk(bs.vertices, bs.faces[tri], bs.tri_normals[tri], bs.tri_surface[tri], sph,
                                          surface_samples, seed)
    n = len(pos)
    caster = TriangleCaster(bs.vertices, bs.faces, threads)
    eps = bs.eps
    irr = np.zeros((n, 3))
    beams = []  # (pos, dir, power, medium, cross-section, boundary normal)
    returned = []  # the same for light that scattered in a medium before it reached the sample

    layer_rng = np.random.default_rng([seed, 0x1A7E])  # Fresnel choices inside transparent layers

    def enter(vis, wdir, E, into):
        """Beams (appended to `into`) from samples vis lit from directions wdir with irradiance E: refracted in
        through the outer surface, then through transparent layers until a medium is reached."""
        bpos, bdir = pos[vis].copy(), -wdir
        bpow = E * area
        bmed = np.full(len(vis), -1, np.int64)
        bcos = np.zeros(len(vis))
        bn = np.zeros((len(vis), 3))
        alive = np.ones(len(vis), np.bool_)
        # (a hit at distance 0: the sample itself)
        _cross(bs.surfaces, bpos, bdir, bpow, bmed, bcos, nrm[vis], nrm[vis], np.zeros(len(vis)), sid[vis], eps,
               alive, bn, np.full(len(vis), -1.0))
        # crossings and reflections inside the layers (a glass wall guides light by total internal reflection)
        for _ in range(max_layers + 2 * max_reflections):
            walk = np.flatnonzero(alive & (bmed < 0))
            if len(walk) == 0:
                break
            t, s, ng, ns = closest_surface_hits(caster, bs, bpos[walk], bdir[walk])
            sub = alive[walk].copy()
            p_, d_, w_, m_, c_, n_ = bpos[walk], bdir[walk], bpow[walk], bmed[walk], bcos[walk], bn[walk]
            _cross(bs.surfaces, p_, d_, w_, m_, c_, ng, ns, t, s, eps, sub, n_, layer_rng.random(len(walk)))
            bpos[walk], bdir[walk], bpow[walk], bmed[walk], bcos[walk] = p_, d_, w_, m_, c_
            alive[walk], bn[walk] = sub, n_
        keep = alive & (bmed >= 0)
        into.append((bpos[keep], bdir[keep], bpow[keep], bmed[keep], area * np.abs(bcos[keep]), bn[keep]))

    for li in range(len(bs.lights)):
        wdir, dist, E = np.zeros((n, 3)), np.zeros(n), np.zeros((n, 3))
        vis = _lit(caster, bs, li, pos, nrm, eps, seed, wdir, dist, E)
        irr[vis] += E[vis]
        enter(vis, wdir[vis], E[vis], beams)
        advance()
    vis, wdir, E0, E1 = _indirect(caster, bs, pos, nrm, sid, eps, seed, returned_orders)
    irr[vis] += E0 + E1
    if len(vis):
        # one path per sample is heavy-tailed (a table point's path that finds the light through the glass by
        # chance: oil glass, 10 pixels held 73 % of the 16-spp error); each sample's indirect power is shared
        # among its neighbours, the total kept, as the bounced generations do
        from pbvol_cli.pointbased.bounced import SMOOTHING, _share_among_neighbours

        for E in (E0, E1):
            shared = np.zeros_like(E)
            _share_among_neighbours(pos[vis], E, SMOOTHING * spacing, shared)
            E[:] = shared
    enter(vis, wdir, E0, beams)
    enter(vis, wdir, E1, returned)
    advance()
    parts = []
    for group, s_off, adv in ((beams, 0, advance), (returned, 0x2E7, None)):
        bpos, bdir, bpow, bmed, barea, bnrm = (np.concatenate([b[i] for b in group]) for i in range(6))
        seg = segments
        if group is returned:
            # the returned light is diffuse and smooth, like the boundary's bounced light: fewer beams and
            # segments (bumpy sphere on its floor, every returned beam kept at 16 segments: 1.8x the time, 1.8x
            # the memory)
            keep, bpow = thin_by_power(bpow, RETURNED_BEAMS, np.random.default_rng([seed, 0x2E8]))
            bpos, bdir, bmed, barea, bnrm = bpos[keep], bdir[keep], bmed[keep], barea[keep], bnrm[keep]
            seg = max(1, segments // 4)
        parts.append(beam_segments(caster, bs, bpos, bdir, bpow, bmed, barea, bnrm, seg, max_reflections,
                                   seed + s_off, adv))
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    flag = np.concatenate([np.zeros(len(parts[0]["len"]), np.int8), np.ones(len(parts[1]["len"]), np.int8)])
    caster.close()
    if progress is not None:
        progress(steps, steps)
    return LightSamples(pos, nrm, sid, np.full(n, area), irr, cat["start"], cat["dir"], cat["len"], cat["power"],
                        cat["area"], cat["medium"], cat["ends"], cat["plane"], flag)
