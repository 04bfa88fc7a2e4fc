"""The smooth terms evaluated once per cell and direction bin and shared by the camera points in them.

Double and multiple scattering (and the bounced light) vary over a mean free path and more, while a pass asks for
them at tens of thousands of camera points a fraction of that apart. The points of a pass (DeferredBins: all its
camera batches and path depths together, where each batch and depth had bins of its own) are binned by
position (cubes of `cell` mean free paths of the medium's densest channel) and by direction (a cube map of
`directions` x `directions` bins per face); each occupied bin is evaluated once, at one of its points drawn in
proportion to its weight, and that radiance serves every point of the bin, each with its own weight (path
throughput, transmittance, pdf): the bin's total is unbiased. The grid is shifted and the cube map turned at random
in every evaluation, so that over passes the bins' edges average out: the image converges to the terms blurred over
about a cell, not to a blocky one.

Why this pays: a point's estimate of these terms is already noisy (the light cut is stochastic), and a pixel that
borrows its neighbour's estimate has the same noise as with its own; the work falls by the points per bin.
tests/pointbased/test_radiance_cache.py measures the blur against the per-point evaluation.

Double and multiple scattering cost about the same at a bin, but one often carries far less light than the other
(the oil's multiple scattering, the wax's double): the lesser is then evaluated at a random share of the bins,
weighted by its inverse (TermShares), unbiased; the points after a diffuse bounce, evaluated one by one, take the
same shares (gather._after_diffuse).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit

from pbvol_cli.physics.sampling import points_on_segment, rand, stratified_depth
from pbvol_cli.pointbased.light_cut import double_multiple
from pbvol_cli.pointbased.single_scattering import single_scattering
from pbvol_cli.pointbased.volume_samples import Query, nearer_plane

CacheSettings = namedtuple("CacheSettings", ["cell", "lateral", "directions", "single"])
CacheSettings.__doc__ = """Sharing of the smooth terms: bins `cell` mean free paths (the medium's densest channel; 0:
every point evaluates its own) deep below the boundary and `lateral` mean free paths wide (at most SIZE_SHARE of
the medium's size), `directions` bins per cube-map face, and whether single scattering is shared too (the bounced
light's: smooth; the lights' own single scattering never is)."""

SIZE_SHARE = 0.125  # bins at most this share of the medium's size wide: the light's gradient across a body is
# linear over such a width, which a box blur keeps (1 and 2 mean free paths on a sphere 4 across blurred double
# scattering above the noise: tests/pointbased/test_radiance_cache.py)


TERM_SHARE_MIN = 0.125  # the least share of the bins at which a term is evaluated (its weight at most 8)
TERM_DOUBLE, TERM_MULTIPLE = 1, 2  # a representative's terms (_evaluate): bit flags
PILOT_SHARE = 0.125  # the share of a pass's first bins that evaluates both terms, to measure them


class TermShares:
    """How often a camera pass's bins evaluate double and multiple scattering (one per medium and sample set,
    made anew each pass). Evaluating a term at a share q of the bins (weighted 1 / q) adds its second moment
    E[Y^2] (1 / q - 1) to the variance and saves (1 - q) of its cost; the two cost about the same at a bin, so the
    noise x time is least with q in proportion to sqrt(E[Y^2]) (the classical splitting result): the term of the
    larger second moment is always evaluated, the other at sqrt of their ratio, at least TERM_SHARE_MIN. Y is a
    bin's contribution (its value times the bin's weight, channels summed), its moments summed over the pass's
    bins so far, the first measured on a pilot (PILOT_SHARE of the pass's first bins evaluate both terms); a pass
    depends on nothing before it (render --samples, merge). Measured: docs/pbl.md, section 12."""

    def __init__(self):
        self.second_moment = np.zeros(2)  # double, multiple

    def measured(self) -> bool:
        return bool(self.second_moment.max() > 0.0)

    def shares(self) -> tuple[float, float]:
        """(q_double, q_multiple) for the next bins (both 1 until a term has been seen)."""
        m2 = self.second_moment
        if m2.max() <= 0.0:
            return 1.0, 1.0
        q = np.sqrt(m2 / m2.max())
        return float(max(TERM_SHARE_MIN, q[0])), float(max(TERM_SHARE_MIN, q[1]))

    def add(self, values, w_bin, shares=(1.0, 1.0)):
        """Bins evaluated at shares (q_double, q_multiple): values (bins, 3 layers, 3) weighted by 1 / q, w_bin (bins,
        3) their weights. A kept bin's (Y / q)^2 times q has the expectation of Y^2 over all bins."""
        for k, layer in enumerate((1, 2)):
            self.second_moment[k] += shares[k] * float(np.sum((values[:, layer] * w_bin).sum(axis=1) ** 2))


def cache_settings(pbl, single: bool = False) -> CacheSettings:
    """The sharing of a scene's [render.pbl] (config.PblSettings); single: for the bounced light, whose bins are
    pbl.bounced_bins times coarser in depth, width and direction."""
    f = float(pbl.bounced_bins) if single else 1.0
    return CacheSettings(f * float(pbl.cache_cell), f * float(max(pbl.cache_lateral, pbl.cache_cell)),
                         max(1, round(int(pbl.cache_directions) / f)), single)


ScatteredPoints = namedtuple("ScatteredPoints", ["pos", "dir", "weight", "plane", "owner"])
ScatteredPoints.__doc__ = """Points where segments take their smooth terms: position (m, 3), propagation direction
toward the camera (m, 3), weight per channel (m, 3: throughput x transmittance / (pdf x points per segment)), the
boundary plane (m, 4) and the segment (m,) each belongs to."""


@njit(cache=True)
def _segment_points(idx, tseg, med, k, per_mfp, counts):
    """Each segment idx[j]'s points into counts[j]: k, or with per_mfp points_on_segment's (at most k)."""
    sig_a, sig_s = med.sigma_a, med.sigma_s
    s = min(sig_a[0] + sig_s[0], min(sig_a[1] + sig_s[1], sig_a[2] + sig_s[2]))
    for j in range(idx.shape[0]):
        counts[j] = points_on_segment(k, s, tseg[idx[j]]) if per_mfp else k


@njit(cache=True)
def _scattered_points(idx, pos, dirs, beta, tseg, rng, med, counts, planes, out):
    """counts[j] points per segment idx[j] at stratified depths (as gather._segment's), into out (ScatteredPoints)."""
    sig_a, sig_s = med.sigma_a, med.sigma_s
    s = min(sig_a[0] + sig_s[0], min(sig_a[1] + sig_s[1], sig_a[2] + sig_s[2]))
    m = 0
    for j in range(idx.shape[0]):
        i = idx[j]
        dmax = tseg[i]
        frac = -math.expm1(-s * dmax) if s > 0.0 else 1.0
        xi = rand(rng, i)
        n = counts[j]
        for k in range(n):
            d, pdf = stratified_depth(k, n, xi, s, dmax, frac)
            px, py, pz = pos[i, 0] + d * dirs[i, 0], pos[i, 1] + d * dirs[i, 1], pos[i, 2] + d * dirs[i, 2]
            out.pos[m, 0], out.pos[m, 1], out.pos[m, 2] = px, py, pz
            for c in range(3):
                out.dir[m, c] = -dirs[i, c]
                out.weight[m, c] = beta[i, c] * math.exp(-(sig_a[c] + sig_s[c]) * d) / (pdf * n)
            e = nearer_plane(planes, i, px, py, pz)
            for c in range(4):
                out.plane[m, c] = planes[i, e + c]
            out.owner[m] = i
            m += 1


def scattered_points(idx, pos, dirs, beta, tseg, rng, med, k, planes, per_mfp: bool = False) -> ScatteredPoints:
    """k points per segment idx[j] (per_mfp: points_on_segment's, at most k: the smooth terms') at
    gather._segment's stratified depths (drawing the segment's random number as it does), its rays' arrays as
    there."""
    counts = np.empty(len(idx), np.int64)
    _segment_points(idx, tseg, med, int(k), bool(per_mfp), counts)
    m = int(counts.sum())
    pts = ScatteredPoints(np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 4)),
                          np.empty(m, np.int64))
    _scattered_points(idx, pos, dirs, beta, tseg, rng, med, counts, planes, pts)
    return pts


@njit(nogil=True, cache=True)
def _evaluate(reps, terms, pts, rng, med, vs, settings, do_single, values):
    """The terms at the points reps (indices into pts: ScatteredPoints) into values (len(reps), 3 layers, 3); terms
    (len(reps),): which of double (TERM_DOUBLE) and multiple (TERM_MULTIPLE) scattering each evaluates."""
    o = np.zeros(3)
    o3 = np.zeros(3)
    pplane = np.empty(4)
    for j in range(reps.shape[0]):
        r = reps[j]
        for c in range(4):
            pplane[c] = pts.plane[r, c]
        q = Query(pts.pos[r, 0], pts.pos[r, 1], pts.pos[r, 2], pts.dir[r, 0], pts.dir[r, 1], pts.dir[r, 2], pplane)
        if do_single:
            o[:] = 0.0
            single_scattering(vs, med, q, o)
            for c in range(3):
                values[j, 0, c] = o[c]
        dd, mm = (terms[j] & TERM_DOUBLE) != 0, (terms[j] & TERM_MULTIPLE) != 0
        if dd or mm:
            o[:] = 0.0
            o3[:] = 0.0
            double_multiple(vs, med, q, settings.cut_size, settings.clamp, dd, mm, o, o3, rng, pts.owner[r], -1,
                            settings.cut_roulette)
            for c in range(3):
                values[j, 1, c] = o[c]
                values[j, 2, c] = o3[c]


def bin_keys(pos: np.ndarray, dirs: np.ndarray, depth: np.ndarray, lateral: float, cell: float, directions: int,
             rng) -> np.ndarray:
    """(m, 5) integer keys of the bins of points pos (m, 3) with directions dirs (m, 3, unit) at depths depth (m,)
    below their boundary plane (inf: none): cubes of side `lateral` on a grid shifted by a random offset, cut in
    slices `cell` thick by depth where lateral > cell (the terms fall fastest away from the boundary), and the
    cube-map bin (directions^2 per face) of the direction turned by a random rotation. Lengths in scene units."""
    ijk = np.floor((pos + rng.random(3) * lateral) / lateral).astype(np.int64)
    slab = np.zeros(len(pos), np.int64)
    if lateral > cell:
        slab = np.floor(np.minimum(depth, 1e9 * cell) / cell + rng.random()).astype(np.int64)
    rot, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    d = dirs @ rot.T
    axis = np.abs(d).argmax(axis=1)
    rows = np.arange(len(d))
    major = d[rows, axis]
    u = d[rows, (axis + 1) % 3] / np.abs(major)
    v = d[rows, (axis + 2) % 3] / np.abs(major)
    iu = np.minimum(((u + 1.0) * 0.5 * directions).astype(np.int64), directions - 1)
    iv = np.minimum(((v + 1.0) * 0.5 * directions).astype(np.int64), directions - 1)
    face = 2 * axis + (major > 0)
    return np.column_stack([ijk, slab, (face * directions + iu) * directions + iv])


def bin_groups(keys: np.ndarray) -> np.ndarray:
    """Each row's bin (m,): the rank of its key row (keys (m, k) integers) among the distinct rows in lexicographic
    order, as np.unique(keys, axis=0, return_inverse=True) numbers them, taken on one integer per row (mixed radix
    over the columns' ranges: the same order) where the ranges' product fits 62 bits: ten times faster."""
    if len(keys) == 0:
        return np.zeros(0, np.int64)
    lo = keys.min(axis=0)
    span = keys.max(axis=0) - lo + 1
    if float(np.prod(span.astype(np.float64))) >= 2.0 ** 62:
        return np.unique(keys, axis=0, return_inverse=True)[1].ravel()
    flat = np.zeros(len(keys), np.int64)
    for c in range(keys.shape[1]):
        flat = flat * span[c] + (keys[:, c] - lo[c])
    return np.unique(flat, return_inverse=True)[1].ravel()


def representatives(group: np.ndarray, weight: np.ndarray, rng, bins: np.ndarray | None = None) -> np.ndarray:
    """For each bin 0..max(group) (or each entry of bins, which may repeat a bin), one of its points drawn with
    probability proportional to its weight (one number per point: shared_terms passes the channels' sum): the
    bin's total, sum of weight_i x L(representative), is then an unbiased estimate of sum of weight_i x L(x_i) (a
    uniform draw would be biased where the weights and the light vary together across a bin, as the boundary's
    Fresnel transmission and the light do across a sphere, or the channels' transmittance and the light with the
    depth). A bin of zero weight takes its first point. group numbers the bins 0..max(group), each present."""
    order = np.argsort(group, kind="stable")
    g = group[order]
    w = np.maximum(weight[order], 0.0)
    start = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    end = np.r_[start[1:], len(g)]
    if bins is not None:
        start, end = start[bins], end[bins]
    cw = np.cumsum(w)
    before = np.r_[0.0, cw][start]
    total = cw[end - 1] - before
    pick = np.searchsorted(cw, before + rng.random(len(start)) * total, side="right")
    pick = np.where(total > 0, np.clip(pick, start, end - 1), start)
    return order[pick]


def extra_evaluations(group: np.ndarray, pixel: np.ndarray, weight: np.ndarray, pixel_factor: np.ndarray,
                      splits: float, rng) -> np.ndarray:
    """How many more times than once each bin is evaluated (nbins,), `splits` x the bins in all, dealt in
    proportion to sqrt(S_b): S_b = sum over pixels p of (W_bp)^2 pixel_factor[p], W_bp the weight of bin b's points
    in pixel p (channels summed), pixel_factor the pixel's 1 / (its estimate's divisor^2 x its image^2 + 0.01): the
    share of the image's relMSE a bin's noise holds, if every bin's light were alike and as noisy. The splitting
    optimum (the least sum of S_b / n_b at a fixed sum of n_b); fractions rounded at random. The counts depend on
    the points' weights and the image before the pass only, never on an evaluation: each bin's mean stays
    unbiased."""
    nb = int(group.max()) + 1 if len(group) else 0
    if nb == 0 or splits <= 0.0:
        return np.zeros(nb, np.int64)
    npix = len(pixel_factor)
    key, inv = np.unique(group.astype(np.int64) * npix + pixel, return_inverse=True)
    w_bp = np.bincount(inv.ravel(), weights=weight)
    s = np.bincount(key // npix, weights=w_bp * w_bp * pixel_factor[key % npix], minlength=nb)
    root = np.sqrt(np.maximum(s, 0.0))
    if not root.sum() > 0.0:
        return np.zeros(nb, np.int64)
    share = splits * nb * root / root.sum()
    return (np.floor(share) + (rng.random(nb) < share - np.floor(share))).astype(np.int64)


def thread_parts(owner: np.ndarray, parts: int) -> list[np.ndarray]:
    """The representatives (their segments owner) dealt to `parts` parts (some empty where fewer segments), each
    holding all of a segment's and keeping their order: a segment's random state is then advanced in one part, in
    the same order for any thread count. Segments are dealt by their rank among the owners present, not by their
    index: the camera's rays in a medium often have indices of one parity (a transmitted child is every second
    slot), and a split by owner % threads gave one thread all the work."""
    _, rank = np.unique(owner, return_inverse=True)
    part = rank.ravel() % parts
    return [np.flatnonzero(part == t) for t in range(parts)]


def lateral_width(cache: CacheSettings, mfp: float, vs) -> float:
    """The bins' width along the boundary (scene units): cache.lateral mean free paths mfp, at most SIZE_SHARE of
    the medium's size (vs.size: the volume samples' box), at least a cell deep."""
    return max(min(cache.lateral * mfp, SIZE_SHARE * vs.size), cache.cell * mfp)


def all_terms(settings, n: int) -> np.ndarray:
    """The terms (_evaluate's) of n representatives that evaluate what settings (GatherSettings) ask."""
    return np.full(n, TERM_DOUBLE * bool(settings.double) + TERM_MULTIPLE * bool(settings.multiple), np.int8)


EVAL_PARTS_PER_THREAD = 8  # a flush's representatives in this many parts a thread, taken by whichever thread is
# free: their costs vary (0.1 to several ms), and with two equal halves one thread of the milk glass's pass idled
# for 0.22 s of its bins' 3.8 s (docs/pbl.md)


def _evaluate_on_threads(pool, threads, reps, terms, pts, rng, med, vs, settings, do_single, values):
    """_evaluate at reps (with their terms) into values, the representatives dealt to parts by segment
    (thread_parts), which the threads take as they come free: one call for all of a flush's bins, however their
    terms differ, so that no thread waits at a group's end. A segment's random state is advanced by one part, in
    its representatives' order: the same values for any thread count and any order of the parts."""
    if threads <= 1 or len(reps) < 2:
        _evaluate(reps, terms, pts, rng, med, vs, settings, do_single, values)
        return
    parts = thread_parts(pts.owner[reps], min(len(reps), threads * EVAL_PARTS_PER_THREAD))
    vals = [np.zeros((len(p), 3, 3)) for p in parts]
    list(pool.map(lambda t: _evaluate(reps[parts[t]], terms[parts[t]], pts, rng, med, vs, settings, do_single,
                                      vals[t]), range(len(parts))))
    for p, v in zip(parts, vals):
        values[p] = v


def _evaluate_shares(pool, threads, reps, which, pts, rng, med, vs, settings, do_single, values, shares, bin_rng):
    """The bins `which` (indices into reps), each evaluating double with probability shares[0] and multiple with
    shares[1] (bin_rng), the value weighted by the inverse, into values."""
    q_d, q_m = shares
    u = bin_rng.random((len(which), 2))
    terms = (TERM_DOUBLE * (u[:, 0] < q_d) + TERM_MULTIPLE * (u[:, 1] < q_m)).astype(np.int8)
    some = (terms != 0) | do_single  # (neither term and no single scattering: nothing to evaluate)
    sel, terms = which[some], terms[some]
    part = np.zeros((len(sel), 3, 3))
    _evaluate_on_threads(pool, threads, reps[sel], terms, pts, rng, med, vs, settings, do_single, part)
    part[:, 1] /= q_d
    part[:, 2] /= q_m
    values[sel] = part


def shared_terms(pool, threads, idx, pos, dirs, beta, tseg, rng, med, vs, settings, cache: CacheSettings, out,
                 planes, bin_rng, term_shares: TermShares | None = None):
    """The smooth terms of segments idx (as gather.eval_segments would add them) into out (n, 3 layers, 3),
    evaluated once per bin (bin_keys) at a random point of it. settings: GatherSettings (its double and multiple
    flags and kmax_scattered); cache.single: single scattering shared too. bin_rng (numpy Generator): the grid's
    shift and turn, the points chosen and the bins that evaluate each term (term_shares: how often; None: every
    bin both). Returns the number of evaluations."""
    if len(idx) == 0:
        return 0
    pts = scattered_points(idx, pos, dirs, beta, tseg, rng, med, settings.kmax_scattered, planes,
                           per_mfp=True)
    contrib, n = binned_terms(pool, threads, pts, rng, med, vs, settings, cache, bin_rng, term_shares)
    for layer in range(3):
        for c in range(3):
            out[:, layer, c] += np.bincount(pts.owner, weights=contrib[:, layer, c], minlength=len(out))
    return n


def binned_terms(pool, threads, pts: ScatteredPoints, rng, med, vs, settings, cache: CacheSettings, bin_rng,
                 term_shares: TermShares | None = None, image=None):
    """(contrib (m, 3 layers, 3), evaluations): each point's share of its bin's smooth terms (shared_terms's), the
    representatives' random states rng[pts.owner]. image: (pixel (m,), pixel_factor (npix,), splits): each point's
    pixel and extra_evaluations' factors and share, the bins then evaluated more than once where the image's noise
    asks (each evaluation at a representative of its own, their mean the bin's value); None: once each."""
    mfp = 1.0 / float(np.max(med.sigma_a + med.sigma_s))
    depth = pts.plane[:, 3] - np.einsum("ij,ij->i", pts.plane[:, :3], pts.pos)
    keys = bin_keys(pts.pos, pts.dir, depth, lateral_width(cache, mfp, vs), cache.cell * mfp, cache.directions,
                    bin_rng)
    group = bin_groups(keys)
    weight = pts.weight.sum(axis=1)
    reps = representatives(group, weight, bin_rng)
    nb = len(reps)
    of_bin = np.arange(nb)  # each evaluation's bin
    if image is not None:
        extra = extra_evaluations(group, image[0], weight, image[1], image[2], bin_rng)
        if extra.any():
            more = np.repeat(of_bin, extra)
            reps = np.concatenate([reps, representatives(group, weight, bin_rng, more)])
            of_bin = np.concatenate([of_bin, more])
    values = np.zeros((len(reps), 3, 3))
    do_single = bool(cache.single and settings.single)
    w_bin = np.stack([np.bincount(group, weights=pts.weight[:, c], minlength=nb) for c in range(3)], axis=1)
    if term_shares is None or not (settings.double and settings.multiple):
        _evaluate_on_threads(pool, threads, reps, all_terms(settings, len(reps)), pts, rng, med, vs, settings,
                             do_single, values)
    else:
        rest = np.arange(len(reps))
        if not term_shares.measured():  # a pilot: a random share of the bins evaluates both terms
            pilot = np.sort(bin_rng.permutation(len(reps))[:max(1, math.ceil(PILOT_SHARE * len(reps)))])
            part = np.zeros((len(pilot), 3, 3))
            _evaluate_on_threads(pool, threads, reps[pilot], all_terms(settings, len(pilot)), pts, rng, med, vs,
                                 settings, do_single, part)
            values[pilot] = part
            term_shares.add(part, w_bin[of_bin[pilot]])
            rest = np.setdiff1d(rest, pilot)
        shares = term_shares.shares()
        _evaluate_shares(pool, threads, reps, rest, pts, rng, med, vs, settings, do_single, values, shares, bin_rng)
        term_shares.add(values[rest], w_bin[of_bin[rest]], shares)
    # the draw follows the weights' channel sum; per channel c the bin's total stays unbiased when it is scaled by
    # (w_rc / w_r) / (W_c / W): the representative's share of channel c over the bin's
    w_rep, w_b = pts.weight[reps], w_bin[of_bin]
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = (w_rep / w_rep.sum(axis=1, keepdims=True)) / (w_b / w_b.sum(axis=1, keepdims=True))
    scale = np.where(np.isfinite(scale), scale, 1.0)
    values *= scale[:, None, :]
    if len(reps) > nb:  # a bin's value: the mean of its evaluations
        count = np.bincount(of_bin, minlength=nb)
        values = np.stack([np.stack([np.bincount(of_bin, weights=values[:, t, c], minlength=nb) for c in range(3)],
                                    axis=1) for t in range(3)], axis=1) / count[:, None, None]
    contrib = values[group] * pts.weight[:, None, :]
    if not do_single:
        contrib[:, 0] = 0.0
    return contrib, len(reps)


DEFERRED_BIN_POINTS = 1 << 19  # smooth-term points a DeferredBins holds before it evaluates them (112 bytes each)


class DeferredBins:
    """The smooth terms' points of a pass's camera segments, drawn segment by segment as the paths go
    (scattered_points, the segment's random state advanced then) and binned and evaluated together (flush): the
    bins of one evaluation serve every batch and every path depth, where each batch and depth had bins of its own
    (a 512 x 512 pass's four batches evaluated four times the bins of a 256 x 256 one). Each bin's total stays
    unbiased (representatives); the representatives' light cuts take random states of their own, drawn from the
    flush's generator."""

    def __init__(self, bin_rng, npix: int, pixel_factor: np.ndarray | None = None, splits: float = 0.0):
        self.bin_rng, self.npix = bin_rng, npix  # (numpy Generator: the bins' draws; the layers' pixels)
        # binned_terms's image factors (npix,) and share of extra evaluations (None or 0: each bin once)
        self.pixel_factor, self.splits = pixel_factor, float(splits)
        self.parts = {}  # key -> (VolumeSamples, Medium, settings, cache, TermShares, layers, [point arrays])
        self.count = 0  # the points held

    def unmeasured(self) -> bool:
        """Whether a key held has TermShares not yet measured (the caller flushes it then: the segments after a
        diffuse bounce, evaluated point by point, take the shares measured on the bins)."""
        return any(part[4] is not None and not part[4].measured() for part in self.parts.values())

    def full(self) -> bool:
        """Whether it holds DEFERRED_BIN_POINTS points or more (the caller flushes it: memory stays bounded)."""
        return self.count >= DEFERRED_BIN_POINTS

    def add(self, key, vs, med, settings, cache: CacheSettings, term_shares, layers, idx, pos, dirs, beta, tseg, rng,
            planes, pixel):
        """The smooth terms' points of segments idx (shared_terms's) for pixels pixel[idx], under key (a medium and
        sample set: the points of one key are binned together). layers: three (npix, 3) arrays (or None) taking
        the single, double and multiple contributions."""
        if len(idx) == 0:
            return
        pts = scattered_points(idx, pos, dirs, beta, tseg, rng, med, settings.kmax_scattered, planes, per_mfp=True)
        part = self.parts.setdefault(key, (vs, med, settings, cache, term_shares, layers, []))
        part[6].append((pts.pos, pts.dir, pts.weight, pts.plane, pixel[pts.owner]))
        self.count += len(pts.owner)

    def flush(self, pool, threads) -> int:
        """Bins and evaluates the points held and adds their contributions into their layers, per pixel. Returns
        the evaluations."""
        bin_rng, npix = self.bin_rng, self.npix
        parts, self.parts, self.count = self.parts, {}, 0
        n = 0
        for vs, med, settings, cache, term_shares, layers, chunks in parts.values():
            pixel = np.concatenate([c[4] for c in chunks])
            # by pixel (a pass traces one medium path a pixel: its points in the path's order), so that the order,
            # and the draws that follow it, do not depend on how the pass's paths were cut in batches
            order = np.argsort(pixel, kind="stable")
            pos, wdir, weight, plane = (np.concatenate([c[k] for c in chunks])[order] for k in range(4))
            pixel = pixel[order]
            chunks.clear()
            m = len(pixel)
            pts = ScatteredPoints(pos, wdir, weight, plane, np.arange(m, dtype=np.int64))
            rng = bin_rng.integers(0, 1 << 63, m, dtype=np.int64).view(np.uint64)  # a state per point
            image = None if self.pixel_factor is None or self.splits <= 0 else (pixel, self.pixel_factor, self.splits)
            contrib, k = binned_terms(pool, threads, pts, rng, med, vs, settings, cache, bin_rng, term_shares, image)
            n += k
            for layer, target in enumerate(layers):
                if target is None:
                    continue
                for c in range(3):
                    target[:, c] += np.bincount(pixel, weights=contrib[:, layer, c], minlength=npix)
        return n
