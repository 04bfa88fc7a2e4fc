"""The medium's in-scattered light gathered along ray segments inside it (Wang et al. 2016, sec. 3.6, eq. 9).

A segment of length d_max in a medium gets k points at stratified depths d_k = -log(1 - u_k (1 - e^(-s d_max))) / s
(s: the medium's smallest sigma_t, u_k = (k + xi) / k), weighted per channel by e^(-sigma_t d_k) / (pdf(d_k) k): the
transmittance toward the segment's start is in the weight. At each point the light samples' single, double and
multiple scattering toward the segment's start (estimators: single_scattering.py, light_cut.py). Used by the
camera paths (camera_pass.py) and by the bounced light's gather rays (bounced.py).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit

from pbvol_cli.physics.sampling import points_on_segment, rand, stratified_depth
from pbvol_cli.pointbased.light_cut import MULTIPLE_CUT_SHARE, double_multiple
from pbvol_cli.pointbased.radiance_cache import CacheSettings, scattered_points, shared_terms
from pbvol_cli.pointbased.single_scattering import single_scattering_at_points, single_scattering
from pbvol_cli.pointbased.volume_samples import ENTRY_N, ENTRY_Q, EXIT_N, EXIT_Q, PLANE_COLS, Query, nearer_plane

GatherSettings = namedtuple("GatherSettings", ["kmax", "cut_size", "clamp", "single", "double", "multiple",
                                               "kmax_scattered", "kmax_diffuse", "cut_size_diffuse", "cut_roulette"],
                            defaults=(0.0,))
GatherSettings.__doc__ = """How a segment is evaluated: kmax points for single scattering, kmax_scattered for double
and multiple (smooth along a ray), kmax_diffuse random points for every term after a diffuse bounce; the light cut's
cut_size refinements (cut_size_diffuse after a diffuse bounce), its clamp (scene units) and the share of its
importance below which a node is played by roulette (cut_roulette, light_cut._cut_estimate; 0: none); which terms
(single, double, multiple: bools)."""
LAYER_SINGLE, LAYER_DOUBLE, LAYER_MULTIPLE = 0, 1, 2  # out[ray, layer, channel]


def gather_settings(pbl, terms=("single", "double", "multiple")) -> GatherSettings:
    """The camera paths' settings from a scene's [render.pbl] (config.PblSettings), for the given terms."""
    return GatherSettings(pbl.kmax, pbl.cut_size, pbl.clamp, "single" in terms, "double" in terms,
                          "multiple" in terms, pbl.kmax_scattered, pbl.kmax_diffuse, pbl.cut_size_diffuse,
                          float(pbl.cut_roulette))


@njit(cache=True)
def _segment(i, pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse, planes):
    """The medium's light along ray i over [0, tseg[i]], times beta[i], into out[i, layer, channel]. A ray after a
    diffuse bounce (diffuse[i] > 0) takes settings.kmax_diffuse random points for every term (sec. 3.6: averaged
    over the bounces), its double scattering with a light cut of settings.cut_size_diffuse refinements: such a
    point's spread comes from its random depth and cosine-drawn direction more than from the cut (docs/pbl.md,
    section 9). planes[i]: the boundary's tangent planes where the segment starts and ends (segment_planes), the
    nearer of which is each point's for the multiple term's image."""
    sig_a, sig_s = med.sigma_a, med.sigma_s
    kmax, k2 = settings.kmax, settings.kmax_scattered
    cut = settings.cut_size_diffuse if diffuse[i] > 0 else settings.cut_size
    do_s, do_d, do_m = settings.single, settings.double, settings.multiple
    dmax = tseg[i]
    s = min(sig_a[0] + sig_s[0], min(sig_a[1] + sig_s[1], sig_a[2] + sig_s[2]))
    frac = -math.expm1(-s * dmax) if s > 0.0 else 1.0
    o = np.zeros(3)
    o3 = np.zeros(3)
    wx, wy, wz = -dirs[i, 0], -dirs[i, 1], -dirs[i, 2]
    xi = rand(rng, i)
    pplane = np.empty(4)
    # single scattering at kmax points; double and multiple (smooth along the ray) at their own k2 points
    for comp in range(2):
        n = kmax if comp == 0 else points_on_segment(k2, s, dmax)
        if diffuse[i] > 0:
            n = settings.kmax_diffuse
        if (comp == 0 and not do_s) or (comp == 1 and not (do_d or do_m)):
            continue
        for k in range(n):
            d, pdf = stratified_depth(k, n, xi, s, dmax, frac)
            px, py, pz = pos[i, 0] + d * dirs[i, 0], pos[i, 1] + d * dirs[i, 1], pos[i, 2] + d * dirs[i, 2]
            o[:] = 0.0
            o3[:] = 0.0
            if comp == 0:
                single_scattering(vs, med, Query(px, py, pz, wx, wy, wz, pplane), o)
            else:
                e = nearer_plane(planes, i, px, py, pz)
                for c in range(4):
                    pplane[c] = planes[i, e + c]
                double_multiple(vs, med, Query(px, py, pz, wx, wy, wz, pplane), cut, settings.clamp,
                                do_d, do_m, o, o3, rng, i, settings.cut_size // MULTIPLE_CUT_SHARE,
                                settings.cut_roulette)
            for c in range(3):
                w = beta[i, c] * math.exp(-(sig_a[c] + sig_s[c]) * d) / (pdf * n)
                if comp == 0:
                    out[i, LAYER_SINGLE, c] += w * o[c]
                else:
                    out[i, LAYER_DOUBLE, c] += w * o[c]
                    out[i, LAYER_MULTIPLE, c] += w * o3[c]


@njit(nogil=True, cache=True)
def _eval_segments(idx, pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse, planes):
    for k in range(idx.shape[0]):
        _segment(idx[k], pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse, planes)


def eval_segments(pool, threads, idx, pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse, planes,
                  cache: CacheSettings | None = None, bin_rng=None, term_shares=None, diffuse_share: float = 1.0,
                  deferred=None):
    """_segment for the rays idx: med (Medium), vs (VolumeSamples), settings (GatherSettings), out (n, 3, 3).
    With cache (CacheSettings, cell > 0) and bin_rng, the smooth terms of the rays that did not bounce off a diffuse
    surface are shared among the points of a bin (radiance_cache.shared_terms, with term_shares: a
    radiance_cache.TermShares, how often a bin evaluates each term) instead, and those of the rays after a diffuse
    bounce are evaluated on a share diffuse_share of them (camera_pass.DiffuseShare), weighted by its inverse.
    deferred(idx, pos, dirs, beta, tseg, rng, planes), when given, takes those shared terms' segments instead, to
    bin them with others (radiance_cache.DeferredBins.add); out then holds only the other terms.

    Numba's parallel loops reject the nested tuples (the octree, the tables): threads over slices instead, the
    kernel releasing the GIL. Rays are independent, so the result does not depend on the split."""
    after_diffuse = diffuse[idx] > 0  # every term at kmax_diffuse random points, as before
    direct = idx[~after_diffuse]
    if cache is None or not cache.cell > 0.0 or not (settings.double or settings.multiple or cache.single):
        if settings.double or settings.multiple or not settings.single:
            _on_threads(pool, threads, idx, pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse, planes)
        else:  # single scattering alone (the camera paths take it apart from the smooth terms)
            _on_threads(pool, threads, idx[after_diffuse], pos, dirs, beta, tseg, rng, med, vs, settings, out,
                        diffuse, planes)
            single_along_segments(pool, threads, direct, pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse,
                                  planes)
        return
    _after_diffuse(pool, threads, idx[after_diffuse], pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse,
                   planes, term_shares, bin_rng, diffuse_share)
    if settings.single and not cache.single:
        single_along_segments(pool, threads, direct, pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse,
                              planes)
    if deferred is not None:
        deferred(direct, pos, dirs, beta, tseg, rng, planes)
        return
    shared_terms(pool, threads, direct, pos, dirs, beta, tseg, rng, med, vs, settings, cache, out, planes, bin_rng,
                 term_shares)


def _after_diffuse(pool, threads, idx, pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse, planes,
                   term_shares, bin_rng, share: float = 1.0):
    """Every term of the rays idx after a diffuse bounce, point by point (_segment), on a share `share` of the rays
    (the others none: a Russian roulette, bin_rng drawing which), weighted by its inverse, and among those double
    and multiple each on the pass's share (term_shares: radiance_cache.TermShares, as measured on the bins; None:
    all), weighted by its inverse."""
    if share < 1.0 and len(idx):
        kept = idx[bin_rng.random(len(idx)) < share]
        prior = out[kept].copy()  # (what the rows held: only the new terms are scaled)
        _after_diffuse_terms(pool, threads, kept, pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse, planes,
                             term_shares, bin_rng)
        out[kept] = prior + (out[kept] - prior) / share
        return
    _after_diffuse_terms(pool, threads, idx, pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse, planes,
                         term_shares, bin_rng)


def _after_diffuse_terms(pool, threads, idx, pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse, planes,
                         term_shares, bin_rng):
    """_after_diffuse's terms of the rays idx."""
    q_d, q_m = term_shares.shares() if term_shares is not None and settings.double and settings.multiple \
        else (1.0, 1.0)
    if (q_d == 1.0 and q_m == 1.0) or len(idx) == 0:
        _on_threads(pool, threads, idx, pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse, planes)
        return
    u = bin_rng.random((len(idx), 2))
    keep_d, keep_m = u[:, 0] < q_d, u[:, 1] < q_m
    for kd, km in ((True, True), (True, False), (False, True), (False, False)):
        part = settings._replace(double=kd, multiple=km)
        sel = idx[(keep_d == kd) & (keep_m == km)]
        if len(sel) == 0 or not (kd or km or part.single):
            continue
        prior = out[sel, LAYER_DOUBLE:LAYER_MULTIPLE + 1].copy()  # (what the rows held: only the new share is scaled)
        _on_threads(pool, threads, sel, pos, dirs, beta, tseg, rng, med, vs, part, out, diffuse, planes)
        out[sel, LAYER_DOUBLE] = prior[:, 0] + (out[sel, LAYER_DOUBLE] - prior[:, 0]) / q_d
        out[sel, LAYER_MULTIPLE] = prior[:, 1] + (out[sel, LAYER_MULTIPLE] - prior[:, 1]) / q_m


def single_along_segments(pool, threads, idx, pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse, planes):
    """Single scattering of the rays idx (none after a diffuse bounce) at _segment's kmax points, into out: the
    same points and sums as _segment's, taken the cheaper way (single_scattering.single_scattering_at_points)."""
    if len(idx) == 0:
        return
    pts = scattered_points(idx, pos, dirs, beta, tseg, rng, med, settings.kmax, planes)
    s1 = single_scattering_at_points(pool, threads, vs, med, pts.pos, pts.dir, morton_order)
    _add_single(pts.owner, pts.weight, s1, out)


@njit(cache=True)
def _add_single(owner, weight, s1, out):
    """out[owner[j], LAYER_SINGLE] += weight[j] s1[j], in the points' order (a segment's points in _segment's)."""
    for j in range(owner.shape[0]):
        for c in range(3):
            out[owner[j], LAYER_SINGLE, c] += weight[j, c] * s1[j, c]


DEFERRED_POINTS = 1 << 17  # points a DeferredSingle holds before it evaluates them (10 MB of them): a 512 x 512
# oil-sphere render of two passes peaked at 916-929 MiB, at 937-949 with 1 << 18 and 956-962 with 1 << 19 (one flush
# a pass), taking a twentieth less time; a 256 x 256 pass (95 000 points) is one flush either way


class DeferredSingle:
    """The single scattering of camera paths, its points drawn segment by segment as the paths go
    (scattered_points: the segment's random number drawn then, as _segment draws it) and evaluated together later
    (flush): one evaluation of many points, where each depth of the paths, or each batch of them, was one of fewer.
    Sample by sample a flush costs a pass over the volume samples and the grid cells of their kernels, however few
    the points: a pass at 512 x 512, four camera batches, took 3.5 s of single scattering flushed at every batch's
    end, 2.8 s in one flush (benchmarks/pbl_profile.py --resolution 512 --spp 1)."""

    def __init__(self):
        self.parts = {}  # medium -> (VolumeSamples, Medium, [(positions, directions, weights, pixels)])
        self.count = 0  # the points held

    def full(self) -> bool:
        """Whether it holds DEFERRED_POINTS points or more (the caller flushes it: memory stays bounded)."""
        return self.count >= DEFERRED_POINTS

    def add(self, m: int, vs, med, idx, pos, dirs, beta, tseg, rng, kmax: int, planes, pixel):
        """The kmax points of each segment idx in medium m (as _segment draws them: kmax_diffuse after a diffuse
        bounce), for pixels pixel[idx]."""
        if len(idx) == 0:
            return
        pts = scattered_points(idx, pos, dirs, beta, tseg, rng, med, kmax, planes)
        self.parts.setdefault(m, (vs, med, []))[2].append((pts.pos, pts.dir, pts.weight, pixel[pts.owner]))
        self.count += len(pts.owner)

    def flush(self, pool, threads, layer, npix: int):
        """Adds the points' single scattering times their weights into layer (npix, 3), per pixel."""
        parts, self.parts, self.count = self.parts, {}, 0
        for vs, med, chunks in parts.values():
            pos, wdir, weight, pixel = (np.concatenate([c[k] for c in chunks]) for k in range(4))
            chunks.clear()  # (their memory freed before the evaluation's)
            value = single_scattering_at_points(pool, threads, vs, med, pos, wdir, morton_order)
            value *= weight
            for ch in range(3):
                layer[:, ch] += np.bincount(pixel, weights=value[:, ch], minlength=npix)


def _spread_bits(v):
    """10-bit integers -> their bits spaced three apart (one axis of a Morton code)."""
    v = v.astype(np.uint64) & np.uint64(0x3FF)
    for shift, mask in ((16, 0xFF0000FF), (8, 0x0F00F00F), (4, 0xC30C30C3), (2, 0x49249249)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def morton_order(points):
    """The permutation of points (m, 3) along a Morton curve (a 1024^3 grid over their box): neighbours in space
    become neighbours in the order, so the octree's nodes and samples their walks read stay in cache."""
    finite = np.isfinite(points).all(axis=1)  # a point at infinity (an unbounded segment's) takes the first cell
    if len(points) < 2 or not finite.any():
        return np.arange(len(points))
    lo, hi = points[finite].min(axis=0), points[finite].max(axis=0)
    cell = np.where(finite[:, None], (points - lo) / np.maximum(hi - lo, 1e-30) * 1023.0, 0.0)
    q = np.clip(cell, 0.0, 1023.0).astype(np.int64)
    code = _spread_bits(q[:, 0]) | (_spread_bits(q[:, 1]) << np.uint64(1)) | (_spread_bits(q[:, 2]) << np.uint64(2))
    return np.argsort(code, kind="stable")


def spatial_order(idx, pos, dirs, tseg):
    """idx reordered along a Morton curve through its segments' midpoints (morton_order). Each ray's terms are its
    own, so the order changes no value."""
    if len(idx) < 2:
        return idx
    mid = pos[idx] + 0.5 * np.where(np.isfinite(tseg[idx]), tseg[idx], 0.0)[:, None] * dirs[idx]
    return idx[morton_order(mid)]


def _on_threads(pool, threads, idx, pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse, planes):
    idx = spatial_order(idx, pos, dirs, tseg)
    if threads <= 1 or len(idx) < 64:
        _eval_segments(np.ascontiguousarray(idx), pos, dirs, beta, tseg, rng, med, vs, settings, out, diffuse, planes)
        return
    # interleaved slices balance rays of different cost (copied: one array layout, one compiled kernel)
    list(pool.map(lambda j: _eval_segments(np.ascontiguousarray(idx[j::threads]), pos, dirs, beta, tseg, rng, med,
                                           vs, settings, out, diffuse, planes), range(threads)))


def segment_planes(pos, dirs, t, n_start, n_end):
    """(n, PLANE_COLS): the tangent planes n . x = q where each segment (from pos along dirs for t) starts and ends,
    normals oriented out of the segment's side (n_start . d < 0, n_end . d > 0), from the surfaces' normals there
    (NaN or an infinite t: no plane, q = inf). The multiple term mirrors its sources in the nearer one of each
    point."""
    out = np.zeros((len(pos), PLANE_COLS))
    out[:, ENTRY_N + 2] = out[:, EXIT_N + 2] = 1.0
    out[:, ENTRY_Q] = out[:, EXIT_Q] = np.inf
    end = pos + np.where(np.isfinite(t), t, 0.0)[:, None] * dirs
    for col, nrm, x, sgn in ((ENTRY_N, n_start, pos, -1.0), (EXIT_N, n_end, end, 1.0)):
        if nrm is None:
            continue
        cos = np.einsum("ij,ij->i", nrm, dirs)
        ok = np.isfinite(cos) & (cos != 0.0) & (np.isfinite(t) if col == EXIT_N else True)
        n = nrm[ok] * (sgn * np.sign(cos[ok]))[:, None]
        out[ok, col:col + 3] = n
        out[ok, col + 3] = np.einsum("ij,ij->i", n, x[ok])
    return out
