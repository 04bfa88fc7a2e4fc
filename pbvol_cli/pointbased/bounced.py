"""Bounced scattering (Wang et al. 2016, sec. 3.10, eq. 7): scattered light reflected by the medium's boundary.

The volume samples follow the unscattered light through internal reflections, and the double and multiple terms
carry scattered light in straight lines (the table: through an infinite medium), so light that has scattered and
is then reflected back by the boundary (Fresnel, total internal reflection above the critical angle) is missing:
most of the light in a high-albedo medium behind glass (wax, milk).

The paper stores this light at surface samples as a diffuse value and single-scatters it (eq. 7). Here it is
carried the same way as the light from the lights, as beams:
1. boundary points x_j on the surfaces bounding the medium (area A_j, inward normal n_j): blue noise, and in a
   convex medium points shot from the sources in uniform directions, where the arriving light is peaked; the two
   are weighted by the balance heuristic (gather_points);
2. from each, a direction w into the medium, drawn in proportion to cos x the boundary's reflectance toward the
   outside (reflectance_tables; a share REFLECTION_MIX by cos alone); the radiance arriving at x_j from w, L_in, is
   the camera estimator (single + double + multiple of the previous generation's samples) along that ray;
3. that light is reflected specularly: a beam from x_j along the mirror direction, of power
   pi F(w . n_j) L_in A_j / p(w) (p: w's density over the cosine density; integral of L F cos dw = pi E[L F / p]),
   cross-section A_j; one gather ray per point is noisy (a volume sample close to the ray), so each point's
   reflected power is shared among its neighbours within SHARING_RADIUS x their spacing (total kept; the beams'
   directions stay their own: the reflected light's direction is decorrelated from its power over that distance,
   as the paper's diffuse value assumes). Drawn by cos alone, the beams beyond the critical angle (F = 1: light
   that stays in until it scatters) were 56 % of the beams behind eta 1.5 but carry over 90 % of the reflected
   power, and the sharing gave the others (F = 0.04 near the normal: light that leaves at the next wall) the same:
   a thin medium's trapped light was a third short (docs/pbl.md, section 8);
4. the beams are cut into volume samples like the lights' (their own internal reflections followed), and give
   generation g + 1's samples, gathered in turn for the next generation;
5. the generations after the last are a geometric tail: the last generation's power is scaled by 1 / (1 - r), r
   the ratio of its emitted power to the one before (docs/pbl.md gives measured ratios).
The union of generations is one more set of volume samples, evaluated on camera rays by the same three estimators;
its sum is the `bounced` layer (light with at least one scattering before a reflection: order 2 and above).
Boundaries that are not dielectric (index-matched, diffuse) reflect nothing here.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.intersect import closest_surface_hits
from pbvol_cli.geometry.scene_build import (DIELECTRIC, SPH_SURFACE, SURF_ETA_IN, SURF_ETA_OUT, SURF_MEDIUM_IN,
                                           SURF_TYPE, BuiltScene)
from pbvol_cli.physics.fresnel import fresnel_dielectric
from pbvol_cli.physics.sampling import cosine_around, rand, seed_state, uniform_sphere
from pbvol_cli.pointbased.beams import Beams, beam_segments, layer_reflectance, slab_reflectance
from pbvol_cli.pointbased.gather import eval_segments, segment_planes
from pbvol_cli.pointbased.surface_samples import BOUNDARY_STREAM, SHARING_RADIUS, poisson_disk, share_among_neighbours
from pbvol_cli.pointbased.volume_samples import SAMPLE_KEYS, scattered_share
from pbvol_cli.render.interfaces import indices


# single scattering of the bounced beams: a disc of this many times the boundary point's radius (narrower, a few
# strong beams made single-pixel outliers: docs/pbl.md)
BOUNCED_KERNEL = 3.0
MIN_SHARE = 0.01  # generations stop once one scatters less than this share of the lights' samples' power
TAIL_RATIO_MAX = 0.9  # generation-to-generation ratio the tail is extrapolated with at most


def boundary_points(bs: BuiltScene, medium: int, count: int, seed: int, generation: int = 0):
    """About `count` blue-noise points on the surfaces bounding `medium`, a set of its own for each generation.
    Returns (positions, inward normals, surface ids, area per point (scene units^2), the points' minimum distance,
    geometric normals (exterior)); empty when no dielectric surface bounds it."""
    surf = bs.surfaces
    ids = _reflecting_surfaces(bs, medium)
    if len(ids) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64), 0.0, 0.0, np.zeros((0, 3))
    tri = np.isin(bs.tri_surface, ids)
    sph = bs.spheres[np.isin(bs.spheres[:, SPH_SURFACE].astype(np.int64), ids)]
    # streams apart from the light samples' and from the generation before, whose beams leave from its points: on
    # one stream each point gathered beside a beam's entry, and a dense body's arriving light read 14x too high
    pos, nrm, sid, area, radius, gnrm = poisson_disk(bs.vertices, bs.faces[tri], bs.tri_normals[tri],
                                                     bs.tri_surface[tri], sph, count, seed, 8,
                                                     BOUNDARY_STREAM + generation, geometric=True)
    inward = np.where((surf[sid, SURF_MEDIUM_IN] == medium)[:, None], -nrm, nrm)  # normals point to the exterior
    return pos, inward, sid, area, radius, gnrm


def _reflecting_surfaces(bs: BuiltScene, medium: int) -> np.ndarray:
    """The dielectric surfaces bounding `medium` (their rows)."""
    return np.flatnonzero(bs.surfaces_bounding(medium) & (bs.surfaces[:, SURF_TYPE] == DIELECTRIC)).astype(np.int64)


SOURCE_LIST = 4096  # sources, drawn by scattered power, that the near-source boundary points are shot from


def source_list(sets: list, seed: int, generation: int) -> np.ndarray:
    """SOURCE_LIST points (M, 3) drawn with replacement, by scattered power (all channels), from the volume
    samples of `sets` (SampleSets): their segments' centres, inside the medium."""
    centre = np.concatenate([d.kernel.centre for d in sets])
    weight = np.concatenate([d.scat.sum(axis=1) for d in sets])
    cum = np.cumsum(weight)
    if len(cum) == 0 or cum[-1] <= 0:
        return np.zeros((0, 3))
    u = np.random.default_rng([seed, 0xB5, generation]).random(SOURCE_LIST) * cum[-1]
    return np.ascontiguousarray(centre[np.minimum(np.searchsorted(cum, u, side="right"), len(cum) - 1)])


@njit(parallel=True, cache=True)
def _shot_rays(src, seed, stream, origins, dirs):
    """Ray k: from a source of the list chosen uniformly, in a direction uniform over the sphere."""
    for k in prange(origins.shape[0]):
        st = np.empty(1, np.uint64)
        st[0] = seed_state(seed, stream, k)
        i = min(int(rand(st, 0) * src.shape[0]), src.shape[0] - 1)
        d = uniform_sphere(rand(st, 0), rand(st, 0))
        for c in range(3):
            origins[k, c] = src[i, c]
            dirs[k, c] = d[c]


def near_source_points(bs: BuiltScene, caster, medium: int, src: np.ndarray, attempts: int, seed: int,
                       generation: int):
    """The boundary points that `attempts` rays from the sources `src` (source_list) meet first, where they meet a
    dielectric surface bounding a convex `medium`: the light arriving at the boundary is peaked next to the
    sources near it, which blue-noise points tens of mean free paths apart seldom see (docs/pbl.md, section 8).
    Returns (positions, inward shading normals, surface ids, geometric normals (exterior))."""
    origins, dirs = np.zeros((attempts, 3)), np.zeros((attempts, 3))
    _shot_rays(src, seed, 0xB600 + generation, origins, dirs)
    t, sid, ng, ns = closest_surface_hits(caster, bs, origins, dirs)
    hit = np.flatnonzero(np.isfinite(t) & np.isin(sid, _reflecting_surfaces(bs, medium)))
    pos = origins[hit] + t[hit, None] * dirs[hit]
    sid = sid[hit]
    inward = np.where((bs.surfaces[sid, SURF_MEDIUM_IN] == medium)[:, None], -ns[hit], ns[hit])
    return pos, inward, sid, ng[hit]


@njit(parallel=True, cache=True)
def source_density(pos, gnrm, src, out):
    """out[j]: the density (1/scene units^2) of the near-source points at boundary point j, the mean over the
    sources of cos(theta_j) / (4 pi r^2): a direction uniform over the sphere from a source inside a convex body
    meets its boundary once."""
    for j in prange(pos.shape[0]):
        acc = 0.0
        for i in range(src.shape[0]):
            d0, d1, d2 = pos[j, 0] - src[i, 0], pos[j, 1] - src[i, 1], pos[j, 2] - src[i, 2]
            r2 = max(d0 * d0 + d1 * d1 + d2 * d2, 1e-300)
            acc += abs(d0 * gnrm[j, 0] + d1 * gnrm[j, 1] + d2 * gnrm[j, 2]) / (4.0 * math.pi * r2 * math.sqrt(r2))
        out[j] = acc / max(src.shape[0], 1)


def gather_points(bs: BuiltScene, caster, medium: int, count: int, seed: int, generation: int, sets: list,
                  near_share: float):
    """The boundary points of one generation's gather: blue noise over the boundary and, for a convex medium, a
    share `near_share` of `count` shot from the sources of `sets` (near_source_points), the two combined by the
    balance heuristic: point j's area is 1 / (n_blue / A + n_shot p_src(x_j)), A the boundary's area.
    Returns (positions, inward normals, surface ids, areas in scene units^2 (n,), or one for all blue noise, the
    spacing of `count` blue-noise points, the area a point has among `count` blue-noise ones)."""
    shots = int(round(near_share * count)) if near_share > 0 else 0
    pos, nin, sid, area, spacing, gnrm = boundary_points(bs, medium, max(count - shots, 1), seed, generation)
    n_blue = len(pos)
    if n_blue == 0:
        return pos, nin, sid, np.zeros(0), 0.0, 0.0
    src = source_list(sets, seed, generation) if shots else np.zeros((0, 3))
    if len(src) == 0:
        return pos, nin, sid, area, spacing, area
    total = area * n_blue
    # the points' spacing and area as if all `count` were blue noise: the sharing radius and the beams' width
    spacing *= math.sqrt(n_blue / count)
    p2, n2, s2, g2 = near_source_points(bs, caster, medium, src, shots, seed, generation)
    pos, nin, sid, gnrm = (np.concatenate(a) for a in ((pos, p2), (nin, n2), (sid, s2), (gnrm, g2)))
    density = np.zeros(len(pos))
    source_density(pos, gnrm, src, density)
    return pos, nin, sid, 1.0 / (n_blue / total + shots * density), spacing, total / count


@njit(parallel=True, cache=True)
def _reflected_beams(surfaces, medium, pos, nin, sid, w, q, L, area, eps, R2, bpos, bdir, bpow):
    """Beam j: from x_j along the mirror image of the arriving light's direction (-w), power pi F L A_j q_j
    (area[j]; F with the glass wall behind the boundary, if any: slab_reflectance; q_j: 1 / w's density over the
    cosine density)."""
    for j in prange(pos.shape[0]):
        s = sid[j]
        inside_is_interior = surfaces[s, SURF_MEDIUM_IN] == medium
        eta_i, eta_t = indices(surfaces, s, not inside_is_interior)
        c = w[j, 0] * nin[j, 0] + w[j, 1] * nin[j, 1] + w[j, 2] * nin[j, 2]
        F = slab_reflectance(fresnel_dielectric(max(c, 1e-9), eta_t / eta_i)[0], R2[j]) if c > 0.0 else 0.0
        for k in range(3):
            # the light travels along -w; mirrored: -w + 2 (w . n) n, into the medium
            bdir[j, k] = -w[j, k] + 2.0 * c * nin[j, k]
            bpos[j, k] = pos[j, k] + eps * nin[j, k]
            bpow[j, k] = math.pi * F * L[j, k] * area[j] * q[j]


REFLECTION_MIX = 0.02  # the least share of the gather directions drawn by cos alone (where the reflectance toward
# the outside underestimates the boundary's, a glass wall's for one, they keep every direction sampled)
THIN_SCALE = 1.5  # mean free paths of half-thickness (the thinnest channel's) over which the directions turn to cos
REFLECTANCE_BINS = 1024  # bins in sin^2 of the angle to the normal of the reflectance tables
MIN_MEAN_REFLECTANCE = 1e-3  # below this (an index-matched side) the directions are drawn by cos alone


def reflectance_tables(bs: BuiltScene, medium: int, sid: np.ndarray):
    """For the boundary points on the surfaces sid, the reflectance toward the outside by which their gather
    directions are drawn: the Fresnel reflectance from the medium's side (its index) into vacuum, the law of total
    internal reflection that a glass wall between keeps. Returns (each point's table (n,), the tables' values over
    REFLECTANCE_BINS bins of u = sin^2 theta (m, K), their cumulative sums normalised (m, K + 1), their means
    (m,): the hemispherical reflectance, cos-weighted)."""
    surf = bs.surfaces
    inside = surf[sid, SURF_MEDIUM_IN] == medium
    n_med = np.where(inside, surf[sid, SURF_ETA_IN], surf[sid, SURF_ETA_OUT])
    etas, which = np.unique(n_med, return_inverse=True)
    K = REFLECTANCE_BINS
    mu = np.sqrt(1.0 - (np.arange(K) + 0.5) / K)
    f = np.array([[fresnel_dielectric(m, 1.0 / e)[0] for m in mu] for e in etas]).reshape(len(etas), K)
    total = f.sum(axis=1)
    cdf = np.concatenate([np.zeros((len(etas), 1)), np.cumsum(f, axis=1) / np.maximum(total, 1e-300)[:, None]],
                         axis=1)
    return which.astype(np.int64), f, cdf, total / K


def cosine_share(side: float | None, sigma_t: np.ndarray) -> float:
    """The share of a medium's gather directions drawn by cos alone, the rest by the reflectance: REFLECTION_MIX in
    an optically thin body, rising to 1 as tau, its half-thickness in mean free paths of its thinnest channel, grows:
    1 - (1 - REFLECTION_MIX) exp(-(tau / THIN_SCALE)^2). side: the body's smallest side (scene units; None: no
    bounding box, taken as thin); sigma_t (3,): its extinction (1/scene unit). Where a reflected beam scatters
    within a fraction of the body its direction matters little, while the estimators read the sources that the
    trapped beams leave a fraction of a mean free path under the boundary low: drawn by the reflectance, a
    non-absorbing sphere 7.7 mean free paths in radius read 0.93 of its furnace's 1 (1.01 by cos) and the milk
    glass's bounced light was 10 % lower (docs/pbl.md, section 12, "The bumpy sphere's red rim")."""
    if side is None:
        return REFLECTION_MIX
    tau = float(np.min(sigma_t)) * 0.5 * side
    by_reflectance = (1.0 - REFLECTION_MIX) * math.exp(-((tau / THIN_SCALE) ** 2))
    return 1.0 if by_reflectance < 1e-3 else 1.0 - by_reflectance  # (1: the cosine draws' own random stream)


@njit(parallel=True, cache=True)
def gather_directions(nin, table, f, cdf, fmean, mix, seed, stream, out, q, rng):
    """A direction into the medium from each boundary point (its own random stream, left in rng): with
    probability `mix` cosine-weighted, else by cos x its table's reflectance (reflectance_tables); q[j] is 1 / its
    density over the cosine density."""
    K = f.shape[1]
    for j in prange(nin.shape[0]):
        st = np.empty(1, np.uint64)
        st[0] = seed_state(seed, stream, j)
        k = table[j]
        m = mix if fmean[k] > MIN_MEAN_REFLECTANCE else 1.0
        u0 = rand(st, 0) if m < 1.0 else 0.0  # (by cos alone: the same stream as the cosine draws always took)
        u1, u2 = rand(st, 0), rand(st, 0)
        u = u1  # sin^2 theta: uniform under the cosine density
        if u0 >= m:
            lo, hi = 0, K  # the bin b with cdf[b] <= u1 < cdf[b + 1]
            while hi - lo > 1:
                mid = (lo + hi) // 2
                if cdf[k, mid] <= u1:
                    lo = mid
                else:
                    hi = mid
            width = cdf[k, lo + 1] - cdf[k, lo]
            u = (lo + ((u1 - cdf[k, lo]) / width if width > 0.0 else 0.5)) / K
        b = min(int(u * K), K - 1)
        q[j] = 1.0 / (m + (1.0 - m) * f[k, b] / fmean[k]) if m < 1.0 else 1.0
        out[j, 0], out[j, 1], out[j, 2] = cosine_around(u, u2, nin[j, 0], nin[j, 1], nin[j, 2])
        rng[j] = st[0]


def reflected_beams(bs: BuiltScene, caster, medium: int, pos, nin, sid, w, q, L, area, spacing: float):
    """The beams the boundary points x_j (pos, inward normals nin, surface ids sid, area (scene units^2, one or per
    point), minimum distance `spacing`) reflect of the radiance L (n, 3) arriving from the directions w (n, 3, drawn
    by gather_directions, q its weights): each from x_j along the mirror image of -w, its power pi F L A_j q_j
    shared among its neighbours (share_among_neighbours). Returns (positions, directions, powers, the powers' robust
    total before the sharing spreads a spike over its neighbours)."""
    n = len(pos)
    bpos, bdir, bpow = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    # the glass wall behind the boundary, seen by the light leaving along -w from just inside x_j
    inner = pos + bs.eps * nin
    t0, s0, ng0, ns0 = closest_surface_hits(caster, bs, inner, -w)
    R2 = layer_reflectance(caster, bs, inner, -w, t0, s0, ng0, ns0)
    _reflected_beams(bs.surfaces, medium, pos, nin, sid, w, q, L, np.broadcast_to(area, n).copy(), bs.eps, R2, bpos,
                     bdir, bpow)
    rob = robust_total(bpow)
    shared = np.zeros_like(bpow)
    share_among_neighbours(pos, bpow, SHARING_RADIUS * spacing, shared)
    return bpos, bdir, shared, rob


ROBUST_QUANTILE = 0.99  # the tail's ratio clips each boundary point's reflected power at this quantile


def robust_total(power: np.ndarray) -> np.ndarray:
    """Per channel, the sum of the points' powers (n, 3) clipped at their ROBUST_QUANTILE: rare single-point
    spikes do not move it."""
    live = power[power.max(axis=1) > 0]
    if len(live) == 0:
        return np.zeros(power.shape[1])
    cap = np.quantile(live, ROBUST_QUANTILE, axis=0)
    return np.minimum(live, cap[None, :]).sum(axis=0)


def arrival_bound(L: np.ndarray, area, scattered: np.ndarray) -> np.ndarray:
    """Per channel, the factor (<= 1) that keeps the flux the gather says arrives at the boundary from inside,
    sum_j pi L_j A_j (radiance L_j (n, 3) along a direction drawn by the cosine density, or weighted as if it were,
    at points of area A_j: `area`, (n,) or one for all), within the power the sources scattered (3,): scattered
    light is absorbed or reaches the boundary, so no more
    can arrive. The estimators break this bound where the table's images are poor, most near the boundary of an
    optically thick, high-albedo body (a marble sphere 270 mean free paths across: a generation's light arriving
    6-13x what it scattered), and a generation-to-generation ratio above 1 then grows without bound (docs/pbl.md)."""
    arriving = np.pi * area * L.sum(axis=0) if np.ndim(area) == 0 else np.pi * (area[:, None] * L).sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(arriving > scattered, scattered / arriving, 1.0)


def bounced_samples(bs: BuiltScene, caster, pool, threads: int, medium: int, source, make_set, count: int,
                    generations: int, segments: int, max_reflections: int, settings, seed: int, extra=None,
                    near_share: float = 0.0):
    """Volume samples of the light scattered in `medium` and reflected by its boundary, `generations` times.

    source: the medium's SampleSet of the lights' volume samples; extra: another SampleSet whose scattered light
    the first generation gathers too (the light the scene sent back: volume_samples.returned_samples), or None;
    make_set(samples) builds one from a namespace of v_* arrays; settings: the gather rays' GatherSettings;
    near_share: the share of the `count` boundary points shot from the sources (gather_points; a convex medium
    only, else 0). Returns the union of the generations as such a namespace, or None when the boundary reflects
    nothing."""
    med = source.medium  # (with the flat faces of its boundary)
    mix = cosine_share(bs.medium_side(medium), med.sigma_a + med.sigma_s)
    gens, emitted, robust = [], [], []
    data = source
    for g in range(generations):
        sources = [data] if g > 0 or extra is None else [data, extra]
        pos, nin, sid, area, spacing, width = gather_points(bs, caster, medium, count, seed, g, sources, near_share)
        n = len(pos)
        if n == 0:
            return None
        w, q, rng = np.zeros((n, 3)), np.zeros(n), np.zeros(n, np.uint64)
        gather_directions(nin, *reflectance_tables(bs, medium, sid), mix, seed, 0xB0 + 4 * g, w, q, rng)
        t, _, ng, _ = closest_surface_hits(caster, bs, pos + bs.eps * nin, w)
        ok = np.flatnonzero(np.isfinite(t))
        L = np.zeros((n, 3))
        planes = segment_planes(pos + bs.eps * nin, w, t, nin, ng)
        for d in sources:
            out = np.zeros((n, 3, 3))
            eval_segments(pool, threads, ok, pos + bs.eps * nin, w, np.ones((n, 3)), np.where(np.isfinite(t), t, 0.0),
                          rng.copy(), med, d.kernel, settings, out, np.zeros(n, np.int64), planes)
            L += out.sum(axis=1)
        L *= arrival_bound(L * q[:, None], area, sum(d.scat.sum(axis=0) for d in sources))[None, :]
        bpos, bdir, bpow, rob = reflected_beams(bs, caster, medium, pos, nin, sid, w, q, L, area, spacing)
        live = np.flatnonzero(bpow.max(axis=1) > 0)
        if len(live) == 0:
            break
        beams = Beams(bpos[live], bdir[live], bpow[live], np.full(len(live), medium, np.int64),
                      np.full(len(live), width), nin[live].copy())
        seg = beam_segments(caster, bs, beams, segments, max_reflections,
                            seed + 7919 * (g + 1))
        gen = SimpleNamespace(**{f"v_{k}": v for k, v in seg.items()})
        gens.append(gen)
        emitted.append(bpow[live].sum(axis=0))
        robust.append(rob)
        if g + 1 < generations:
            data = make_set(gen)
            if scattered_share(source, data) < MIN_SHARE:
                break  # too little to follow further (a liquid whose boundary hardly reflects)
    if not gens:
        return None
    if len(gens) >= 2:
        # the generations after the last: a geometric tail at the last ratio of emitted powers (the later
        # generations converge to the boundary's slowest-decaying pattern), carried by the last generation. The
        # ratio is taken from robust totals: one gather ray that meets a bounced beam head-on (peaked phase,
        # g = 0.9) makes a point reflect tens of times more than any other, and the raw ratio would let the tail
        # multiply that spike by up to 1 / (1 - TAIL_RATIO_MAX) = 10
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.clip(np.nan_to_num(robust[-1] / robust[-2]), 0.0, TAIL_RATIO_MAX)
        gens[-1].v_power = gens[-1].v_power / (1.0 - r)[None, :]
    return SimpleNamespace(**{k: np.concatenate([getattr(x, k) for x in gens]) for k in SAMPLE_KEYS})
