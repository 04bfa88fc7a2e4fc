"""Gathering the VPLs along camera rays (seed 004, sections 4.2-4.4), for `--method vpl`.

A camera segment in medium m of length t gets, besides the ray marcher's emission and single scattering from the
lights (render/raymarch.py, layer "volume"), the light the VPLs scatter into it (layer "vpl"):

    sum over R stratified points r_k = (k + u) t / R:  T(0, r_k) sigma_s(r_k) (t / R) G_k,
    G_k = (1 / P) sum over the VPLs v of P walks chosen at random:
          f_p(r_k) I_v(toward r_k) T(v, r_k) V(v, r_k) min(1 / d^2, b)

(P of the N walks, each standing for N / P of them: unbiased before the clamp; the 1/N of the walks cancels). The
clamp bound b = 1 / d_c^2 removes the VPLs' singular spikes and loses the light of VPLs closer than d_c. The
compensation (Kollig and Keller 2004, Raab et al. 2006, as the seed accelerates it: distances sampled within the
clamping radius from the locally homogeneous sigma_t at r_k, visibility checked) adds at each r_k one vertex x =
r_k + s w, w sampled from the phase function at r_k (whose value it cancels), s from sigma e^(-sigma s) /
(1 - e^(-sigma d_c)) on [0, d_c):

    T(r_k, x) sigma_s(x) (1 - b s^2) / p(s) * [the light x scatters toward r_k: one light sample and the VPLs of
    P walks, unclamped],

which is the missing part in expectation (for volume VPLs; surface VPLs' clamped part near a surface is not
compensated, and a vertex beyond a surface is dropped: the seed's approximation, errors close to surfaces). Stopping
after one level with unclamped VPLs is unbiased (seed section 4.4); its spikes are rarer and smaller.
Lengths in scene units; transmittances marched as in the ray marcher.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.intersect import closest_surface_hits
from pbvol_cli.geometry.scene_build import MED_G, MED_MAJORANT, MED_PHASE, MED_SIGMA_A, MED_SIGMA_S
from pbvol_cli.physics.lights import light_sample
from pbvol_cli.physics.phase import phase_eval, phase_sample
from pbvol_cli.physics.sampling import rand
from pbvol_cli.render.media import density_at
from pbvol_cli.render.raymarch import RayMarcher, optical_depth
from pbvol_cli.vpl.walks import VOLUME, trace_walks

CONNECTIONS_PER_CHUNK = 2_000_000  # shadow rays of VPL connections in flight at once (about 200 MB)


@njit(parallel=True, cache=True)
def _gather_points(media, data, m, pos, dirs, tlen, segs, R, step, max_steps, rng, g_pos, g_dir, g_w):
    """R stratified points on each segment segs[k] (rows k R .. k R + R - 1): position, the camera ray's direction,
    and weight T(0, r) sigma_s(r) t / R (RGB), T marched from point to point (midpoints)."""
    for k in prange(segs.shape[0]):
        i = segs[k]
        dt = tlen[i] / R
        u = rand(rng, i)
        ox, oy, oz, dx, dy, dz = pos[i, 0], pos[i, 1], pos[i, 2], dirs[i, 0], dirs[i, 1], dirs[i, 2]
        tau = 0.0
        prev = 0.0
        for q in range(R):
            t = (q + u) * dt
            tau += optical_depth(media, data, m, ox + prev * dx, oy + prev * dy, oz + prev * dz, dx, dy, dz,
                                 t - prev, step, max_steps)
            prev = t
            d, _ = density_at(media, data, m, ox + t * dx, oy + t * dy, oz + t * dz)
            r = k * R + q
            g_pos[r, 0], g_pos[r, 1], g_pos[r, 2] = ox + t * dx, oy + t * dy, oz + t * dz
            g_dir[r, 0], g_dir[r, 1], g_dir[r, 2] = dx, dy, dz
            for c in range(3):
                st = media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c]
                g_w[r, c] = math.exp(-tau * st) * d * media[m, MED_SIGMA_S + c] * dt


@njit(cache=True)
def vpl_intensity(v_kind, v_in, v_pow, v_med, v_nrm, v_alb, media, v, wx, wy, wz, c):
    """VPL v's intensity (W/sr) toward the unit direction w (channel c)."""
    if v_kind[v] == VOLUME:
        mv = v_med[v]
        cos = v_in[v, 0] * wx + v_in[v, 1] * wy + v_in[v, 2] * wz
        return v_pow[v, c] * phase_eval(int(media[mv, MED_PHASE]), media[mv, MED_G], cos)
    cos = v_nrm[v, 0] * wx + v_nrm[v, 1] * wy + v_nrm[v, 2] * wz
    return v_pow[v, c] * v_alb[v, c] / math.pi * max(cos, 0.0)


@njit(parallel=True, cache=True)
def _choose_walks(rng, walks, chosen):
    """Each point r's walks, chosen uniformly with replacement from its stream rng[r]."""
    for r in prange(chosen.shape[0]):
        for p in range(chosen.shape[1]):
            chosen[r, p] = min(int(rand(rng, r) * walks), walks - 1)


@njit(parallel=True, cache=True)
def _count(first, chosen, count):
    for r in prange(chosen.shape[0]):
        n = 0
        for p in range(chosen.shape[1]):
            w = chosen[r, p]
            if w >= 0:
                n += first[w + 1] - first[w]
        count[r] = n


@njit(parallel=True, cache=True)
def _connect(media, m, g_pos, g_dir, g_w, chosen, offset, first, v_pos, v_in, v_pow, v_kind, v_med, v_nrm, v_alb,
             bound, s_pos, s_dir, s_dist, s_c):
    """Shadow rays from every gather point r to the VPLs of its chosen walks: origin, direction, length and
    contribution before the transmittance, g_w[r] f_p(r) I_v min(1/d^2, bound) / P (bound inf: unclamped);
    g_dir[r]: the direction the light leaves r in, reversed (the camera ray's)."""
    P = chosen.shape[1]
    kind, g = int(media[m, MED_PHASE]), media[m, MED_G]
    for r in prange(g_pos.shape[0]):
        j = offset[r]
        for p in range(P):
            w = chosen[r, p]
            if w < 0:
                continue
            for v in range(first[w], first[w + 1]):
                ux, uy, uz = v_pos[v, 0] - g_pos[r, 0], v_pos[v, 1] - g_pos[r, 1], v_pos[v, 2] - g_pos[r, 2]
                d2 = ux * ux + uy * uy + uz * uz
                d = math.sqrt(d2)
                s_dist[j] = d
                if d <= 0.0:
                    s_c[j, 0] = s_c[j, 1] = s_c[j, 2] = 0.0
                    j += 1
                    continue
                ux, uy, uz = ux / d, uy / d, uz / d
                geo = min(1.0 / d2, bound) / P * phase_eval(kind, g, ux * g_dir[r, 0] + uy * g_dir[r, 1]
                                                            + uz * g_dir[r, 2])
                for c in range(3):
                    s_c[j, c] = g_w[r, c] * geo * vpl_intensity(v_kind, v_in, v_pow, v_med, v_nrm, v_alb, media, v,
                                                                -ux, -uy, -uz, c)
                s_pos[j, 0], s_pos[j, 1], s_pos[j, 2] = g_pos[r, 0], g_pos[r, 1], g_pos[r, 2]
                s_dir[j, 0], s_dir[j, 1], s_dir[j, 2] = ux, uy, uz
                j += 1


@njit(parallel=True, cache=True)
def _compensation_vertices(media, data, m, g_pos, g_dir, g_w, radius, step, max_steps, rng, x_pos, x_dir, x_w,
                           x_len):
    """One compensation vertex x = r + s w per gather point r (random stream rng[r]): w (x_dir) from the phase
    function at r around the camera ray, s in [0, radius) from the truncated exponential at r's sigma_t (the mean
    of the channels); weight g_w[r] T(r, x) sigma_s(x) (1 - s^2 / radius^2) / p(s); x_len[r] = s (the caller
    checks that no surface is closer)."""
    kind, g = int(media[m, MED_PHASE]), media[m, MED_G]
    st_mean = (media[m, MED_SIGMA_A] + media[m, MED_SIGMA_S] + media[m, MED_SIGMA_A + 1] + media[m, MED_SIGMA_S + 1]
               + media[m, MED_SIGMA_A + 2] + media[m, MED_SIGMA_S + 2]) / 3.0
    for r in prange(g_pos.shape[0]):
        u1, u2, u3, u4 = rand(rng, r), rand(rng, r), rand(rng, r), rand(rng, r)
        wx, wy, wz, _ = phase_sample(kind, g, g_dir[r, 0], g_dir[r, 1], g_dir[r, 2], u1, u2, u3)
        d0, _ = density_at(media, data, m, g_pos[r, 0], g_pos[r, 1], g_pos[r, 2])
        sigma = d0 * st_mean
        if sigma * radius > 1e-6:
            a = 1.0 - math.exp(-sigma * radius)
            s = -math.log(1.0 - u4 * a) / sigma
            pdf = sigma * math.exp(-sigma * s) / a
        else:
            s = u4 * radius
            pdf = 1.0 / radius
        x, y, z = g_pos[r, 0] + s * wx, g_pos[r, 1] + s * wy, g_pos[r, 2] + s * wz
        x_pos[r, 0], x_pos[r, 1], x_pos[r, 2] = x, y, z
        x_dir[r, 0], x_dir[r, 1], x_dir[r, 2] = wx, wy, wz
        x_len[r] = s
        tau = optical_depth(media, data, m, g_pos[r, 0], g_pos[r, 1], g_pos[r, 2], wx, wy, wz, s, step, max_steps)
        d, _ = density_at(media, data, m, x, y, z)
        keep = (1.0 - s * s / (radius * radius)) / pdf
        for c in range(3):
            st = media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c]
            x_w[r, c] = g_w[r, c] * math.exp(-tau * st) * d * media[m, MED_SIGMA_S + c] * keep


@njit(parallel=True, cache=True)
def _light_samples(lights, media, m, x_pos, x_dir, x_w, rng, s_pos, s_dir, s_dist, s_c, s_light):
    """One light sample from each compensation vertex x (light chosen uniformly): the light scattered at x toward
    its gather point (the light travels along -w_light, then along -x_dir)."""
    nl = lights.shape[0]
    kind, g = int(media[m, MED_PHASE]), media[m, MED_G]
    for r in prange(x_pos.shape[0]):
        li = min(int(rand(rng, r) * nl), nl - 1)
        u1, u2 = rand(rng, r), rand(rng, r)
        s_light[r] = -1
        s_c[r, 0] = s_c[r, 1] = s_c[r, 2] = 0.0
        s_pos[r, 0], s_pos[r, 1], s_pos[r, 2] = x_pos[r, 0], x_pos[r, 1], x_pos[r, 2]
        if nl == 0:
            continue
        wx, wy, wz, dist, Lr, Lg, Lb, pdf, _ = light_sample(lights, li, x_pos[r, 0], x_pos[r, 1], x_pos[r, 2], u1, u2)
        if pdf <= 0.0:
            continue
        f = phase_eval(kind, g, wx * x_dir[r, 0] + wy * x_dir[r, 1] + wz * x_dir[r, 2]) * nl / pdf
        s_c[r, 0], s_c[r, 1], s_c[r, 2] = x_w[r, 0] * f * Lr, x_w[r, 1] * f * Lg, x_w[r, 2] * f * Lb
        s_dir[r, 0], s_dir[r, 1], s_dir[r, 2] = wx, wy, wz
        s_dist[r] = dist
        s_light[r] = li


class VPLGather(RayMarcher):
    """The segment term of pointbased/camera_pass.render_pbl for `--method vpl`: the ray marcher's emission and
    single scattering (layer "volume") and the VPLs' light (layer "vpl"). for_pass(p) traces pass p's walks (seed
    + p). settings: config.VplSettings; marching: config.RaymarchSettings."""

    layers = ("volume", "vpl")

    def __init__(self, built, marching, settings, seed: int, caster=None):
        super().__init__(built, marching)
        self.settings, self.seed, self.caster = settings, seed, caster
        self.vpls = None
        radius = settings.clamp_distance
        if radius <= 0:  # auto: clamp_mfp of the densest medium's shortest mean free path (at its majorant)
            majorant = float(np.max(built.media[:, MED_MAJORANT], initial=0.0)) if len(built.media) else 0.0
            radius = settings.clamp_mfp / majorant if majorant > 0 else 1.0
        self.clamp_radius = radius  # d_c, scene units
        self.bound = np.inf if not settings.clamp else 1.0 / radius ** 2
        f = settings.compensation_clamp
        self.bound_x = np.inf if f <= 0 else 1.0 / (f * radius) ** 2  # at the compensation vertices
        self.walk_seconds = 0.0

    def for_pass(self, p: int, caster):
        import time

        t = time.perf_counter()
        self.vpls = trace_walks(caster, self.built, self.settings.walks, self.seed + p, self.settings.max_depth)
        self.walk_seconds += time.perf_counter() - t
        return self

    def march(self, caster, m: int, pos, dirs, tlen, rng, gather):
        (volume,), trans = super().march(caster, m, pos, dirs, tlen, rng, gather)
        return (volume, self._vpl_light(caster, m, pos, dirs, tlen, rng, gather)), trans

    def _vpl_light(self, caster, m, pos, dirs, tlen, rng, gather):
        """The VPLs' light along each segment (n, 3), the gathering segments taken in chunks (the connections'
        arrays are gather points x walks_per_point x VPLs per walk long)."""
        n = len(pos)
        out = np.zeros((n, 3))
        segs = np.flatnonzero(gather)
        if self.vpls is None or len(self.vpls) == 0:
            return out
        pos, dirs, tlen = (np.ascontiguousarray(a) for a in (pos, dirs, tlen))
        per_walk = max(len(self.vpls) / self.vpls.walks, 1e-3)
        chunk = max(1, int(CONNECTIONS_PER_CHUNK / (self.settings.gather_points * self.settings.walks_per_point
                                                    * per_walk * (2 if self.settings.compensate else 1))))
        for c0 in range(0, len(segs), chunk):
            self._vpl_chunk(caster, m, pos, dirs, tlen, rng, segs[c0:c0 + chunk], out)
        return out

    def _vpl_chunk(self, caster, m, pos, dirs, tlen, rng, segs, out):
        bs, st = self.built, self.settings
        n = len(pos)
        R = st.gather_points
        G = len(segs) * R
        g_pos, g_dir, g_w = np.zeros((G, 3)), np.zeros((G, 3)), np.zeros((G, 3))
        _gather_points(bs.media, bs.density_data, m, pos, dirs, tlen, segs, R, self.steps[m], self.max_steps, rng,
                       g_pos, g_dir, g_w)
        seg_of = np.repeat(segs, R)  # each gather point's segment
        # each gather point's own random stream, from its segment's (kernels over the points run in parallel)
        g_rng = rng[seg_of] ^ (np.uint64(0x9E3779B97F4A7C15) * (np.arange(G, dtype=np.uint64) % np.uint64(R)
                                                                 + np.uint64(1)))
        rays = [self._connections(m, g_pos, g_dir, g_w, seg_of, g_rng, self.bound)]
        if st.clamp and st.compensate:
            rays += self._compensation(caster, m, g_pos, g_dir, g_w, seg_of, g_rng)
        s_pos, s_dir, s_dist, s_c, s_light, s_seg = (np.concatenate([r[c] for r in rays]) for c in range(6))
        live = np.flatnonzero(s_c.max(axis=1) > 0)
        if len(live):
            c = s_c[live] * self.shadow(caster, s_pos[live], s_dir[live], s_dist[live], s_light[live],
                                        np.full(len(live), m, np.int64))
            for ch in range(3):
                out[:, ch] += np.bincount(s_seg[live], weights=c[:, ch], minlength=n)

    def _connections(self, m, g_pos, g_dir, g_w, seg_of, rng, bound):
        """Shadow rays (pos, dir, dist, contribution, light -1, segment) from the points to their chosen walks'
        VPLs."""
        V, P = self.vpls, self.settings.walks_per_point
        chosen = np.zeros((len(g_pos), P), np.int64)
        _choose_walks(rng, V.walks, chosen)
        count = np.zeros(len(g_pos), np.int64)
        _count(V.first, chosen, count)
        offset = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)
        k = int(count.sum())
        s_pos, s_dir, s_dist, s_c = np.zeros((k, 3)), np.zeros((k, 3)), np.zeros(k), np.zeros((k, 3))
        _connect(self.built.media, m, g_pos, g_dir, g_w, chosen, offset, V.first, V.pos, V.incoming, V.power, V.kind,
                 V.medium, V.normal, V.albedo, bound, s_pos, s_dir, s_dist, s_c)
        return s_pos, s_dir, s_dist, s_c, np.full(k, -1, np.int64), np.repeat(seg_of, count)

    def _compensation(self, caster, m, g_pos, g_dir, g_w, seg_of, rng):
        """The compensation vertices' light samples and unclamped VPL connections (shadow-ray tuples)."""
        bs = self.built
        G = len(g_pos)
        x_pos, x_dir, x_w, x_len = np.zeros((G, 3)), np.zeros((G, 3)), np.zeros((G, 3)), np.zeros(G)
        _compensation_vertices(bs.media, bs.density_data, m, g_pos, g_dir, g_w, self.clamp_radius, self.steps[m],
                               self.max_steps, rng, x_pos, x_dir, x_w, x_len)
        t, _, _, _ = closest_surface_hits(caster, bs, g_pos, x_dir)
        x_w[t < x_len] = 0.0  # beyond a surface: dropped (the seed's approximation near surfaces)
        keep = np.flatnonzero(x_w.max(axis=1) > 0)
        x_pos, x_dir, x_w, seg, x_rng = x_pos[keep], x_dir[keep], x_w[keep], seg_of[keep], rng[keep]
        k = len(keep)
        l_pos, l_dir, l_dist, l_c = np.zeros((k, 3)), np.zeros((k, 3)), np.zeros(k), np.zeros((k, 3))
        l_light = np.full(k, -1, np.int64)
        _light_samples(bs.lights, bs.media, m, x_pos, x_dir, x_w, x_rng, l_pos, l_dir, l_dist, l_c, l_light)
        # the VPLs seen from x, clamped by bound_x only; the light leaves x toward r, along -x_dir (_connect's
        # convention: the reverse of the direction passed)
        vpl = self._connections(m, x_pos, x_dir, x_w, seg, x_rng, self.bound_x)
        return [(l_pos, l_dir, l_dist, l_c, l_light, seg), vpl]

