"""Point-based light transport, camera side (Wang et al. 2016, sec. 3.6-3.11, eq. 9).

Camera paths are traced in a wavefront like volpath, but split at smooth interfaces: the reflected and the refracted
branch are both followed, weighted by Fresnel (F and (1 - F) (eta_i/eta_t)^2), up to a split depth, so the image
carries no noise from choosing between them. Each segment a path travels inside a medium (length d_max) gets k_max
points at stratified depths d_k = -log(1 - u_k (1 - exp(-s d_max))) / s (s: the smallest sigma_t of the medium,
u_k = (k + xi)/k_max), weighted per channel by exp(-sigma_t d_k) / pdf(d_k); the in-scattered radiance at each
point comes from the light samples (estimators.py). Branches of small weight evaluate the medium by Russian
roulette. Diffuse surfaces take one shadow ray per light and continue by cosine-sampled bounces (indirect light);
emitters and the environment seen directly or through specular chains add their radiance (see _interact for when
a shadow ray has already counted them).

Light reflected by the medium's boundary after scattering (sec. 3.10) comes as a second set of volume samples per
medium (pointbased/bounced.py), evaluated by the same estimators into the `bounced` layer.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from types import SimpleNamespace

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.raycast import TriangleCaster
from pbvol_cli.geometry.scene_build import (DIELECTRIC, DIFFUSE, MED_G, MED_PHASE, MED_SIGMA_A, MED_SIGMA_S, MIRROR, NULL,
                                           SURF_ALBEDO, SURF_TYPE, BuiltScene)
from pbvol_cli.physics.fresnel import reflect, refract
from pbvol_cli.physics.lights import ENVIRONMENT, LIGHT_RGB, LIGHT_TYPE, emitted_toward, light_sample
from pbvol_cli.physics.sampling import cosine_hemisphere, depth_of_fraction, rand, seed_state
from pbvol_cli.pointbased.estimators import END_EXTENSION, double_multiple, single_scattering
from pbvol_cli.render.camera import generate_camera_rays
from pbvol_cli.render.interfaces import dielectric_fresnel, incident_side, indices, medium_beyond, shadow_ray_length
from pbvol_cli.geometry.intersect import closest_surface_hits, light_hits, visible

COMPONENTS = ("single", "double", "multiple", "bounced")


@njit(cache=True)
def _segment(i, pos, dirs, beta, tseg, rng, med, md, settings, out, diffuse, planes):
    """Medium contribution of ray i over [0, tseg[i]] into out[i, component, channel]. A ray after a diffuse bounce
    (diffuse[i] > 0) takes settings[7] random points for every component (sec. 3.6: averaged over the bounces).
    planes[i]: the boundary's tangent planes where the segment starts and ends (segment_planes), the nearer of
    which is each point's for the multiple term's image."""
    tree, v_start, v_dir, v_len, v_power, v_area, v_centre, v_scat, v_rb, tabs, v_ends, v_plane, r_near = md
    sig_a, sig_s = med[MED_SIGMA_A:MED_SIGMA_A + 3], med[MED_SIGMA_S:MED_SIGMA_S + 3]
    kind, g = int(med[MED_PHASE]), med[MED_G]
    kmax, cut_size, rclamp, k2 = int(settings[0]), int(settings[1]), settings[2], int(settings[6])
    do_s, do_d, do_m = settings[3] > 0, settings[4] > 0, settings[5] > 0
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
        n = kmax if comp == 0 else k2
        if diffuse[i] > 0:
            n = int(settings[7])
        if (comp == 0 and not do_s) or (comp == 1 and not (do_d or do_m)):
            continue
        for k in range(n):
            u = (k + xi) / n * frac
            if s > 0.0:
                d = depth_of_fraction(u, s)
                pdf = s * math.exp(-s * d) / frac
            else:
                d = u * dmax
                pdf = 1.0 / dmax
            px, py, pz = pos[i, 0] + d * dirs[i, 0], pos[i, 1] + d * dirs[i, 1], pos[i, 2] + d * dirs[i, 2]
            o[:] = 0.0
            o3[:] = 0.0
            if comp == 0:
                single_scattering(tree, v_start, v_dir, v_len, v_power, v_area, v_ends, v_plane, sig_a, sig_s, kind,
                                  g, px,
                                  py, pz, wx, wy, wz, o)
            else:
                # the start plane's depth is d cos, the end plane's (d_max - d) cos'
                e = 4 if (planes[i, 7] - (planes[i, 4] * px + planes[i, 5] * py + planes[i, 6] * pz)
                          < planes[i, 3] - (planes[i, 0] * px + planes[i, 1] * py + planes[i, 2] * pz)) else 0
                for c in range(4):
                    pplane[c] = planes[i, e + c]
                double_multiple(tree, v_start, v_dir, v_len, v_power, v_centre, v_scat, v_rb, v_plane, sig_a, sig_s,
                                kind, g,
                                px, py, pz, wx, wy, wz, cut_size, rclamp, r_near, do_d, do_m, tabs, o, o3, rng, i,
                                pplane)
            for c in range(3):
                w = beta[i, c] * math.exp(-(sig_a[c] + sig_s[c]) * d) / (pdf * n)
                if comp == 0:
                    out[i, 0, c] += w * o[c]
                else:
                    out[i, 1, c] += w * o[c]
                    out[i, 2, c] += w * o3[c]


@njit(nogil=True, cache=True)
def _eval_segments(idx, pos, dirs, beta, tseg, rng, med, md, settings, out, diffuse, planes):
    for k in range(idx.shape[0]):
        _segment(idx[k], pos, dirs, beta, tseg, rng, med, md, settings, out, diffuse, planes)


def segment_planes(pos, dirs, t, n_start, n_end):
    """(n, 8): the tangent planes n . x = q where each segment (from pos along dirs for t) starts and ends, normals
    oriented out of the segment's side (n_start . d < 0, n_end . d > 0), from the surfaces' normals there (NaN or
    an infinite t: no plane, q = inf). The multiple term mirrors its sources in the nearer one of each point."""
    out = np.zeros((len(pos), 8))
    out[:, 2] = out[:, 6] = 1.0
    out[:, 3] = out[:, 7] = np.inf
    for col, nrm, x, sgn in ((0, n_start, pos, -1.0), (4, n_end, pos + np.where(np.isfinite(t), t, 0.0)[:, None]
                                                        * dirs, 1.0)):
        if nrm is None:
            continue
        cos = np.einsum("ij,ij->i", nrm, dirs)
        ok = np.isfinite(cos) & (cos != 0.0) & (np.isfinite(t) if col == 4 else True)
        n = nrm[ok] * (sgn * np.sign(cos[ok]))[:, None]
        out[ok, col:col + 3] = n
        out[ok, col + 3] = np.einsum("ij,ij->i", n, x[ok])
    return out


def eval_segments(pool, threads, idx, pos, dirs, beta, tseg, rng, med, md, settings, out, diffuse, planes):
    """Numba's parallel loops reject nested tuples (the octree, the tables): threads over slices instead, the
    kernel releasing the GIL. Rays are independent, so the result does not depend on the split. planes: the
    segments' end planes (segment_planes)."""
    if threads <= 1 or len(idx) < 64:
        _eval_segments(idx, pos, dirs, beta, tseg, rng, med, md, settings, out, diffuse, planes)
        return
    # interleaved slices balance rays of different cost
    list(pool.map(lambda j: _eval_segments(idx[j::threads], pos, dirs, beta, tseg, rng, med, md, settings, out,
                                           diffuse, planes), range(threads)))


@njit(cache=True)
def _cosine_direction(u1, u2, nx, ny, nz):
    """cosine_hemisphere behind a call: inlined into _interact's parallel loop it trips numba's array analysis."""
    return cosine_hemisphere(u1, u2, nx, ny, nz)


@njit(parallel=True, cache=True)
def _interact(surfaces, media, lights, pos, dirs, beta, medium, depth, rng, t, surf, ng, ns, li, eps, max_depth,
              seed, emit, child_pos, child_dir, child_beta, child_med, child_ok, sh_pos, sh_dir, sh_dist, sh_C, sh_ok,
              state, child_state, max_diffuse):
    """Emission, then the surface at t: up to two children per ray (reflected, transmitted); at a diffuse surface,
    one shadow ray per light (slots i * n_lights + light) and, below max_diffuse bounces, one cosine-sampled
    child (slot 2i) for indirect light. state[i] = 4 x (diffuse bounces) + 2 x (a specular interface crossed
    since the last diffuse bounce) + ... : lights and the environment seen directly after a diffuse bounce are
    already counted by the shadow rays, which stop at every surface; seen through a specular chain (a caustic
    through the glass) they are not, and count."""
    nl = lights.shape[0]
    for i in prange(pos.shape[0]):
        child_ok[2 * i] = child_ok[2 * i + 1] = False
        for lk in range(nl):
            sh_ok[i * nl + lk] = False
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        n_diffuse = state[i] >> 2
        counts = n_diffuse == 0 or (state[i] & 2) != 0  # emission not already counted by a shadow ray
        if li[i] >= 0 and not counts:
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
        if depth[i] >= max_depth:
            continue
        hx, hy, hz = pos[i, 0] + t[i] * dx, pos[i, 1] + t[i] * dy, pos[i, 2] + t[i] * dz
        entering, gx, gy, gz, nx, ny, nz = incident_side(dx, dy, dz, ng[i, 0], ng[i, 1], ng[i, 2], ns[i, 0], ns[i, 1],
                                                         ns[i, 2])
        stype = surfaces[s, SURF_TYPE]
        if stype == DIFFUSE:
            # direct light from every light, one sample each (the environment by cosine-weighted directions)
            st = np.empty(1, np.uint64)
            st[0] = rng[i]
            for lk in range(nl):
                j = i * nl + lk
                sh_ok[j] = False
                u1, u2 = rand(st, 0), rand(st, 0)
                if lights[lk, LIGHT_TYPE] == ENVIRONMENT:
                    wx, wy, wz = _cosine_direction(u1, u2, nx, ny, nz)
                    dist, Lr, Lg, Lb = np.inf, lights[lk, LIGHT_RGB], lights[lk, LIGHT_RGB + 1], lights[lk, LIGHT_RGB + 2]
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
            if n_diffuse < max_diffuse:
                j = 2 * i
                wx, wy, wz = _cosine_direction(rand(st, 0), rand(st, 0), nx, ny, nz)
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
            child_state[j] = state[i] | 2
            child_ok[j] = True


BOUNCED_ROULETTE = 0.2  # bounced samples carrying less than this share of the scattered power are evaluated
# on that share / BOUNCED_ROULETTE of the camera segments


def bounced_share(md, mdb) -> float:
    """The bounced samples' scattered power relative to the lights' samples' (all channels together)."""
    a = float(md.scat.sum())
    return float(mdb.scat.sum()) / a if a > 0 else 0.0


NEAR_FIELD_RADII = 3.0  # double scattering's near field (summed exactly): at most this many median beam radii,
NEAR_FIELD_COUNT = 16.0  # and holding about this many segments (dense samples: the bumpy sphere's 900k, 3.6x slower)


def near_field_radius(start, dirs, length, rb) -> float:
    """Radius R of double scattering's exactly summed near field (estimators.double_multiple): NEAR_FIELD_RADII
    median beam radii, smaller where the segments are so dense that more than NEAR_FIELD_COUNT would pass within R
    of a point (segments per volume n, median length l: n (pi R^2 l + 4/3 pi R^3), the volume within R of a
    segment; the volume is the samples' bounding box, an over-estimate)."""
    if len(length) == 0:
        return 0.0
    ends = np.concatenate([start, start + length[:, None] * dirs])
    volume = float(np.prod(np.maximum(ends.max(axis=0) - ends.min(axis=0), 1e-9)))
    n, ell = len(length) / volume, float(np.median(length))
    roots = np.roots([4.0 / 3.0 * np.pi * n, np.pi * n * ell, 0.0, -NEAR_FIELD_COUNT])
    r_count = float(max(r.real for r in roots if abs(r.imag) < 1e-9 * max(1.0, abs(r)) and r.real > 0))
    return min(NEAR_FIELD_RADII * float(np.median(rb)), r_count)


SAMPLE_KEYS = ("v_start", "v_dir", "v_len", "v_power", "v_area", "v_medium", "v_ends", "v_plane")


def returned_samples(samples, medium: int, area_scale: float = 1.0) -> SimpleNamespace:
    """The volume samples of `medium` whose light scattered in a medium before it reached the surface samples
    (v_returned == 1: light that left and the scene sent back; the bounced layer's), as a namespace of v_*
    arrays, cross-sections scaled by area_scale."""
    sel = (samples.v_medium == medium) & (samples.v_returned == 1)
    out = SimpleNamespace(**{k: getattr(samples, k)[sel] for k in SAMPLE_KEYS})
    out.v_area = out.v_area * area_scale
    return out


class MediumData:
    """A medium's light samples prepared for the kernels: octree, per-sample arrays, its three tables."""

    def __init__(self, samples, medium: int, media_row: np.ndarray, tables: list, beam_width: float = 1.0):
        """samples: LightSamples (its volume samples of light that has not scattered before reaching the surface
        samples: v_returned == 0) or a namespace of v_* arrays (all taken)."""
        from pbvol_cli.pointbased.octree import build_octree

        sel = samples.v_medium == medium
        returned = getattr(samples, "v_returned", None)
        if returned is not None:
            sel &= returned == 0
        self.start = np.ascontiguousarray(samples.v_start[sel])
        self.dir = np.ascontiguousarray(samples.v_dir[sel])
        self.len = np.ascontiguousarray(samples.v_len[sel])
        self.power = np.ascontiguousarray(samples.v_power[sel])
        # single scattering's kernel: a disc of beam_width x the beam's own radius (area x beam_width^2)
        self.area = np.ascontiguousarray(samples.v_area[sel]) * beam_width ** 2
        st = media_row[MED_SIGMA_A:MED_SIGMA_A + 3] + media_row[MED_SIGMA_S:MED_SIGMA_S + 3]
        safe = np.where(st > 0, st, 1.0)
        absorbed = -np.expm1(-st[None, :] * self.len[:, None])
        self.scat = self.power * np.where(st > 0, media_row[MED_SIGMA_S:MED_SIGMA_S + 3] / safe, 0.0)[None, :] * absorbed
        self.centre = self.start + 0.5 * self.len[:, None] * self.dir
        rb = np.sqrt(self.area / np.pi)  # the kernel's radius: the boxes must hold it
        self.rb = rb / beam_width  # the beam's own radius: double scattering's 1/r^2 smoothing
        self.ends = np.ascontiguousarray(samples.v_ends[sel])
        self.plane = np.ascontiguousarray(samples.v_plane[sel])
        # boxes hold the kernel disc along the segment, continued at the boundary (estimators.END_EXTENSION)
        ext = END_EXTENSION * rb
        first = self.start - (ext * (self.ends & 1 > 0))[:, None] * self.dir
        end = self.start + (self.len + ext * (self.ends & 2 > 0))[:, None] * self.dir
        box_lo = np.minimum(first, end) - rb[:, None]
        box_hi = np.maximum(first, end) + rb[:, None]
        self.tree = build_octree(self.centre, box_lo, box_hi, self.dir, self.scat)
        self.r_near = near_field_radius(self.start, self.dir, self.len, self.rb)
        # tables: MSTable objects, or their render_args() already expanded (shared by every pass's samples)
        self.tabs = tuple(t if isinstance(t, tuple) else t.render_args() for t in tables)
        self.count = int(sel.sum())

    def kernel_tuple(self):
        return (self.tree.arrays(), self.start, self.dir, self.len, self.power, self.area, self.centre, self.scat,
                self.rb, self.tabs, self.ends, self.plane, self.r_near)


# surface_paths = 0 (auto): the first two passes trace AUTO_FIRST_PATHS paths per pixel; from then on each pass
# takes k = sqrt(PASS_COST_RATIO S1 / M) (auto_surface_paths), measured on the passes before it
AUTO_FIRST_PATHS = 8
AUTO_MAX_PATHS = 128
PASS_COST_RATIO = 20.0  # a pass's medium work (estimators, per-pass light and bounced samples) over one surface
# path per pixel, measured at 96x96 (4 spp, 8 and 32 paths): oil glass 3.5 s / 0.115 s = 30, wine glass 2.4 s /
# 0.145 s = 16. The optimum is flat in it (k goes as its square root; 2x off costs about 6 % of the efficiency),
# and a constant keeps the image independent of timings (the same seed gives the same image)


def auto_surface_paths(s1: float, m: float) -> int:
    """Camera paths per pixel for the next pass. A pass with k paths costs about c (k + R) (R = PASS_COST_RATIO)
    and leaves a variance S1 / k + M (S1: one surface path's, M: the medium evaluation's, both relative as
    compare's relMSE): the product, the error at equal time, is least at k = sqrt(R S1 / M)."""
    if not s1 > 0.0:
        return 1
    if not m > 0.0:
        return AUTO_MAX_PATHS
    return int(min(AUTO_MAX_PATHS, max(1, round(math.sqrt(PASS_COST_RATIO * s1 / m)))))


class _PassStatistics:
    """The two variances auto_surface_paths weighs, from the passes so far, relative per pixel and channel as
    compare's relMSE (over the image so far squared + 0.01): the surface paths' spread within a pass (one path's
    variance) and the medium's from pass to pass (one evaluation per pixel and pass)."""

    def __init__(self, npix: int):
        self.surface_var = np.zeros((npix, 3))  # sum over passes of the within-pass variance of one path
        self.surface_passes = 0
        self.medium_sum, self.medium_sq = np.zeros((npix, 3)), np.zeros((npix, 3))
        self.passes = 0

    def add(self, k: int, surface_sum, surface_sq, medium):
        """A pass: its per-pixel sum and sum of squares over its k surface paths, and its medium estimate."""
        if k > 1:
            self.surface_var += np.maximum(surface_sq - surface_sum ** 2 / k, 0.0) / (k - 1)
            self.surface_passes += 1
        self.medium_sum += medium
        self.medium_sq += medium ** 2
        self.passes += 1

    def next_paths(self, image) -> int | None:
        """k for the next pass, or None while two passes (one of them with k > 1) are not yet in."""
        if self.passes < 2 or self.surface_passes < 1:
            return None
        den = image ** 2 + 1e-2
        s1 = float((self.surface_var / self.surface_passes / den).mean())
        p = self.passes
        m = float((np.maximum(self.medium_sq - self.medium_sum ** 2 / p, 0.0) / (p - 1) / den).mean())
        return auto_surface_paths(s1, m)


def render_pbl(bs: BuiltScene, media_for_pass, spp: int, seed: int, settings: dict, threads: int,
               progress=None):
    """Renders spp passes; pass p uses the light samples media_for_pass(p) ({medium: (MediumData of the lights'
    samples, MediumData of the bounced samples or None)}). A pass traces k camera paths per pixel: all of them
    shade surfaces, and one of them, chosen uniformly at random per pixel and pass, also evaluates the medium, its
    medium terms weighted by k. The pixel's estimate stays unbiased and the medium's cost per pass is that of one
    path, while the surfaces' noise (path traced like volpath's) falls k times. k is settings["surface_paths"], or
    with 0 (auto) chosen per pass from the variances measured on the passes before it (auto_surface_paths): the
    oil and wine glasses' images are mostly surface noise, the milk's and the wax's mostly the medium's.
    Returns (image (H, W, 3), layers {name: (H, W, 3)}, stats; stats["surface_paths"]: k of each pass)."""
    W, H = bs.resolution
    npix = W * H
    fixed = int(settings.get("surface_paths", 1))
    sett = np.array([settings["kmax"], settings["cut_size"], settings["clamp"],
                     float("single" in settings["components"]), float("double" in settings["components"]),
                     float("multiple" in settings["components"]), settings["kmax_scattered"],
                     settings["kmax_diffuse"]])
    caster = TriangleCaster(bs.vertices, bs.faces, threads)
    pool = ThreadPoolExecutor(threads) if threads > 1 else None
    names = (*COMPONENTS, "surface")
    layers = {name: np.zeros((npix, 3)) for name in names}
    stats = _PassStatistics(npix)
    ks = []
    t0 = time.perf_counter()
    chunk = 1 << 18
    done = 0  # camera paths traced so far: path g is camera sample g // npix of pixel g % npix
    for p in range(spp):
        k = fixed
        if k == 0:  # auto: from the passes so far, once two are in (the image so far weighs them as relMSE does)
            k = (p and stats.next_paths(sum(layers.values()) / p)) or AUTO_FIRST_PATHS
        ks.append(k)
        media_data = media_for_pass(p)
        # which of the pixel's k paths evaluates the medium in this pass (k = 1: every path, as ever)
        chosen = np.random.default_rng([seed, p, 0x5EC7]).integers(0, k, npix) if k > 1 else np.zeros(npix, np.int64)
        per_pass = npix * k
        acc = {name: np.zeros((npix, 3)) for name in names}
        surface_sq = np.zeros((npix, 3))
        for c0 in range(0, per_pass, chunk):
            n = min(chunk, per_pass - c0)
            path_surface = np.zeros((n, 3))
            _trace_batch(bs, caster, pool, threads, media_data, seed, done + c0, n, npix, sett, settings,
                         acc, chosen, k, path_surface)
            pix = (done + c0 + np.arange(n)) % npix
            for ch in range(3):
                surface_sq[:, ch] += np.bincount(pix, weights=path_surface[:, ch] ** 2, minlength=npix)
            if progress is not None:
                progress(p * npix + (c0 + n) * npix // per_pass, spp * npix)
        done += per_pass
        for name in names:
            layers[name] += acc[name] / k
        stats.add(k, acc["surface"], surface_sq, sum(acc[c] for c in COMPONENTS) / k)
    caster.close()
    if pool is not None:
        pool.shutdown()
    out = {name: (v / spp).reshape(H, W, 3) for name, v in layers.items()}
    image = sum(out.values())
    return image, out, {"time_s": time.perf_counter() - t0, "spp": spp, "surface_paths": ks}


def _trace_batch(bs, caster, pool, threads, media_data, seed, done, n, npix, sett, settings, layers, chosen=None,
                 kpaths=1, path_surface=None):
    """n camera paths starting at global path index `done`, traced to the end, added into layers. Path g is
    camera sample g // npix of pixel g % npix; it evaluates the medium (weight kpaths) where its sample's index
    within its pass, (g // npix) % kpaths, is chosen[pixel] (a pass's k consecutive samples
    cover every residue once, wherever it starts). path_surface (n, 3): each path's surface light, added to."""
    sett_b = sett.copy()
    # the bounced samples' single, double and multiple all make the bounced layer (tests may take a subset)
    sett_b[3:6] = settings.get("bounced_estimators", (1.0, 1.0, 1.0))
    sett_b[0] = sett[6]  # bounced light is smooth along a ray: k_max_scattered points for its single scattering too
    pos, dirs = np.zeros((n, 3)), np.zeros((n, 3))
    pixel = np.zeros(n, np.int64)
    rng = np.zeros(n, np.uint64)
    generate_camera_rays(bs.camera, seed, done, n, pos, dirs, pixel, rng)
    gidx = np.arange(done, done + n, dtype=np.int64)
    path = np.arange(n)  # each ray's camera path within the batch
    evm = np.ones(n, np.bool_) if chosen is None else ((gidx // npix) % kpaths == chosen[pixel])  # evaluates the medium
    beta = np.ones((n, 3))
    roulette_rng = np.random.default_rng([seed, done])
    medium = np.full(n, -1, np.int64)
    depth = np.zeros(n, np.int64)
    state = np.zeros(n, np.int64)  # see _interact
    n_start = np.full((n, 3), np.nan)  # the normal of the surface each ray leaves (NaN: the camera)
    while len(pos):
        t, surf, ng, ns = closest_surface_hits(caster, bs, pos, dirs)
        tl, li = np.empty(len(pos)), np.empty(len(pos), np.int64)
        light_hits(bs.lights, pos, dirs, t, tl, li, np.full(len(pos), -1, np.int64))
        tev = np.minimum(t, tl)
        inside = np.flatnonzero((medium >= 0) & np.isfinite(tev))
        contrib = np.zeros((len(pos), 4, 3))
        planes = segment_planes(pos, dirs, t, n_start, ng) if len(inside) else None
        for m in np.unique(medium[inside]):
            sub = inside[medium[inside] == m]
            md, mdb = media_data.get(int(m), (None, None))
            ms = sub[evm[sub]]  # the paths that evaluate the medium in this pass
            if md is not None and md.count and len(ms):
                # weak branches (internal reflections) are evaluated with probability beta_max / roulette,
                # their weight divided by it: unbiased, and most of the cost was in branches of weight < 0.01
                q = np.minimum(1.0, beta[ms].max(axis=1) / max(settings["roulette"], 1e-300))
                keep = roulette_rng.random(len(ms)) < q
                ev = ms[keep]
                beta_ev = beta.copy()
                beta_ev[ev] /= (q[keep] / kpaths)[:, None]
                eval_segments(pool, threads, ev, pos, dirs, beta_ev, tev, rng, bs.media[m], md.kernel_tuple(),
                              sett, contrib, state >> 2, planes)
                if mdb is not None and mdb.count:
                    # where the bounced light is a small share of the scattered power, it is evaluated on a
                    # matching fraction of the segments (weight 1 / fraction: unbiased, its noise stays small)
                    qb = min(1.0, bounced_share(md, mdb) / BOUNCED_ROULETTE)
                    evb = ev[roulette_rng.random(len(ev)) < qb]
                    beta_b = beta_ev / qb
                    cb3 = np.zeros((len(pos), 3, 3))
                    eval_segments(pool, threads, evb, pos, dirs, beta_b, tev, rng, bs.media[m], mdb.kernel_tuple(),
                                  sett_b, cb3, state >> 2, planes)
                    contrib[:, 3] += cb3.sum(axis=1)
            st = sum(bs.medium_sigmas(m))
            beta[sub] *= np.exp(-st[None, :] * tev[sub, None])
        for c, name in enumerate(COMPONENTS):
            for ch in range(3):
                layers[name][:, ch] += np.bincount(pixel, weights=contrib[:, c, ch], minlength=npix)
        k = len(pos)
        emit = np.zeros((k, 3))
        cp, cd, cb = np.zeros((2 * k, 3)), np.zeros((2 * k, 3)), np.zeros((2 * k, 3))
        cm, cok, cstate = np.zeros(2 * k, np.int64), np.zeros(2 * k, np.bool_), np.zeros(2 * k, np.int64)
        ks = k * len(bs.lights)
        shp, shd, shdist, shc, shok = (np.zeros((ks, 3)), np.zeros((ks, 3)), np.zeros(ks), np.zeros((ks, 3)),
                                       np.zeros(ks, np.bool_))
        li = np.where(tl < t, li, -1)
        # _interact's t is the distance to what the ray meets: the emitter's where one is in front (a sphere
        # light's side is judged at that point)
        _interact(bs.surfaces, bs.media, bs.lights, pos, dirs, beta, medium, depth, rng, tev, surf, ng, ns, li,
                  bs.eps, settings["max_split_depth"], seed, emit, cp, cd, cb, cm, cok, shp, shd, shdist, shc, shok,
                  state, cstate, settings["diffuse_bounces"])
        sidx = np.flatnonzero(shok)
        if len(sidx):
            vis = sidx[visible(caster, bs, shp[sidx], shd[sidx], shdist[sidx], sidx % len(bs.lights))]
            np.add.at(emit, vis // len(bs.lights), shc[vis])
        for ch in range(3):
            layers["surface"][:, ch] += np.bincount(pixel, weights=emit[:, ch], minlength=npix)
            if path_surface is not None:
                path_surface[:, ch] += np.bincount(path, weights=emit[:, ch], minlength=n)
        keep = cok & (cb.max(axis=1) > 1e-5)
        parent = np.repeat(np.arange(k), 2)[keep]
        pos, dirs, beta, medium, state = cp[keep], cd[keep], cb[keep], cm[keep], cstate[keep]
        depth, pixel, evm, path = depth[parent] + 1, pixel[parent], evm[parent], path[parent]
        n_start = ng[parent]  # a child leaves the surface its parent met
        rng = rng[parent] ^ (np.uint64(0x9E37) * (keep.nonzero()[0] % 2 + 1).astype(np.uint64))
