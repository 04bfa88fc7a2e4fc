"""The point-based method's camera side: camera paths, their surfaces, and the medium gathered along them
(Wang et al. 2016, sec. 3.6-3.11).

Camera paths are traced in a wavefront like volpath's, but split at smooth interfaces: the reflected and the
refracted branch are both followed, weighted by Fresnel (F and (1 - F) (eta_i/eta_t)^2), up to a split depth, so
the image carries no noise from choosing between them. Each segment a path travels inside a medium gathers the
medium's light from the light samples (gather.py). Branches of small weight evaluate the medium by Russian
roulette. Diffuse surfaces take one shadow ray per light and continue by cosine-sampled bounces (indirect light);
emitters and the environment seen directly or through specular chains add their radiance (see _interact_rays for
when a shadow ray has already counted them).

Light reflected by the medium's boundary after scattering (sec. 3.10) comes as a second set of volume samples per
medium (bounced.py), evaluated by the same estimators into the `bounced` layer.
"""

from __future__ import annotations

import math
import time
from collections import namedtuple
from concurrent.futures import ThreadPoolExecutor
from functools import partial

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.intersect import closest_surface_hits, light_hits, visible
from pbvol_cli.geometry.raycast import TriangleCaster
from pbvol_cli.geometry.scene_build import (CAM_HEIGHT, CAM_UP, DIELECTRIC, DIFFUSE, MIRROR, NULL, SURF_ALBEDO,
                                           SURF_ETA_IN, SURF_ETA_OUT, SURF_TYPE, BuiltScene)
from pbvol_cli.physics.fresnel import reflect, refract
from pbvol_cli.physics.lights import ENVIRONMENT, LIGHT_RGB, LIGHT_TYPE, emitted_toward, light_sample
from pbvol_cli.physics.sampling import cosine_hemisphere, mix64, rand
from pbvol_cli.pointbased.caustics import caustic_map, irradiance
from pbvol_cli.pointbased.diffuse_filter import DiffuseVertices
from pbvol_cli.pointbased.gather import (LAYER_DOUBLE, LAYER_MULTIPLE, LAYER_SINGLE, DeferredSingle, eval_segments,
                                         gather_settings, segment_planes)
from pbvol_cli.pointbased.peak_deflections import draw_deflections, peak_rates
from pbvol_cli.pointbased.radiance_cache import DeferredBins, TermShares, cache_settings
from pbvol_cli.pointbased.volume_samples import PLANE_COLS, medium_params, scattered_share
from pbvol_cli.render.camera import camera_rays_for
from pbvol_cli.render.interfaces import dielectric_fresnel, incident_side, indices, medium_beyond, shadow_ray_length
from pbvol_cli.render.sample_sums import SampleSums, layer_means

COMPONENTS = ("single", "double", "multiple", "bounced")
LAYER_BOUNCED = 3  # contrib[ray, layer, channel]: gather's three layers, then the bounced samples' sum
BOUNCED_ROULETTE = 0.2  # bounced samples carrying less than this share of the scattered power are evaluated
# on that share / BOUNCED_ROULETTE of the camera segments (weight 1 / share: unbiased, their noise stays small)

# the kernels' bundles (numba reads them by field name)
Rays = namedtuple("Rays", ["pos", "dir", "beta", "medium", "depth", "rng", "state"])
Hits = namedtuple("Hits", ["t", "surface", "ng", "ns", "light"])
Children = namedtuple("Children", ["pos", "dir", "beta", "medium", "ok", "state"])
ShadowRays = namedtuple("ShadowRays", ["pos", "dir", "dist", "contrib", "ok"])
# shadows_cross: the surfaces the shadow rays pass (0: none, as pbl's; 1: null boundaries, 2: smooth dielectrics too,
# the ray marcher's), so a light seen past one of them after a diffuse bounce is already counted
# caustics: whether a caustic map (caustics.py) carries the emitters seen after a diffuse bounce through smooth
# interfaces, which the camera paths then no longer count
PathLimits = namedtuple("PathLimits", ["eps", "max_split_depth", "max_diffuse", "shadows_cross", "caustics"])


# Numba pitfall: arrays unpacked from a tuple inside a parallel function lose their writes in prange (numba
# 0.68). The parallel kernel therefore only loops over chunks and calls an inner function that takes the tuples.
_ROULETTE_STREAM = np.uint64(0xD1B54A32D192ED03)  # a child's survival draw, apart from the numbers its path uses
_INV_2_53 = 1.0 / 9007199254740992.0
RAY_CHUNK = 256  # rays a kernel call handles: the bundles' arrays are unpacked once per call, not per ray


@njit(parallel=True, cache=True)
def _interact(surfaces, lights, rays, hits, limits, emit, children, shadows):
    n = rays.pos.shape[0]
    for c in prange((n + RAY_CHUNK - 1) // RAY_CHUNK):
        _interact_rays(c * RAY_CHUNK, min(n, (c + 1) * RAY_CHUNK), surfaces, lights, rays, hits, limits, emit,
                       children, shadows)


@njit(cache=True)
def _interact_rays(lo, hi, surfaces, lights, rays, hits, limits, emit, children, shadows):
    """Rays lo .. hi-1, each (ray i): its emission, then the surface it meets at hits.t[i]: up to two children
    (reflected: slot 2i, transmitted: 2i + 1); at a diffuse surface, one shadow ray per light (slots i * n_lights
    + light) and, below limits.max_diffuse bounces, one cosine-sampled child (slot 2i) for indirect light.
    rays.state[i] = 4 x (diffuse bounces) + 2 x (a specular interface crossed since the last diffuse bounce):
    lights and the environment seen directly after a diffuse bounce are already counted by the shadow rays, which
    stop at every surface; seen through a specular chain (a caustic through the glass) they are not, and count,
    unless limits.caustics: an emitter after a diffuse bounce is then the caustic map's (gathered by the caller)."""
    pos, dirs, beta, medium, depth, rng, state = (rays.pos, rays.dir, rays.beta, rays.medium, rays.depth, rays.rng,
                                                  rays.state)
    t, surf, ng, ns, li = hits.t, hits.surface, hits.ng, hits.ns, hits.light
    child_pos, child_dir, child_beta = children.pos, children.dir, children.beta
    child_med, child_ok, child_state = children.medium, children.ok, children.state
    sh_pos, sh_dir, sh_dist, sh_C, sh_ok = shadows.pos, shadows.dir, shadows.dist, shadows.contrib, shadows.ok
    eps = limits.eps
    nl = lights.shape[0]
    st = np.empty(1, np.uint64)  # a diffuse hit's random stream, for rand
    for i in range(lo, hi):
        child_ok[2 * i] = child_ok[2 * i + 1] = False
        for lk in range(nl):
            sh_ok[i * nl + lk] = False
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        n_diffuse = state[i] >> 2
        counts = n_diffuse == 0 or (state[i] & 2) != 0  # emission not already counted by a shadow ray
        if li[i] >= 0 and (not counts or (n_diffuse > 0 and limits.caustics)):
            continue
        if li[i] >= 0:  # an area light in front of the surface
            e = emitted_toward(lights, li[i], dx, dy, dz, pos[i, 0], pos[i, 1], pos[i, 2], t[i])
            for c in range(3):
                emit[i, c] += beta[i, c] * lights[li[i], LIGHT_RGB + c] * e
            continue
        s = surf[i]
        if s < 0 and not counts:
            continue
        if s < 0:
            for k in range(nl):
                if lights[k, LIGHT_TYPE] == ENVIRONMENT:
                    for c in range(3):
                        emit[i, c] += beta[i, c] * lights[k, LIGHT_RGB + c]
            continue
        if depth[i] >= limits.max_split_depth:
            continue
        hx, hy, hz = pos[i, 0] + t[i] * dx, pos[i, 1] + t[i] * dy, pos[i, 2] + t[i] * dz
        entering, gx, gy, gz, nx, ny, nz = incident_side(dx, dy, dz, ng[i, 0], ng[i, 1], ng[i, 2], ns[i, 0], ns[i, 1],
                                                         ns[i, 2])
        stype = surfaces[s, SURF_TYPE]
        if stype == DIFFUSE:
            # direct light from every light, one sample each (the environment by cosine-weighted directions)
            st[0] = rng[i]
            for lk in range(nl):
                j = i * nl + lk
                sh_ok[j] = False
                u1, u2 = rand(st, 0), rand(st, 0)
                if lights[lk, LIGHT_TYPE] == ENVIRONMENT:
                    wx, wy, wz = cosine_hemisphere(u1, u2, nx, ny, nz)
                    dist = np.inf
                    Lr, Lg, Lb = lights[lk, LIGHT_RGB], lights[lk, LIGHT_RGB + 1], lights[lk, LIGHT_RGB + 2]
                    c = wx * nx + wy * ny + wz * nz
                    f = 1.0  # (c / pi) / pdf, pdf = c / pi
                    ok = c > 0.0
                else:
                    wx, wy, wz, dist, Lr, Lg, Lb, pdf, delta = light_sample(lights, lk, hx, hy, hz, u1, u2)
                    c = wx * nx + wy * ny + wz * nz
                    ok = pdf > 0.0 and c > 0.0
                    f = c / math.pi / pdf if ok else 0.0
                if ok and wx * gx + wy * gy + wz * gz > 0.0:
                    sh_C[j, 0] = beta[i, 0] * surfaces[s, SURF_ALBEDO] * f * Lr
                    sh_C[j, 1] = beta[i, 1] * surfaces[s, SURF_ALBEDO + 1] * f * Lg
                    sh_C[j, 2] = beta[i, 2] * surfaces[s, SURF_ALBEDO + 2] * f * Lb
                    sh_pos[j, 0], sh_pos[j, 1], sh_pos[j, 2] = hx + eps * gx, hy + eps * gy, hz + eps * gz
                    sh_dir[j, 0], sh_dir[j, 1], sh_dir[j, 2] = wx, wy, wz
                    sh_dist[j] = shadow_ray_length(dist, eps)
                    sh_ok[j] = True
            if n_diffuse < limits.max_diffuse:
                j = 2 * i
                wx, wy, wz = cosine_hemisphere(rand(st, 0), rand(st, 0), nx, ny, nz)
                if wx * gx + wy * gy + wz * gz > 0.0:
                    child_dir[j, 0], child_dir[j, 1], child_dir[j, 2] = wx, wy, wz
                    child_pos[j, 0], child_pos[j, 1], child_pos[j, 2] = hx + eps * gx, hy + eps * gy, hz + eps * gz
                    for c in range(3):  # albedo: (albedo / pi) cos / (cos / pi)
                        child_beta[j, c] = beta[i, c] * surfaces[s, SURF_ALBEDO + c]
                    child_med[j] = medium[i]
                    child_state[j] = (n_diffuse + 1) << 2
                    child_ok[j] = True
            rng[i] = st[0]
            continue
        # specular: reflected child (slot 2i) and transmitted child (slot 2i + 1)
        eta_i = eta_t = 1.0
        cos_i = cos_t = 1.0
        if stype == MIRROR:
            F, kt = 1.0, 0.0
            rscale = (surfaces[s, SURF_ALBEDO], surfaces[s, SURF_ALBEDO + 1], surfaces[s, SURF_ALBEDO + 2])
        else:
            eta_i, eta_t = indices(surfaces, s, entering)
            cos_i, F, cos_t = dielectric_fresnel(eta_i, eta_t, dx, dy, dz, nx, ny, nz)
            if stype != DIELECTRIC:
                F, cos_t = 0.0, cos_i
            kt = (1.0 - F) * (eta_i / eta_t) ** 2
            rscale = (1.0, 1.0, 1.0)
        if F > 0.0:
            j = 2 * i
            wx, wy, wz = reflect(dx, dy, dz, nx, ny, nz)
            child_dir[j, 0], child_dir[j, 1], child_dir[j, 2] = wx, wy, wz
            child_pos[j, 0], child_pos[j, 1], child_pos[j, 2] = hx + eps * gx, hy + eps * gy, hz + eps * gz
            for c in range(3):
                child_beta[j, c] = beta[i, c] * F * rscale[c]
            child_med[j] = medium[i]
            child_state[j] = state[i] | 2
            child_ok[j] = True
        if kt > 0.0:
            j = 2 * i + 1
            if stype == NULL:
                wx, wy, wz = dx, dy, dz
            else:
                wx, wy, wz = refract(dx, dy, dz, nx, ny, nz, eta_t / eta_i, cos_i, cos_t)
            child_dir[j, 0], child_dir[j, 1], child_dir[j, 2] = wx, wy, wz
            child_pos[j, 0], child_pos[j, 1], child_pos[j, 2] = hx - eps * gx, hy - eps * gy, hz - eps * gz
            for c in range(3):
                child_beta[j, c] = beta[i, c] * kt
            child_med[j] = medium_beyond(surfaces, s, entering)
            counted = limits.shadows_cross >= (1 if stype == NULL else 2)  # by the shadow rays, through s
            child_state[j] = state[i] if counted else state[i] | 2
            child_ok[j] = True


# surface_paths = 0 (auto): the first two passes trace AUTO_FIRST_PATHS paths per pixel; from then on each pixel's
# count follows its measured variances, the passes already in the image and those still to come (auto_surface_paths)
AUTO_FIRST_PATHS = 8
CAMERA_CHUNK = 1 << 16  # camera paths traced together: a generation holds a few kB per ray (children, shadow rays,
# contributions), and splitting at glass multiplies the rays; 2^18 made a 512 x 512 pass peak 0.7 GB above its
# light samples (docs/pbl.md, memory)
SURFACE_CHUNK = 1 << 15  # surface-only camera paths traced together: they share nothing within a batch (no bins),
# and a 512 x 512 pass on the wine glass under the sky peaked in their batches: 944-948 MiB at 2^16, 865-867 at
# 2^15, the same image and time (docs/pbl.md, memory)
PILOT_FIRST_SAMPLE = 1 << 40  # the pilot's sample indices (pilot_paths): past any a pass uses, its streams apart
AUTO_MAX_PATHS = 128  # the mean over the pixels, at most
AUTO_MAX_PIXEL_PATHS = 1024  # one pixel's, at most (a small light's mirror image on glass wants hundreds)
PASS_COST_RATIO = 20.0  # a pass's medium work in surface paths per pixel (docs/pbl.md). The optimum is flat in it
# (k goes as its square root), and a constant keeps the image independent of timings


def auto_surface_paths(s1, m: float, max_paths: int = AUTO_MAX_PATHS, before: tuple[float, float] = (0.0, 0.0),
                       remaining: int | None = None):
    """Camera paths for each of the next passes, for one pixel or an array of them. A pass whose pixel p traces
    k_p paths costs about c (sum k_p + R n) (R = PASS_COST_RATIO, n pixels) and leaves a variance sum S1_p / k_p +
    M_p (S1_p: one surface path's, M_p: the medium evaluation's, both relative as compare's relMSE). The image is
    the mean of its passes with equal weights, so with passes already in it (before = (A, C): their variance sum
    and cost per pixel, the pixels' means, cost in surface paths) and `remaining` passes to come at k_p each, its
    error x time (A + r (S1_p / k_p + M)) (C + r (k_p + R)), summed over the pixels, is least at
    k_p = sqrt(S1_p (C + r R) / (A + r M)), M the pixels' mean M_p. With no passes before, or remaining None (as
    many as it takes), that is sqrt(R S1_p / M): a pass's own optimum. With some before and few to come it is
    less: paths added now cannot lower the noise the first passes left in the image."""
    s1 = np.asarray(s1, float)
    a, c = before
    r = remaining
    den = (a + r * m) if r is not None else m
    if den > 0.0:
        ratio = (c + r * PASS_COST_RATIO) / den if r is not None else PASS_COST_RATIO / m
        k = np.clip(np.rint(np.sqrt(ratio * np.maximum(s1, 0.0))), 1, max_paths)
    else:
        k = np.full(s1.shape, float(max_paths))
    k = np.where(s1 > 0.0, k, 1.0).astype(np.int64)
    return int(k) if k.ndim == 0 else k


def pilot_surface_paths(s1: np.ndarray, width: int, mean_paths: int = AUTO_FIRST_PATHS) -> np.ndarray:
    """The first passes' camera paths per pixel from a pilot's measured surface variances s1 (one path's, relative
    as compare's relMSE, per pixel): as many paths in all as mean_paths in every pixel, one of them in every pixel
    and the others spread as sqrt(s1) (the least sum of s1_p / k_p at a fixed sum of k_p), each pixel's s1 first
    raised to its 3 x 3 neighbourhood's mean (a rare hit seen in one pixel is likely in its neighbours); at most
    AUTO_MAX_PIXEL_PATHS. With no variance anywhere, mean_paths everywhere. (Half of them in every pixel read
    more error at less time: docs/pbl.md, section 9.)"""
    w = np.sqrt(np.maximum(_spread(np.asarray(s1, float), width), 0.0))
    if not np.any(w > 0):
        return np.full(len(w), mean_paths, np.int64)
    floor = 1
    return np.minimum(floor + np.rint((mean_paths - floor) * w / w.mean()), AUTO_MAX_PIXEL_PATHS).astype(np.int64)


DIFFUSE_COST = 0.3  # the smooth terms after a diffuse bounce over the rest of a pass's cost, as measured on the
# sky-lit glasses at 256² (oil 2.35 of 10.25 s, milk 1.66 of 7.69 s: 0.30 and 0.28); the optimum is flat in it
DIFFUSE_SHARE_MIN = 0.125  # the least share of those rays that evaluates them (their weight at most 8)


def diffuse_share(b: float, v: float, p_before: float) -> float:
    """The share p of the camera rays after a diffuse bounce that evaluate the medium's smooth terms (weighted 1 /
    p) in the next pass. Evaluating them on a share p adds b (1/p - 1) to a pass's variance and saves (1 - p) of
    their cost D = DIFFUSE_COST x the rest's: with the pass's variance a + b / p (a: the rest, v measured at
    p_before) the noise x time (a + b / p)(1 + DIFFUSE_COST p) is least at p = sqrt(b / (a DIFFUSE_COST)), the
    splitting optimum. b: their second moment (relative, as compare's relMSE, a pixel's mean)."""
    a = v - b / p_before
    if b <= 0.0:
        return DIFFUSE_SHARE_MIN
    if a <= 0.0:
        return 1.0
    return float(min(1.0, max(DIFFUSE_SHARE_MIN, math.sqrt(b / (a * DIFFUSE_COST)))))


class DiffuseShare:
    """A pass's share p of the rays after a diffuse bounce that evaluate the smooth terms (gather._after_diffuse),
    and the second moment of what they added, measured for the next passes' share: the sum over those rays of
    p (value / den)^2 per channel, value their contribution to the pixel's estimate (weighted 1 / p, so that p times
    its square has the unweighted one's expectation), den the pixel's image so far squared + 0.01 (None: not
    measured, the first pass)."""

    def __init__(self, p: float, den: np.ndarray | None):
        self.p, self.den, self.second_moment, self.rays = float(p), den, 0.0, 0

    def add(self, pixel: np.ndarray, kpaths: np.ndarray, value: np.ndarray):
        """value (n, 3): the rays' smooth terms after a diffuse bounce as evaluated, weighted by their pixel's path
        count kpaths (n,) like every medium term (the pixel's estimate divides by it)."""
        self.rays += len(pixel)
        if self.den is None or len(pixel) == 0:
            return
        y = value / kpaths[:, None]
        self.second_moment += self.p * float((y * y / self.den[pixel]).mean(axis=1).sum())


def _spread(values: np.ndarray, width: int) -> np.ndarray:
    """Each pixel's value raised to the mean of its 3 x 3 neighbourhood where that is larger: a rare event (a
    caustic path) seen in one pixel is likely in its neighbours too."""
    return np.maximum(values, neighbourhood_sums(values[:, None], width)[:, 0] / 9.0)


class PixelStatistics:
    """The variances auto_surface_paths weighs, from the passes so far, relative per pixel and channel as
    compare's relMSE (over the image so far squared + 0.01): each pixel's surface paths' (every path it traced: they
    are independent and alike) and the medium's from pass to pass (one evaluation per pixel and pass)."""

    def __init__(self, npix: int, width: int):
        self.width = width
        self.count = np.zeros(npix)  # surface paths traced per pixel
        self.inv_count = np.zeros(npix)  # the sum over passes of 1 / the pixel's paths in the pass
        self.surface_sum, self.surface_sq = np.zeros((npix, 3)), np.zeros((npix, 3))
        self.medium_sum, self.medium_sq = np.zeros((npix, 3)), np.zeros((npix, 3))
        self.passes = 0
        self.diffuse = []  # (second moment a pixel, share) of the rays after a diffuse bounce, per measured pass
        self.pilot_surface = None  # a pilot's relative variance of one surface path per pixel (Pilot), if any

    def add(self, k: np.ndarray, surface_sum, surface_sq, medium):
        """A pass: each pixel's path count k, the sum and sum of squares of its paths' surface light, and its
        medium estimate."""
        self.count += k
        self.inv_count += 1.0 / k
        self.surface_sum += surface_sum
        self.surface_sq += surface_sq
        self.medium_sum += medium
        self.medium_sq += medium ** 2
        self.passes += 1

    def variances(self, image) -> tuple[np.ndarray, float]:
        """(one surface path's relative variance per pixel, the medium's mean relative variance)."""
        den = image ** 2 + 1e-2
        n = self.count[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            var = np.where(n > 1, np.maximum(self.surface_sq - self.surface_sum ** 2 / n, 0.0) / (n - 1), 0.0)
        p = self.passes
        m = float((np.maximum(self.medium_sq - self.medium_sum ** 2 / p, 0.0) / (p - 1) / den).mean())
        return (var / den).mean(axis=1), m

    def add_diffuse(self, share: DiffuseShare, npix: int):
        """A pass's DiffuseShare (npix pixels), kept where it measured rays after a diffuse bounce."""
        if share.den is not None and share.rays > 0:
            self.diffuse.append((share.second_moment / npix, share.p))

    def next_diffuse_share(self, image, k: np.ndarray) -> float:
        """The next pass's share of the rays after a diffuse bounce that evaluate the smooth terms (diffuse_share),
        the pass tracing k paths per pixel; 1 until two passes and a measured second moment are in. With a pilot
        the second pass takes the share from the first pass's rays (measured over the pilot's image) and the pilot's
        surface variance, the medium's pass-to-pass variance (which wants two passes) left out: the rest's variance
        read low, the share no lower than the optimum (the oracle share at the second pass saved 6-12 % at two
        passes: docs/pbl.md, section 13)."""
        if self.passes == 1 and self.pilot_surface is not None and self.diffuse:
            b, p = self.diffuse[-1]
            return diffuse_share(b, float(np.mean(self.pilot_surface / k)) + b / p, p)
        if self.passes < 2 or not self.diffuse:  # (from the third pass on: the variances want two passes)
            return 1.0
        s1, m = self.variances(image)
        b = float(np.mean([d[0] for d in self.diffuse]))
        return diffuse_share(b, float(np.mean(s1 / k)) + m, self.diffuse[-1][1])

    def next_paths(self, image, remaining: int | None = None) -> np.ndarray | None:
        """Each pixel's path count for the next pass, or None while two passes are not yet in; remaining: the passes
        still to come, the next one included (None: as many as it takes). The counts' mean is at most
        AUTO_MAX_PATHS."""
        if self.passes < 2 or self.count.max() < 2:
            return None
        s1, m = self.variances(image)
        # what the passes so far left in the image (their variance sum S1_p sum_q 1 / k_q + passes M) and cost
        before = (float(np.mean(s1 * self.inv_count)) + self.passes * m,
                  float(self.count.mean()) + self.passes * PASS_COST_RATIO)
        k = auto_surface_paths(_spread(s1, self.width), m, AUTO_MAX_PIXEL_PATHS, before, remaining)
        if k.mean() > AUTO_MAX_PATHS:
            k = np.maximum(1, (k * (AUTO_MAX_PATHS / k.mean())).astype(np.int64))
        return k


def pass_paths(k: np.ndarray, first: np.ndarray):
    """A pass's camera paths in tracing order, sample by sample (every pixel's first, then the second of those
    with two or more...): (pixel, sample index of the pixel, index of the path among its pixel's in this pass).
    k: paths per pixel in this pass; first: each pixel's sample index so far."""
    k = np.ascontiguousarray(k, np.int64)
    pixels, ranks = np.empty(int(k.sum()), np.int64), np.empty(int(k.sum()), np.int64)
    _paths_by_rank(k, pixels, ranks)
    return pixels, first[pixels] + ranks, ranks


@njit(cache=True)
def _paths_by_rank(k, pixels, ranks):
    """pass_paths' order in one pass over the paths (a counting sort by rank; a boolean matrix of the largest
    count by the pixels cost 0.13 s a pass where a pixel takes 1024 paths): the paths of rank r start after those
    of the lower ranks, pixels in order within a rank."""
    top = 0
    for p in range(k.shape[0]):
        top = max(top, k[p])
    start = np.zeros(top + 1, np.int64)
    for p in range(k.shape[0]):
        start[k[p]] += 1  # pixels with exactly k[p] paths
    # pixels with more than r paths = those with r + 1 or more; rank r's paths start after all lower ranks'
    more = k.shape[0] - start[0]
    offset = np.zeros(top, np.int64)
    acc = 0
    for r in range(top):
        offset[r] = acc
        acc += more
        more -= start[r + 1]
    for p in range(k.shape[0]):
        for r in range(k[p]):
            j = offset[r]
            pixels[j], ranks[j] = p, r
            offset[r] = j + 1


def render_pbl(bs: BuiltScene, media_for_pass, spp: int, seed: int, pbl, threads: int, progress=None,
               bounced_terms=("single", "double", "multiple"), time_limit: float | None = None, entry=None,
               segment=None, first_pass: int = 0):
    """Renders spp passes with the settings pbl (config.PblSettings); pass p uses the light samples
    media_for_pass(p) ({medium: (SampleSet of the lights' samples, SampleSet of the bounced samples or None)}).

    A pass traces k_p camera paths for pixel p: all of them shade surfaces, and one of them, chosen uniformly at
    random per pixel and pass, also evaluates the medium, its medium terms weighted by k_p. The pixel's estimate
    stays unbiased and the medium's cost per pass is that of one path, while the surfaces' noise (path traced like
    volpath's) falls k_p times. k_p is pbl.surface_paths for every pixel, or with 0 (auto) chosen per pixel and pass
    from the variances measured on the passes before it and the passes still to come of the spp
    (auto_surface_paths): a small light's mirror image on a glass takes hundreds of paths, a pixel of the medium
    alone one. bounced_terms: the estimators that evaluate the bounced samples (all three make the bounced layer;
    tests take a subset). time_limit (seconds): no pass starts
    after it. entry: a term evaluated where camera paths enter a medium, a layer of its own (entry.layer):
    entry.for_pass(p).radiance(m, points, eta) is the light leaving the boundary there over the Fresnel
    transmittance (dipole/hierarchy.DiffusionPasses). segment: a term evaluated along each segment a camera path
    travels in a medium, layers of its own (segment.layers), for pass p segment.for_pass(p, caster):
    .march(caster, m, pos, dirs, lengths, rng, gather) gives the radiance it adds to each layer (zero where not
    gather) and the transmittance the path goes on with,
    segment.shadow(caster, pos, dirs, dist, light, medium) the transmittance of the surfaces' shadow rays
    (render/raymarch.RayMarcher; its through_dielectrics: whether they cross smooth dielectrics); the media then need
    not be homogeneous. first_pass: the passes are first_pass .. first_pass + spp - 1 of the scene's sequence
    (render --samples; see first_path_indices). Returns (image (H, W, 3), layers {name: (H, W, 3)}, stats;
    stats["spp"]: the passes rendered, stats["surface_paths"]: the mean paths per pixel of each pass,
    stats["diffuse_shares"]: each pass's share of the rays after a diffuse bounce that evaluate the smooth terms
    (DiffuseShare), stats["sums"]:
    {layer: render/sample_sums.SampleSums over the passes}, in the order the image adds the layers)."""
    W, H = bs.resolution
    npix = W * H
    settings = gather_settings(pbl, pbl.components)
    # the bounced light is smooth along a ray: kmax_scattered points for its single scattering too
    settings_b = gather_settings(pbl, bounced_terms)._replace(kmax=pbl.kmax_scattered)
    caster = TriangleCaster(bs.vertices, bs.faces, threads)
    pool = ThreadPoolExecutor(threads) if threads > 1 else None
    names = (*COMPONENTS, "surface", *((entry.layer,) if entry is not None else ()),
             *(segment.layers if segment is not None else ()))
    sums = {name: SampleSums() for name in names}  # each layer's sum over passes, merged exactly by pbvol merge
    stats = PixelStatistics(npix, W)
    ks, shares = [], []
    t0 = time.perf_counter()
    chunk = CAMERA_CHUNK
    done, first_sample = first_path_indices(pbl.surface_paths, first_pass, npix)
    samples_so_far = np.full(npix, first_sample, np.int64)  # each pixel's (its next path's sample index)
    passes = 0
    first_k = None  # the first two passes' counts (auto: from a pilot, or AUTO_FIRST_PATHS)
    pilot_den = None  # the first pass's measure of the rays after a diffuse bounce (the pilot's image)
    # caustics from photons (caustics.py), in media the camera paths attenuate themselves (no entry or segment term)
    with_caustics = pbl.caustic_photons > 0 and entry is None and segment is None
    caustics_of = (lambda p: caustic_map(bs, caster, round(pbl.caustic_photons * npix), pbl.caustic_radius,
                                         pixel_angle(bs), seed, p, max_depth=pbl.max_split_depth,
                                         deflect=_pass_settings(pbl, p).peak_deflections)) \
        if with_caustics else (lambda p: None)
    caustics = caustics_of(first_pass)
    if pbl.surface_paths == 0 and pbl.pilot_paths > 0 and entry is None and segment is None:
        # (the pilot path traces the caustics: with the photons' smooth caustic the wax candle's first pass read
        # relMSE 0.014 over seeds 2-12 against 0.012 with this one, measured alike; docs/pbl.md, "The candle's
        # first pass under a pilot that sees the caustics")
        pilot = _pilot(bs, caster, pool, threads, seed, npix, W, _pass_settings(pbl, first_pass), settings,
                       settings_b)
        first_k, stats.pilot_surface, pilot_den = pilot.counts, pilot.surface_variance, pilot.image ** 2 + 1e-2
    for p in range(first_pass, first_pass + spp):
        if time_limit is not None and passes > 0 and time.perf_counter() - t0 > time_limit:
            break
        passes += 1
        image_so_far = sum(s.total() for s in sums.values()) / (passes - 1) if passes > 1 else None
        if pbl.surface_paths > 0:
            k = np.full(npix, pbl.surface_paths, np.int64)
        else:  # auto: from the passes so far, once two are in (the image so far weighs them as relMSE does)
            k = stats.next_paths(image_so_far, spp - passes + 1) if image_so_far is not None else None
            if k is None:
                k = first_k if first_k is not None else np.full(npix, pbl.first_paths, np.int64)
        ks.append(float(k.mean()))
        # (like the auto counts, the share follows the passes before: with a fixed count k every ray plays, so that
        # a part of a render repeats its passes bit for bit, docs/distributed.md)
        share = stats.next_diffuse_share(image_so_far, k) if pbl.diffuse_shares and pbl.surface_paths == 0 else 1.0
        shares.append(share)
        diffuse = DiffuseShare(share, image_so_far ** 2 + 1e-2 if image_so_far is not None else pilot_den)
        media_data = media_for_pass(p)
        caustics = caustics if p == first_pass else caustics_of(p)
        pbl_p = _pass_settings(pbl, p)
        entry_p = entry.for_pass(p) if entry is not None else None
        segment_p = segment.for_pass(p, caster) if segment is not None else None
        # which of the pixel's k paths evaluates the medium in this pass (k = 1: every path)
        draw = np.random.default_rng([seed, p, 0x5EC7])
        if k.min() == k.max():
            chosen = draw.integers(0, k[0], npix) if k[0] > 1 else np.zeros(npix, np.int64)
        else:
            chosen = draw.integers(0, k)
        pixels, samples, ranks = pass_paths(k, samples_so_far)
        evm = ranks == chosen[pixels]
        # the paths that evaluate the medium first, in batches of their own: the smooth terms are shared among the
        # points of a batch (radiance_cache), and batches mixing them with the surface-only paths held k times fewer
        first = np.argsort(~evm, kind="stable")
        pixels, samples, evm = pixels[first], samples[first], evm[first]
        acc = {name: np.zeros((npix, 3)) for name in names}
        surface_sq = np.zeros((npix, 3))
        per_pass = len(pixels)
        single = DeferredSingle()  # the lights' single scattering, evaluated for many batches at once
        # the smooth terms' bins, evaluated for many batches and depths at once
        # (a pixel's share of the image's relMSE per unit of its medium points' weight squared: those weights hold
        # its path count k, which its estimate divides by; the pilot's or the passes' image so far with auto
        # counts, none with a fixed count, whose passes follow nothing before them)
        den = diffuse.den.mean(axis=1) if diffuse.den is not None and pbl.surface_paths == 0 else np.ones(npix)
        bins = DeferredBins(np.random.default_rng([seed, p, 0xB125]), npix, 1.0 / (den * (k * k)), pbl.bin_splits)
        term_shares = {} if pbl.term_shares else None  # how often the bins evaluate double and multiple scattering
        # the medium's light after a first diffuse bounce, pooled among neighbouring vertices (diffuse_filter)
        vertices = single_v = None
        if pbl.diffuse_filter > 0 and entry is None and segment is None:
            vertices = DiffuseVertices(np.random.default_rng([seed, p, 0xD1F5]), pixel_angle(bs), pbl.diffuse_filter)
            single_v = DeferredSingle()
        # (the segment term marches every path's segments with the batch's random numbers: its batches stay whole)
        surface_chunk = SURFACE_CHUNK if segment is None else chunk
        for c0, c1 in batch_bounds(per_pass, int(evm.sum()), chunk, surface_chunk):
            part = slice(c0, c1)
            path_surface = _trace_batch(bs, caster, pool, threads, media_data, seed, done + c0, pixels[part],
                                        samples[part], evm[part], k[pixels[part]], npix, settings, settings_b,
                                        pbl_p, acc, single, entry_p, segment_p, term_shares, diffuse, bins, vertices,
                                        single_v, caustics)
            if single.full() or part.stop == per_pass:
                single.flush(pool, threads, acc["single"], npix)
            if vertices is not None and (single_v.full() or part.stop == per_pass):
                _flush_single_at_vertices(single_v, vertices, pool, threads)
            if part.stop == per_pass:
                bins.flush(pool, threads)
                if vertices is not None:
                    vertices.flush([acc[name] if name in acc else None for name in COMPONENTS])
            for ch in range(3):
                surface_sq[:, ch] += np.bincount(pixels[part], weights=path_surface[:, ch] ** 2, minlength=npix)
            if progress is not None:
                progress((passes - 1) * npix + part.stop * npix // per_pass, spp * npix)
        done += per_pass
        samples_so_far += k
        for name in names:
            sums[name].push(p, p + 1, acc[name] / k[:, None])
        stats.add(k, acc["surface"], surface_sq, sum(acc[c] for c in names if c != "surface") / k[:, None])
        stats.add_diffuse(diffuse, npix)
        # this pass's sample sets and buffers freed before the next pass builds its own: not both at once
        media_data = acc = surface_sq = pixels = samples = ranks = evm = first = path_surface = caustics = None
    caster.close()
    if pool is not None:
        pool.shutdown()
    out = layer_means(sums, passes, (H, W, 3))
    image = sum(out.values())
    return image, out, {"time_s": time.perf_counter() - t0, "spp": passes, "surface_paths": ks, "sums": sums,
                        "diffuse_shares": shares}


Pilot = namedtuple("Pilot", ["counts", "surface_variance", "image"])
Pilot.__doc__ = """What the pilot measured: the first two passes' path counts (npix,), one surface path's variance per
pixel relative to the pilot's image squared + 0.01 (npix,), and that image (npix, 3: the surfaces' light alone)."""


def pixel_angle(bs: BuiltScene) -> float:
    """A pixel's angular width at the image's centre (radians)."""
    cam = bs.camera
    return 2.0 * float(np.linalg.norm(cam[CAM_UP:CAM_UP + 3])) / float(cam[CAM_HEIGHT])


def _flush_single_at_vertices(single_v, vertices, pool, threads):
    """The single scattering found after first diffuse vertices (single_v: gather.DeferredSingle whose 'pixels' are
    vertex ids) into their store (DiffuseVertices)."""
    if single_v.count == 0:
        return
    layer = np.zeros((vertices.count, 3))
    single_v.flush(pool, threads, layer, vertices.count)
    light = np.zeros((vertices.count, len(COMPONENTS), 3))
    light[:, LAYER_SINGLE] = layer
    vertices.accumulate(np.arange(vertices.count), light)


def _pass_settings(pbl, p: int):
    """pbl (config.PblSettings) as pass p takes it: without the peak's deflections before peak_deflections_from."""
    if pbl.peak_deflections and p < pbl.peak_deflections_from:
        return pbl.model_copy(update={"peak_deflections": False})
    return pbl


def _pilot(bs, caster, pool, threads, seed: int, npix: int, width: int, pbl, settings, settings_b) -> Pilot:
    """The first passes' path counts (pilot_surface_paths) from pbl.pilot_paths surface-only camera paths per pixel,
    each pixel's variance and mean taken over its own paths or (pbl.pilot_pool) over the paths of its 3 x 3
    neighbourhood, traced before them with sample indices and random streams of their own (from PILOT_FIRST_SAMPLE): the counts
    are independent of the paths they weigh, so the image stays unbiased; the pilot's light is not in the image."""
    per = pbl.pilot_paths
    total, total_sq = np.zeros((npix, 3)), np.zeros((npix, 3))
    ranks = np.repeat(np.arange(per, dtype=np.int64)[None, :], npix, axis=0).ravel()
    pixels = np.repeat(np.arange(npix, dtype=np.int64), per)
    kpaths = np.full(npix, per, np.int64)
    # the layers the paths add into, never read (the pilot's light is each path's): one set for all batches
    layers = {name: np.zeros((npix, 3)) for name in (*COMPONENTS, "surface")}
    for c0 in range(0, len(pixels), SURFACE_CHUNK):
        part = slice(c0, c0 + SURFACE_CHUNK)
        n = len(pixels[part])
        light = _trace_batch(bs, caster, pool, threads, {}, seed, PILOT_FIRST_SAMPLE + c0, pixels[part],
                             PILOT_FIRST_SAMPLE + ranks[part], np.zeros(n, np.bool_), kpaths[pixels[part]], npix,
                             settings, settings_b, pbl, layers, DeferredSingle())
        add_rows(total, pixels[part], light)  # (np.bincount's sums where a pixel's paths lie in one batch)
        add_rows(total_sq, pixels[part], light * light)
    if pbl.pilot_pool:
        # each pixel's variance from the paths of its 3 x 3 neighbourhood: a rare hit (a small light's mirror image)
        # found by any of them raises the pixel's count, so that one path a pixel finds what four a pixel found
        # alone, at a quarter of the cost (docs/pbl.md, section 9, "A pooled pilot")
        total, total_sq = neighbourhood_sums(total, width), neighbourhood_sums(total_sq, width)
        per *= 9
    mean = total / per
    var = np.maximum(total_sq - total * mean, 0.0) / max(per - 1, 1)
    relative = (var / (mean ** 2 + 1e-2)).mean(axis=1)
    return Pilot(pilot_surface_paths(relative, width, pbl.first_paths), relative, mean)


def neighbourhood_sums(values: np.ndarray, width: int) -> np.ndarray:
    """Each pixel's sum of values (npix, c) over its 3 x 3 neighbourhood, the image's edge rows and columns
    repeated beyond it (every pixel sums nine)."""
    img = values.reshape(-1, width, values.shape[1])
    h = img.shape[0]
    pad = np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="edge")
    return sum(pad[1 + dy:1 + dy + h, 1 + dx:1 + dx + width] for dy in (-1, 0, 1)
               for dx in (-1, 0, 1)).reshape(values.shape)


def first_path_indices(surface_paths: int, first_pass: int, npix: int) -> tuple[int, int]:
    """(camera paths traced before pass first_pass, each pixel's first sample index): what seeds the camera paths'
    random streams. With a fixed count k both are what a render from pass 0 reaches there, so a render of passes
    A..B-1 repeats those passes of a longer render exactly. With auto counts they depend on the passes before, which
    a part does not render: its streams then start past any the earlier passes can use (AUTO_MAX_PIXEL_PATHS a
    pixel and pass), independent of them, and its counts follow its own passes."""
    k = surface_paths if surface_paths > 0 else AUTO_MAX_PIXEL_PATHS
    return first_pass * npix * k, first_pass * k


def _channel_max(a):
    """The largest of each row's three channels (a: (n, 3)): numpy's max along a 3-wide axis is 6x slower."""
    return np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2])


@njit(cache=True)
def add_rows(target, index, values):
    """target[index[j]] += values[j] for each row j in order (3 channels): np.add.at's sums, and np.bincount's
    into a layer, at a fraction of their cost for the small wavefronts of a camera batch (both cost a pass over
    the whole image, or were slow)."""
    for j in range(index.shape[0]):
        for c in range(3):
            target[index[j], c] += values[j, c]


@njit(inline="always", cache=True)
def _child_state(parent_state, slot):
    """The random state a child in `slot` starts from (its parent's, turned per slot)."""
    return parent_state ^ (np.uint64(0x9E37) * np.uint64(slot % 2 + 1))


@njit(parallel=True, cache=True)
def _next_rays(children, ng, depth, pixel, evm, path, kpaths, rng, min_beta, roulette):
    """The next generation of camera rays: the children (Children, slot 2 i + 1 the transmitted child of ray i)
    that exist and carry more than min_beta in some channel, with what they inherit from their parent ray i (the
    surface normal ng there, the depth + 1, pixel, evm, path, kpaths and the random state, turned per slot). A
    child of weight b below `roulette` (its largest channel) goes on with probability b / roulette, its weight
    divided by it (Russian roulette: unbiased).
    Returns (slots, pos, dir, beta, medium, state, depth, pixel, evm, path, kpaths, n_start, rng)."""
    beta = children.beta
    n = 0
    slots = np.empty(beta.shape[0], np.int64)
    boost = np.empty(beta.shape[0])  # 1 / the child's survival probability
    for s in range(beta.shape[0]):
        if not children.ok[s]:
            continue
        b = max(beta[s, 0], max(beta[s, 1], beta[s, 2]))
        if b <= min_beta:
            continue
        q = 1.0
        if b < roulette:  # its own uniform number: the child's random state mixed with a stream of its own
            q = b / roulette
            z = mix64(_child_state(rng[s >> 1], s) ^ _ROULETTE_STREAM)
            if (z >> np.uint64(11)) * _INV_2_53 >= q:
                continue
        slots[n] = s
        boost[n] = 1.0 / q
        n += 1
    slots = slots[:n]
    o_pos, o_dir, o_beta, o_start = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    o_medium, o_state, o_depth = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    o_pixel, o_evm, o_path = np.empty(n, pixel.dtype), np.empty(n, np.bool_), np.empty(n, path.dtype)
    o_kpaths, o_rng = np.empty(n, kpaths.dtype), np.empty(n, np.uint64)
    for j in prange(n):  # each child writes its own row: the same arrays for any thread count
        s = slots[j]
        i = s >> 1
        for c in range(3):
            o_pos[j, c] = children.pos[s, c]
            o_dir[j, c] = children.dir[s, c]
            o_beta[j, c] = beta[s, c] * boost[j]
            o_start[j, c] = ng[i, c]  # a child leaves the surface its parent met
        o_medium[j], o_state[j], o_depth[j] = children.medium[s], children.state[s], depth[i] + 1
        o_pixel[j], o_evm[j], o_path[j], o_kpaths[j] = pixel[i], evm[i], path[i], kpaths[i]
        o_rng[j] = _child_state(rng[i], s)
    return (slots, o_pos, o_dir, o_beta, o_medium, o_state, o_depth, o_pixel, o_evm, o_path, o_kpaths, o_start,
            o_rng)


@njit(cache=True)
def _attenuate(beta, idx, t, sigma_t):
    """beta[i] *= e^(-sigma_t t[i]) per channel for the rays idx (their transmittance over t)."""
    for j in range(idx.shape[0]):
        i = idx[j]
        for c in range(3):
            beta[i, c] *= math.exp(-sigma_t[c] * t[i])


def _roulette(ms, beta, kpaths, u, threshold: float):
    """The paths of ms that evaluate a term, those of weight beta_max below `threshold` with probability
    beta_max / threshold (u: a uniform number per path), and the weights they evaluate it with (beta divided by
    that probability, times the pixel's path count kpaths): unbiased."""
    q = np.minimum(1.0, _channel_max(beta[ms]) / max(threshold, 1e-300))
    keep = u < q
    ev = ms[keep]
    weight = beta.copy()
    weight[ev] /= (q[keep] / kpaths[ev])[:, None]
    return ev, weight


def batch_bounds(n: int, n_medium: int, chunk: int, surface_chunk: int) -> list[tuple[int, int]]:
    """The batches (start, end) of a pass's n camera paths, those that evaluate the medium first (n_medium of them):
    `chunk` paths a batch while a batch starts among those (their bins are shared within a batch), then
    `surface_chunk` (a surface-only path's light is its own, and the medium's random numbers are drawn for the
    paths that evaluate it: any batch size gives the same image)."""
    bounds, c = [], 0
    while c < n:
        size = chunk if c < n_medium else surface_chunk
        bounds.append((c, min(c + size, n)))
        c += size
    return bounds


def _shares(term_shares, m, kind: str):
    """The pass's TermShares of medium m's lit or bounced samples (made on first use), or None."""
    return None if term_shares is None else term_shares.setdefault((int(m), kind), TermShares())


def _measure_shares(bins, pool, threads, state, idx):
    """Flushes bins (radiance_cache.DeferredBins, or None) before segments idx are evaluated when some of them come
    after a diffuse bounce (evaluated point by point with the term shares the bins measure) and the bins hold
    terms whose shares are not measured yet."""
    if bins is not None and bins.unmeasured() and bool(((state[idx] >> 2) > 0).any()):
        bins.flush(pool, threads)


def _trace_batch(bs, caster, pool, threads, media_data, seed, done, pixels, samples, evm, kpaths, npix, settings,
                 settings_b, pbl, layers, single, entry=None, segment=None, term_shares=None, dshare=None, bins=None,
                 vertices=None, single_v=None, caustics=None):
    """Camera paths (sample samples[i] of pixel pixels[i]; `done` paths traced before them in this render), traced to
    the end, added into layers; the lights' single scattering into single (gather.DeferredSingle), which the caller
    flushes into layers["single"]; term_shares: the pass's radiance_cache.TermShares by (medium, "lit" or
    "bounced"), filled as the bins are evaluated (None: every bin evaluates every term); dshare: the pass's
    DiffuseShare (the share of the rays after a diffuse bounce that evaluate the smooth terms, and their second
    moment measured; None: all of them, not measured); bins: the pass's radiance_cache.DeferredBins, which takes
    the smooth terms of the segments not after a diffuse bounce (flushed here when it is full, or before segments
    after a diffuse bounce take shares it has not measured yet; the caller flushes the rest; None: each depth's
    bins evaluated at once); vertices: the pass's diffuse_filter.DiffuseVertices, which takes the medium's light
    found after a path's first diffuse bounce (its single scattering through single_v, a DeferredSingle keyed by
    vertex; None: the light goes to the path's pixel); caustics: the pass's caustics.CausticMap, gathered at the
    diffuse surfaces the paths meet (None: the camera paths find the caustics themselves). Path i
    evaluates
    the medium where evm[i], its medium terms weighted kpaths[i] (its pixel's path count in this pass), and the
    entry term (render_pbl) where it enters a medium. Returns each path's surface light (n, 3)."""
    n = len(pixels)
    pos, dirs = np.zeros((n, 3)), np.zeros((n, 3))
    rng = np.zeros(n, np.uint64)
    camera_rays_for(bs.camera, seed, pixels, samples, pos, dirs, rng)
    pixel = pixels
    path = np.arange(n)  # each ray's camera path within the batch
    path_surface = np.zeros((n, 3))
    beta = np.ones((n, 3))
    roulette_rng = np.random.default_rng([seed, done])
    medium = np.full(n, -1, np.int64)
    depth = np.zeros(n, np.int64)
    state = np.zeros(n, np.int64)  # see _interact_rays
    n_start = np.full((n, 3), np.nan)  # the normal of the surface each ray leaves (NaN: the camera)
    limits = PathLimits(bs.eps, pbl.max_split_depth, pbl.diffuse_bounces,
                        0 if segment is None else 2 if segment.through_dielectrics else 1, caustics is not None)
    cache, cache_b = cache_settings(pbl), cache_settings(pbl, single=True)  # the bounced light is smooth throughout
    p_diffuse = dshare.p if dshare is not None else 1.0
    entered = np.zeros(n)  # eta beyond / eta before where a ray has just entered a medium (0: it has not)
    vertex = np.full(n, -1, np.int64)  # each ray's first diffuse vertex in vertices (-1: none yet, or no filter)
    travelled = np.zeros(n)  # the distance each ray's path has gone from the camera (a vertex's pixel footprint)
    # the truncated peak's deflections (peak_deflections.py): each medium's rate, each path's deflections so far, and
    # the rays that start at a deflection, whose segment's medium terms were gathered straight on (see below)
    rates = peak_rates(bs.media) if pbl.peak_deflections else None
    turns = np.zeros(n, np.int64)
    gathered = np.zeros(n, np.bool_)
    while len(pos):
        t, surf, ng, ns = closest_surface_hits(caster, bs, pos, dirs)
        tl, li = np.empty(len(pos)), np.empty(len(pos), np.int64)
        light_hits(bs.lights, pos, dirs, t, tl, li, np.full(len(pos), -1, np.int64))
        tev = np.minimum(t, tl)
        turned, d_turn, dir_turn = np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3))
        if rates is not None:  # a deflection before the surface ends the path's segment there
            turned, d_turn, dir_turn, advanced = draw_deflections(rates, bs.media, dirs, tev, medium, turns, rng)
            rng[turned] = advanced
        # The medium's terms are gathered straight on to the surface ahead, as without the deflections, and not
        # again along the pieces after a deflection: their light (the camera side up to a wider scattering) changed
        # little with the deflections, the light the path finds beyond the medium most (docs/pbl.md, section 2),
        # and along the pieces it cost 2.4 times the pass
        length = tev.copy()  # what each ray travels: to its deflection where it turns
        length[turned] = d_turn
        inside = np.flatnonzero((medium >= 0) & np.isfinite(tev))
        evaluates = evm & ~gathered if rates is not None else evm
        # the boundary planes of the segments that evaluate the medium (the kernels read no other row)
        need = inside[evaluates[inside]]
        planes = contrib = None
        if len(need):
            contrib = np.zeros((len(pos), 4, 3))  # medium terms per ray: zero but in rows of need
            planes = np.zeros((len(pos), PLANE_COLS))
            planes[need] = segment_planes(pos[need], dirs[need], t[need], n_start[need], ng[need])
        for m in np.unique(medium[inside]):
            sub = inside[medium[inside] == m]
            lit, bounced = media_data.get(int(m), (None, None))
            ms = sub[evaluates[sub]]  # the paths that evaluate the medium in this pass
            med = lit.medium if lit is not None else medium_params(bs.media, int(m))  # (lit's: with its faces)
            if lit is not None and lit.count and len(ms):
                # weak branches (internal reflections) are evaluated with probability beta_max / roulette,
                # their weight divided by it: unbiased, and most of the cost was in branches of weight < 0.01.
                # Single scattering has a threshold of its own: a branch's single scattering costs a few point
                # evaluations, its smooth terms may cost a bin's light cut (docs/pbl.md, camera paths)
                u = roulette_rng.random(len(ms))
                ev, beta_ev = _roulette(ms, beta, kpaths, u, pbl.roulette)
                if settings.single:
                    ev_s, beta_s = _roulette(ms, beta, kpaths, u, pbl.roulette_single)
                    # kmax points a segment, kmax_diffuse random ones after a diffuse bounce (as gather._segment)
                    diffuse = (state >> 2)[ev_s] > 0
                    after = ev_s[diffuse]
                    if vertices is not None:  # pooled at the paths' first diffuse vertices (diffuse_filter)
                        single_v.add(int(m), lit.kernel, med, after[vertex[after] >= 0], pos, dirs, beta_s, tev, rng,
                                     settings.kmax_diffuse, planes, vertex)
                        after = after[vertex[after] < 0]
                    for part, kmax in ((after, settings.kmax_diffuse), (ev_s[~diffuse], settings.kmax)):
                        single.add(int(m), lit.kernel, med, part, pos, dirs, beta_s, tev, rng, kmax, planes, pixel)
                if settings.double or settings.multiple:
                    s_lit, q_lit = settings._replace(single=False), _shares(term_shares, m, "lit")
                    defer = None if bins is None else partial(
                        bins.add, (int(m), "lit"), lit.kernel, med, s_lit, cache, q_lit,
                        (None, layers["double"], layers["multiple"]), pixel=pixel)
                    _measure_shares(bins, pool, threads, state, ev)
                    eval_segments(pool, threads, ev, pos, dirs, beta_ev, tev, rng, med, lit.kernel, s_lit, contrib,
                                  state >> 2, planes, cache, roulette_rng, q_lit, p_diffuse, defer)
                if bounced is not None and bounced.count:
                    qb = min(1.0, scattered_share(lit, bounced) / BOUNCED_ROULETTE)
                    evb = ev[roulette_rng.random(len(ev)) < qb]
                    beta_b = beta_ev / qb
                    cb3 = np.zeros((len(pos), 3, 3))
                    q_b = _shares(term_shares, m, "bounced")
                    defer = None if bins is None else partial(
                        bins.add, (int(m), "bounced"), bounced.kernel, med, settings_b, cache_b, q_b,
                        (layers["bounced"],) * 3, pixel=pixel)  # (its three terms make the bounced layer)
                    _measure_shares(bins, pool, threads, state, evb)
                    eval_segments(pool, threads, evb, pos, dirs, beta_b, tev, rng, med, bounced.kernel, settings_b,
                                  cb3, state >> 2, planes, cache_b, roulette_rng, q_b, p_diffuse, defer)
                    contrib[evb, LAYER_BOUNCED] += cb3[evb, 0] + cb3[evb, 1] + cb3[evb, 2]  # (the rows it wrote)
            if entry is not None:
                _add_entry_term(entry, int(m), sub[evm[sub] & (entered[sub] > 0)], pos, beta, kpaths, entered,
                                pixel, npix, layers)
            if segment is not None:
                sub_rng = rng[sub]
                # weak branches (internal reflections, the glass's many splits) gather with probability
                # beta_max / roulette, their light divided by it: unbiased, as pbl's medium terms above
                q = np.minimum(1.0, _channel_max(beta[sub]) / max(pbl.roulette, 1e-300))
                gather = evm[sub] & (roulette_rng.random(len(sub)) < q)
                radiances, transmittance = segment.march(caster, int(m), pos[sub], dirs[sub], tev[sub], sub_rng,
                                                         gather)
                rng[sub] = sub_rng
                for name, radiance in zip(segment.layers, radiances):
                    value = radiance * (beta[sub] / np.maximum(q, 1e-300)[:, None]) * kpaths[sub, None]
                    for ch in range(3):
                        layers[name][:, ch] += np.bincount(pixel[sub], weights=value[:, ch], minlength=npix)
                beta[sub] *= transmittance
            else:
                _attenuate(beta, sub, length, sum(bs.medium_sigmas(m)))
        if bins is not None and bins.full():
            bins.flush(pool, threads)
        if len(need) and dshare is not None:  # the smooth terms after a diffuse bounce, for the next shares
            after = need[(state >> 2)[need] > 0]
            dshare.add(pixel[after], kpaths[after], contrib[after, LAYER_DOUBLE:].sum(axis=1))
        if len(need) and vertices is not None:  # after a first diffuse vertex: pooled there (diffuse_filter)
            pooled = need[vertex[need] >= 0]
            vertices.accumulate(vertex[pooled], contrib[pooled])
            need = need[vertex[need] < 0]
        if len(need):  # contrib is zero where no segment evaluated the medium
            for c, name in zip((LAYER_SINGLE, LAYER_DOUBLE, LAYER_MULTIPLE, LAYER_BOUNCED), COMPONENTS):
                add_rows(layers[name], pixel[need], contrib[need, c])
        k = len(pos)
        emit = np.zeros((k, 3))
        # (empty: _interact sets every slot's ok flag, and the rest of the slots it keeps)
        children = Children(np.empty((2 * k, 3)), np.empty((2 * k, 3)), np.empty((2 * k, 3)),
                            np.empty(2 * k, np.int64), np.empty(2 * k, np.bool_), np.empty(2 * k, np.int64))
        ks = k * len(bs.lights)
        shadows = ShadowRays(np.empty((ks, 3)), np.empty((ks, 3)), np.empty(ks), np.empty((ks, 3)),
                             np.empty(ks, np.bool_))
        li = np.where(tl < t, li, -1)
        tev = length
        li[turned], surf[turned] = -1, -1  # a deflected ray meets no surface (_interact: no child, no shadow ray)
        new_vertex = None
        travelled = travelled + np.where(np.isfinite(tev), tev, 0.0)
        if caustics is not None:
            _gather_caustics(caustics, bs, pos, dirs, beta, tev, surf, ng, li, depth, travelled, pbl, emit)
        if vertices is not None:
            new_vertex = _first_diffuse_vertices(vertices, bs, pos, dirs, beta, tev, surf, ng, li, evm, state, depth,
                                                 kpaths, pixel, travelled, pbl)
        # the hit distance is to what the ray meets: the emitter's where one is in front (a sphere light's side
        # is judged at that point)
        _interact(bs.surfaces, bs.lights, Rays(pos, dirs, beta, medium, depth, rng, state), Hits(tev, surf, ng, ns, li),
                  limits, emit, children, shadows)
        if len(turned):  # instead: one child in the reflected slot, turned where the segment ended, no light met
            emit[turned] = 0.0
            j = 2 * turned
            children.pos[j] = pos[turned] + tev[turned, None] * dirs[turned]
            children.dir[j], children.beta[j], children.medium[j] = dir_turn, beta[turned], medium[turned]
            children.ok[j], children.state[j] = True, state[turned]
            ng[turned] = np.nan  # (the child's start: no surface)
        sidx = np.flatnonzero(shadows.ok)
        if len(sidx) and segment is not None:  # through null boundaries and the media (heterogeneous ones too)
            tr = segment.shadow(caster, shadows.pos[sidx], shadows.dir[sidx], shadows.dist[sidx],
                                sidx % len(bs.lights), medium[sidx // len(bs.lights)])
            add_rows(emit, sidx // len(bs.lights), shadows.contrib[sidx] * tr)
        elif len(sidx):
            vis = sidx[visible(caster, bs, shadows.pos[sidx], shadows.dir[sidx], shadows.dist[sidx],
                               sidx % len(bs.lights))]
            add_rows(emit, vis // len(bs.lights), shadows.contrib[vis])
        add_rows(layers["surface"], pixel, emit)
        add_rows(path_surface, path, emit)
        parent_dirs, parent_surf, parent_medium = dirs, surf, medium
        slots, pos, dirs, beta, medium, state, depth, pixel, evm, path, kpaths, n_start, rng = _next_rays(
            children, ng, depth, pixel, evm, path, kpaths, rng, 1e-5, pbl.surface_roulette)
        if vertices is not None:  # a child keeps its parent's first diffuse vertex, or the one its parent met
            parent = slots >> 1
            vertex = np.where(vertex[parent] >= 0, vertex[parent], new_vertex[parent])
        travelled = travelled[slots >> 1]
        if rates is not None:  # a deflection is no interaction: the child keeps its parent's depth
            from_turn = np.zeros(len(parent_dirs), np.bool_)
            from_turn[turned] = True
            from_turn = from_turn[slots >> 1] & (slots % 2 == 0)
            depth[from_turn] -= 1
            turns = turns[slots >> 1] + from_turn
            gathered = from_turn
        if entry is not None:
            entered = _entered(bs.surfaces, slots, slots >> 1, parent_surf, parent_dirs, ng, parent_medium, medium)
    return path_surface


def _gather_caustics(cmap, bs, pos, dirs, beta, tev, surf, ng, li, depth, travelled, pbl, emit):
    """The caustic light (cmap: caustics.CausticMap) that the rays meeting a diffuse surface reflect toward the
    camera, beta x albedo / pi x the map's irradiance there, into emit: at the hits where _interact_rays shades a
    diffuse surface (no emitter in front, below the split depth)."""
    s = np.maximum(surf, 0)
    hit = np.flatnonzero((li < 0) & (surf >= 0) & np.isfinite(tev) & (depth < pbl.max_split_depth)
                         & (bs.surfaces[s, SURF_TYPE] == DIFFUSE))
    if len(hit) == 0:
        return
    d = dirs[hit]
    facing = -np.sign(np.einsum("ij,ij->i", d, ng[hit]))[:, None] * ng[hit]  # the side the ray came from
    e = irradiance(cmap, pos[hit] + tev[hit, None] * d, facing, travelled[hit])
    add_rows(emit, hit, beta[hit] * bs.surfaces[s[hit], SURF_ALBEDO:SURF_ALBEDO + 3] / math.pi * e)


def _first_diffuse_vertices(vertices, bs, pos, dirs, beta, tev, surf, ng, li, evm, state, depth, kpaths, pixel,
                            travelled, pbl) -> np.ndarray:
    """The rays (of paths that evaluate the medium) meeting their first diffuse surface, where _interact_rays bounces
    them, into vertices (DiffuseVertices) with weight beta x albedo x their pixel's path count: each ray's new vertex
    id (-1: none). Every such hit is a vertex, its bounce drawn below the surface or not (then it finds nothing)."""
    new_vertex = np.full(len(pos), -1, np.int64)
    if pbl.diffuse_bounces <= 0:
        return new_vertex
    s = np.maximum(surf, 0)
    hit = ((li < 0) & (surf >= 0) & np.isfinite(tev) & evm & ((state >> 2) == 0) & (depth < pbl.max_split_depth)
           & (bs.surfaces[s, SURF_TYPE] == DIFFUSE))
    iv = np.flatnonzero(hit)
    if len(iv) == 0:
        return new_vertex
    d = dirs[iv]
    facing = -np.sign(np.einsum("ij,ij->i", d, ng[iv]))[:, None] * ng[iv]  # the side the path came from
    weight = beta[iv] * bs.surfaces[s[iv], SURF_ALBEDO:SURF_ALBEDO + 3] * kpaths[iv, None]
    new_vertex[iv] = vertices.add(pos[iv] + tev[iv, None] * d, facing, surf[iv], travelled[iv], weight, pixel[iv])
    return new_vertex


def _entered(surfaces, slots, parent, surf, dirs, ng, medium, child_medium) -> np.ndarray:
    """For the children in `slots` (2 parent + 1: transmitted), eta beyond / eta before where the child has just
    crossed into a medium other than its parent's, 0 for the others (dirs, ng, medium, surf: the parents')."""
    s = surf[parent]
    into = (slots % 2 == 1) & (child_medium >= 0) & (child_medium != medium[parent]) & (s >= 0)
    s = np.where(into, s, 0)
    from_outside = (dirs[parent] * ng[parent]).sum(axis=1) < 0.0
    e_in, e_out = surfaces[s, SURF_ETA_IN], surfaces[s, SURF_ETA_OUT]
    return np.where(into, np.where(from_outside, e_in / e_out, e_out / e_in), 0.0)


def _add_entry_term(entry, m: int, idx, pos, beta, kpaths, entered, pixel, npix, layers):
    """The entry term of the rays idx, which have just entered medium m at pos: radiance(...) leaves the boundary
    outward as F_t radiance(...); the ray's weight already holds F_t (eta_before / eta_beyond)^2."""
    if len(idx) == 0:
        return
    value = entry.radiance(m, pos[idx], entered[idx]) * (beta[idx] * (kpaths[idx] * entered[idx] ** 2)[:, None])
    for ch in range(3):
        layers[entry.layer][:, ch] += np.bincount(pixel[idx], weights=value[:, ch], minlength=npix)
