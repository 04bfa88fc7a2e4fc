"""Beams of light inside a medium and the volume samples along them (Wang et al. 2016, sec. 3.4-3.5, read as
photon beams).

A beam is light entering a medium at a boundary point: position, unit direction, RGB power (W), the medium, its
cross-section (scene units^2) and the boundary's normal where it entered. Beams reach a medium through transparent
layers (a glass wall: _cross, Fresnel-weighted), are cut into volume samples along their path to the boundary
(equal fractions of the light extinguished), and continue after Fresnel internal reflections (a glass wall behind
the boundary reflects too: layer_reflectance) until they are negligible.

Volume sample arrays (beam_segments): start, dir, len, power (at the start), area, medium, ends (1: starts on the
boundary, 2: ends there), plane (the boundary's tangent planes where its beam entered and leaves, columns of
volume_samples: ENTRY_N, ENTRY_Q, EXIT_N, EXIT_Q; normals pointing out of the medium).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.intersect import closest_surface_hits
from pbvol_cli.geometry.scene_build import DIELECTRIC, MED_SIGMA_A, MED_SIGMA_S, NULL, SURF_TYPE, BuiltScene
from pbvol_cli.physics.fresnel import fresnel_dielectric, reflect, refract
from pbvol_cli.physics.sampling import depth_of_fraction, rand, seed_state
from pbvol_cli.pointbased.volume_samples import ENTRY_N, ENTRY_Q, EXIT_N, EXIT_Q, PLANE_COLS
from pbvol_cli.render.interfaces import dielectric_fresnel, incident_side, indices, medium_beyond

Beams = namedtuple("Beams", ["pos", "dir", "power", "medium", "area", "normal"])
Beams.__doc__ = """Beams inside media: position (n, 3), unit direction (n, 3), RGB power (n, 3) in W, medium (n,),
cross-section (n,) and the boundary's geometric normal where the current leg started (n, 3)."""
BeamHits = namedtuple("BeamHits", ["t", "surface", "ng", "ns"])
SegmentArrays = namedtuple("SegmentArrays", ["start", "dir", "len", "power", "area", "medium", "ends", "plane"])
SEGMENT_FIELDS = SegmentArrays._fields

START_COS_MIN = 0.1  # a grazing beam's path back to the boundary is taken as at most eps / this (_segment_beam)
REFLECTION_ROULETTE = 1e-4  # reflected beams weaker than this share of their initial power play roulette (a
# larger share made sparse, heavy survivors on shapes whose beams reflect many times: docs/pbl.md)


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
def cross_interface(surfaces, pos, d, power, medium, cosx, ng, ns, t, surf, eps, alive, bn, u):
    """Move each beam to its hit and take it through the interface; kill on anything else. With u[k] < 0 the
    beam is transmitted, its power times Fresnel T (the reflected part leaves); with u[k] in [0, 1) it is reflected
    with probability F (total internal reflection: always) and transmitted otherwise, its power unchanged (an
    unbiased choice): light inside a glass wall is guided by total internal reflection at its outside and leaks
    into the liquid (the rim lit from above glows down the wall). bn: the geometric normal where it crossed into a
    medium (its boundary plane there)."""
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
def _segments(media, surfaces, beams, hits, out, eps, nseg, p_min, R2, seed, leg, alive):
    """For each live beam k (Beams) and its hit (BeamHits): nseg volume samples into out (SegmentArrays, slots
    k * nseg ...), then its internal reflection (_segment_beam)."""
    for k in prange(beams.pos.shape[0]):
        # (k cast: prange's index is uint64 in parallel code, int64 in the serial typing: two compiled copies)
        _segment_beam(np.int64(k), media, surfaces, beams, hits, out, eps, nseg, p_min, R2, seed, leg, alive)


@njit(cache=True)
def _segment_beam(k, media, surfaces, beams, hits, out, eps, nseg, p_min, R2, seed, leg, alive):
    """Cut beam k's path to the boundary into nseg volume samples (equal fractions of 1 - exp(-sigma t) in the
    most penetrating channel), then reflect it internally (Fresnel F, with the glass wall behind the boundary's R2;
    below p_min[k] by roulette) or end it (alive[k] = False). The samples' planes: the boundary's tangent planes
    where the beam starts (normal beams.normal) and ends, outward."""
    pos, d, power, area, bn = beams.pos, beams.dir, beams.power, beams.area, beams.normal
    t, surf, ng, ns = hits.t, hits.surface, hits.ng, hits.ns
    o_start, o_dir, o_len, o_power = out.start, out.dir, out.len, out.power
    o_area, o_medium, o_ends, o_plane = out.area, out.medium, out.ends, out.plane
    base = k * nseg
    m = beams.medium[k]
    tex = t[k]
    if not alive[k] or tex == np.inf:
        alive[k] = False
        for q in range(nseg):
            o_len[base + q] = 0.0
        return
    smin = np.inf
    for c in range(3):
        smin = min(smin, media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c])
    frac = -math.expm1(-smin * tex) if smin > 0.0 else 1.0
    # the beam starts eps inside the boundary (along the normal) with the power that crossed it: its path from the
    # boundary, eps / cos, is given back to its first sample, which then starts on the boundary's tangent plane
    # (a dense medium's beams otherwise carried e^(sigma_t eps / cos) too much, 9 % at a mean free path of 11 eps)
    back = eps / max(abs(d[k, 0] * bn[k, 0] + d[k, 1] * bn[k, 1] + d[k, 2] * bn[k, 2]), START_COS_MIN)
    t0 = 0.0
    for q in range(nseg):
        u = (q + 1.0) / nseg * frac
        t1 = depth_of_fraction(u, smin) if smin > 0.0 else tex * (q + 1.0) / nseg
        if q == nseg - 1:
            t1 = tex
        i = base + q
        lead = back if q == 0 else 0.0
        for c in range(3):
            o_start[i, c] = pos[k, c] + (t0 - lead) * d[k, c]
            o_dir[i, c] = d[k, c]
            o_power[i, c] = power[k, c] * math.exp(-(media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c])
                                                   * (t0 + back - lead))
        o_len[i] = t1 - t0 + lead
        o_area[i] = area[k]
        o_medium[i] = m
        o_ends[i] = (1 if q == 0 else 0) | (2 if q == nseg - 1 else 0)
        # both tangent planes (each source point takes the nearer: sources.source_terms); outward normals
        cs = d[k, 0] * bn[k, 0] + d[k, 1] * bn[k, 1] + d[k, 2] * bn[k, 2]
        ce = d[k, 0] * ng[k, 0] + d[k, 1] * ng[k, 1] + d[k, 2] * ng[k, 2]
        sg = -1.0 if cs > 0.0 else 1.0
        se = 1.0 if ce > 0.0 else -1.0
        for c in range(3):
            o_plane[i, ENTRY_N + c] = sg * bn[k, c]
            o_plane[i, EXIT_N + c] = se * ng[k, c]
        # the start lies eps inside the boundary
        o_plane[i, ENTRY_Q] = (o_plane[i, ENTRY_N] * pos[k, 0] + o_plane[i, ENTRY_N + 1] * pos[k, 1]
                               + o_plane[i, ENTRY_N + 2] * pos[k, 2] + eps)
        o_plane[i, EXIT_Q] = (o_plane[i, EXIT_N] * (pos[k, 0] + tex * d[k, 0])
                              + o_plane[i, EXIT_N + 1] * (pos[k, 1] + tex * d[k, 1])
                              + o_plane[i, EXIT_N + 2] * (pos[k, 2] + tex * d[k, 2]))
        t0 = t1
    # internal reflection at the exit
    s = surf[k]
    if surfaces[s, SURF_TYPE] != DIELECTRIC:
        alive[k] = False
        return
    dx, dy, dz = d[k, 0], d[k, 1], d[k, 2]
    entering, nx, ny, nz, gx, gy, gz, eta_i, eta_t, cos_i, F, _ = _interface(surfaces, s, d, ng, ns, k)
    F = slab_reflectance(F, R2[k])  # a glass wall behind the boundary reflects too (layer_reflectance)
    bn[k, 0], bn[k, 1], bn[k, 2] = ng[k, 0], ng[k, 1], ng[k, 2]
    pmax = 0.0
    for c in range(3):
        power[k, c] *= math.exp(-(media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c]) * (tex + back)) * F
        pmax = max(pmax, power[k, c])
    if pmax < p_min[k]:
        # Russian roulette on weak reflections (unbiased): a beam trapped by total internal reflection would
        # otherwise add max_reflections legs of little power each
        st = np.empty(1, np.uint64)
        st[0] = seed_state(seed, 0x5E6 + leg, k)
        if pmax <= 0.0 or rand(st, 0) * p_min[k] >= pmax:
            alive[k] = False
            return
        for c in range(3):
            power[k, c] *= p_min[k] / pmax
    wx, wy, wz = reflect(dx, dy, dz, nx, ny, nz)
    for c in range(3):
        pos[k, c] = pos[k, c] + tex * d[k, c] + eps * (gx if c == 0 else (gy if c == 1 else gz))
    d[k, 0], d[k, 1], d[k, 2] = wx, wy, wz


def into_media(caster, bs: BuiltScene, pos, nrm, sid, wdir, E, area: float, max_layers: int, max_reflections: int,
               layer_rng, with_source: bool = False):
    """Beams from surface samples (positions, exterior normals, surface ids) lit from directions wdir (toward the
    light) with irradiance E (n, 3): power E x area, refracted in through the outer surface, then through
    transparent layers (crossings and reflections inside a glass wall, which guides light by total internal
    reflection; layer_rng draws the Fresnel choices there) until a medium is reached. Returns the beams that
    reached one, their cross-section area |cos theta_t| (Beams), and with_source the index of each one's sample
    (into pos)."""
    n = len(pos)
    bpos, bdir = pos.copy(), -wdir
    bpow = E * area
    bmed = np.full(n, -1, np.int64)
    bcos = np.zeros(n)
    bn = np.zeros((n, 3))
    alive = np.ones(n, np.bool_)
    # (a hit at distance 0: the sample itself)
    cross_interface(bs.surfaces, bpos, bdir, bpow, bmed, bcos, nrm, nrm, np.zeros(n), sid, bs.eps, alive, bn,
           np.full(n, -1.0))
    for _ in range(max_layers + 2 * max_reflections):
        walk = np.flatnonzero(alive & (bmed < 0))
        if len(walk) == 0:
            break
        t, s, ng, ns = closest_surface_hits(caster, bs, bpos[walk], bdir[walk])
        sub = alive[walk].copy()
        p_, d_, w_, m_, c_, n_ = bpos[walk], bdir[walk], bpow[walk], bmed[walk], bcos[walk], bn[walk]
        cross_interface(bs.surfaces, p_, d_, w_, m_, c_, ng, ns, t, s, bs.eps, sub, n_, layer_rng.random(len(walk)))
        bpos[walk], bdir[walk], bpow[walk], bmed[walk], bcos[walk] = p_, d_, w_, m_, c_
        alive[walk], bn[walk] = sub, n_
    keep = alive & (bmed >= 0)
    beams = Beams(bpos[keep], bdir[keep], bpow[keep], bmed[keep], area * np.abs(bcos[keep]), bn[keep])
    return (beams, np.flatnonzero(keep)) if with_source else beams


def concatenate_beams(parts: list) -> Beams:
    """One Beams of several."""
    return Beams(*(np.concatenate([getattr(b, f) for b in parts]) for f in Beams._fields))


def beam_segments(caster, bs: BuiltScene, beams: Beams, segments: int, max_reflections: int, seed: int,
                  advance=None) -> dict:
    """Volume samples along beams, followed through internal reflections (at most max_reflections; below
    REFLECTION_ROULETTE of the initial power by Russian roulette). Returns the arrays {start, dir, len, power,
    area, medium, ends, plane} (SEGMENT_FIELDS) and leg: the samples of one leg (a beam between two boundary
    points) share an index, 0, 1, ... in the order the legs were traced; the beams' arrays are consumed."""
    p_min = REFLECTION_ROULETTE * beams.power.max(axis=1) if len(beams.power) else np.zeros(0)
    out = {k: [] for k in (*SEGMENT_FIELDS, "leg")}
    alive = np.ones(len(beams.pos), np.bool_)
    legs = 0
    for leg in range(max_reflections + 1):
        act = np.flatnonzero(alive)
        if len(act) == 0:
            break
        live = Beams(*(a[act] for a in beams))
        t, s, ng, ns = closest_surface_hits(caster, bs, live.pos, live.dir)
        m = len(act) * segments
        o = SegmentArrays(np.zeros((m, 3)), np.zeros((m, 3)), np.zeros(m), np.zeros((m, 3)), np.zeros(m),
                          np.zeros(m, np.int64), np.zeros(m, np.int64), np.zeros((m, PLANE_COLS)))
        a_ = alive[act].copy()
        R2 = layer_reflectance(caster, bs, live.pos, live.dir, t, s, ng, ns)
        _segments(bs.media, bs.surfaces, live, BeamHits(t, s, ng, ns), o, bs.eps, segments, p_min[act], R2, seed,
                  leg, a_)
        beams.pos[act], beams.dir[act] = live.pos, live.dir
        beams.power[act], beams.normal[act] = live.power, live.normal
        alive[act] = a_
        valid = o.len > 0
        for key, arr in zip(SEGMENT_FIELDS, o):
            out[key].append(arr[valid])
        out["leg"].append(((legs + np.arange(m, dtype=np.int64) // segments)[valid]).astype(np.int32))  # (slots k *
        # segments + q; 32 bits: a set holds fewer than 2^31 legs, and a render's memory peaks while one is built)
        legs += len(act)
        if advance is not None:
            advance()
    empty = {"start": (0, 3), "dir": (0, 3), "power": (0, 3), "plane": (0, PLANE_COLS)}
    cat = {k: (np.concatenate(v) if v else np.zeros(empty.get(k, 0))) for k, v in out.items()}
    cat["medium"] = cat["medium"].astype(np.int64)
    cat["ends"] = cat["ends"].astype(np.int64)
    cat["leg"] = cat["leg"].astype(np.int32, copy=False)
    return cat


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
