"""The ray-marching integrator of the slides (seed 003, "Emission only", "Single scattering": pbrt-v2's
EmissionIntegrator and SingleScatteringIntegrator), for `--method raymarch`.

Along a camera ray's segment of length t inside a medium: n = ceil(t / step) steps of dt = t / n, stratified by one
random offset u per segment, points at (k + u) dt. From point to point the transmittance is marched, e^(-sigma_t
dt') with sigma_t at the interval's midpoint; at each point the source is added with the transmittance so far:
the emission sigma_a L_e dt and the single scattering sigma_s f L_light / pdf dt from one light sampled at random,
its shadow ray's transmittance marched too (midpoint steps `shadow_step_factor` times longer, as pbrt-v2's) through
every medium it crosses behind index-matched (null) boundaries; any other surface blocks it. The camera path goes on
with the marched transmittance, and the direct light of the diffuse surfaces it meets is marched the same way.

Approximations (as in pbrt-v2): single scattering only; a shadow ray that meets a refracting boundary is blocked (a
sealed medium gets no single scattering from the lights: volpath's next-event estimation has the same limit, its
paths find the lights by scattering), unless `shadows_through_dielectrics` lets it cross smooth dielectrics in a
straight line with their Fresnel transmittance (right for thin, flat glass such as a box's walls, where refraction
only shifts the ray; wrong for a curved boundary); the marching is biased by the step, unbiased in the limit of
small steps.
Lengths in scene units.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.intersect import closest_surface_hits, light_hits
from pbvol_cli.geometry.scene_build import (DIELECTRIC, MAJ_DIMS, MAJ_HI, MAJ_LO, MED_EMIT, MED_G, MED_MAJ,
                                           MED_MAJORANT, MED_PHASE, MED_SIGMA_A, MED_SIGMA_S, NULL, SURF_MEDIUM_IN,
                                           SURF_MEDIUM_OUT, SURF_TYPE)
from pbvol_cli.physics.lights import light_sample
from pbvol_cli.physics.phase import phase_eval
from pbvol_cli.physics.sampling import rand
from pbvol_cli.render.interfaces import dielectric_fresnel, indices
from pbvol_cli.render.media import density_at

MAX_CROSSINGS = 16  # null boundaries a shadow ray passes through at most (then it is blocked)


@njit(parallel=True, cache=True)
def _march(media, data, lights, m, pos, dirs, tlen, gather, first, count, rng, emitted, trans, s_pos, s_dir, s_dist,
           s_c, s_light):
    for i in prange(pos.shape[0]):
        _march_one(np.int64(i), media, data, lights, m, pos, dirs, tlen, gather, first, count, rng, emitted, trans,
                   s_pos, s_dir, s_dist, s_c, s_light)


@njit(cache=True)
def _march_one(i, media, data, lights, m, pos, dirs, tlen, gather, first, count, rng, emitted, trans, s_pos, s_dir,
               s_dist, s_c, s_light):
    """Segment i: its transmittance into trans[i]; where gather[i], its emission into emitted[i] and one light
    sample per step j (first[i] + k) into s_* (the shadow ray from the step's point: origin, direction, length to
    the light, contribution before its transmittance, light index; -1: none)."""
    n = count[i]
    dt = tlen[i] / n
    u = rand(rng, i)
    ox, oy, oz, dx, dy, dz = pos[i, 0], pos[i, 1], pos[i, 2], dirs[i, 0], dirs[i, 1], dirs[i, 2]
    st0 = media[m, MED_SIGMA_A] + media[m, MED_SIGMA_S]
    st1 = media[m, MED_SIGMA_A + 1] + media[m, MED_SIGMA_S + 1]
    st2 = media[m, MED_SIGMA_A + 2] + media[m, MED_SIGMA_S + 2]
    tr0 = tr1 = tr2 = 1.0
    prev = 0.0
    nl = lights.shape[0]
    kind, g = int(media[m, MED_PHASE]), media[m, MED_G]
    for k in range(n):
        t = (k + u) * dt
        mid = 0.5 * (prev + t)
        dm, _ = density_at(media, data, m, ox + mid * dx, oy + mid * dy, oz + mid * dz)
        tr0 *= math.exp(-dm * st0 * (t - prev))
        tr1 *= math.exp(-dm * st1 * (t - prev))
        tr2 *= math.exp(-dm * st2 * (t - prev))
        prev = t
        if not gather[i]:
            continue
        px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
        d, e = density_at(media, data, m, px, py, pz)
        emitted[i, 0] += tr0 * d * media[m, MED_SIGMA_A] * media[m, MED_EMIT] * e * dt
        emitted[i, 1] += tr1 * d * media[m, MED_SIGMA_A + 1] * media[m, MED_EMIT + 1] * e * dt
        emitted[i, 2] += tr2 * d * media[m, MED_SIGMA_A + 2] * media[m, MED_EMIT + 2] * e * dt
        j = first[i] + k
        s_light[j] = -1
        if nl == 0 or d <= 0.0:
            continue
        li = min(int(rand(rng, i) * nl), nl - 1)
        u1, u2 = rand(rng, i), rand(rng, i)
        wx, wy, wz, dist, Lr, Lg, Lb, pdf, delta = light_sample(lights, li, px, py, pz, u1, u2)
        if pdf <= 0.0:
            continue
        f = phase_eval(kind, g, dx * wx + dy * wy + dz * wz) * nl / pdf * d * dt
        s_c[j, 0] = tr0 * media[m, MED_SIGMA_S] * f * Lr
        s_c[j, 1] = tr1 * media[m, MED_SIGMA_S + 1] * f * Lg
        s_c[j, 2] = tr2 * media[m, MED_SIGMA_S + 2] * f * Lb
        s_pos[j, 0], s_pos[j, 1], s_pos[j, 2] = px, py, pz
        s_dir[j, 0], s_dir[j, 1], s_dir[j, 2] = wx, wy, wz
        s_dist[j] = dist
        s_light[j] = li
    mid = 0.5 * (prev + tlen[i])
    dm, _ = density_at(media, data, m, ox + mid * dx, oy + mid * dy, oz + mid * dz)
    trans[i, 0] = tr0 * math.exp(-dm * st0 * (tlen[i] - prev))
    trans[i, 1] = tr1 * math.exp(-dm * st1 * (tlen[i] - prev))
    trans[i, 2] = tr2 * math.exp(-dm * st2 * (tlen[i] - prev))


@njit(cache=True)
def optical_depth(media, data, m, ox, oy, oz, dx, dy, dz, length, step, max_steps):
    """The density integrated over [0, length) of o + s d in medium m (multiply by sigma_t), marched at the
    midpoints of steps of `step` (at most max_steps of them)."""
    n = min(max(1, int(math.ceil(length / step))), max_steps)
    dt = length / n
    tau = 0.0
    for k in range(n):
        t = (k + 0.5) * dt
        d, _ = density_at(media, data, m, ox + t * dx, oy + t * dy, oz + t * dz)
        tau += d * dt
    return tau


@njit(parallel=True, cache=True)
def _shadow_step(media, data, surfaces, eps, alive, pos, dirs, rest, med, t, surf, ng, li, steps, max_steps,
                 through_dielectrics, out, goes_on):
    """One leg of the shadow rays alive[k] (their closest surface at t[k]; li[k] >= 0: another emitter in front):
    out[j] *= the leg's marched transmittance, or 0 where the ray is blocked; a ray that meets a null boundary
    (or, with through_dielectrics, a smooth dielectric: weighted by its Fresnel transmittance times (eta_i /
    eta_t)^2, the radiance's change across it, its direction kept) before its light moves beyond it into the next
    medium (goes_on[k])."""
    for k in prange(alive.shape[0]):
        j = alive[k]
        goes_on[k] = False
        reached = t[k] >= rest[j]
        s = surf[k]
        passes = s >= 0 and (surfaces[s, SURF_TYPE] == NULL or (through_dielectrics
                                                                and surfaces[s, SURF_TYPE] == DIELECTRIC))
        if li[k] >= 0 or (not reached and not passes):
            out[j, 0] = out[j, 1] = out[j, 2] = 0.0
            continue
        length = min(t[k], rest[j])
        m = med[j]
        if m >= 0 and length > 0.0:
            if not math.isfinite(length):
                out[j, 0] = out[j, 1] = out[j, 2] = 0.0
                continue
            tau = optical_depth(media, data, m, pos[j, 0], pos[j, 1], pos[j, 2], dirs[j, 0], dirs[j, 1], dirs[j, 2],
                                 length, steps[m], max_steps)
            for c in range(3):
                out[j, c] *= math.exp(-tau * (media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c]))
        if reached:
            continue
        inv = 1.0 / math.sqrt(ng[k, 0] ** 2 + ng[k, 1] ** 2 + ng[k, 2] ** 2)
        gx, gy, gz = ng[k, 0] * inv, ng[k, 1] * inv, ng[k, 2] * inv
        entering = dirs[j, 0] * gx + dirs[j, 1] * gy + dirs[j, 2] * gz < 0.0
        if surfaces[s, SURF_TYPE] == DIELECTRIC:
            eta_i, eta_t = indices(surfaces, s, entering)
            f = 1.0 if entering else -1.0  # the normal facing the ray
            # the straight ray stands for the refracted one, whose angle it has on the lower index's side: Fresnel
            # from there (no total internal reflection; the same either way by reciprocity)
            _, F, _ = dielectric_fresnel(min(eta_i, eta_t), max(eta_i, eta_t), dirs[j, 0], dirs[j, 1], dirs[j, 2],
                                         f * gx, f * gy, f * gz)
            for c in range(3):
                out[j, c] *= (1.0 - F) * (eta_i / eta_t) ** 2
        med[j] = int(surfaces[s, SURF_MEDIUM_IN]) if entering else int(surfaces[s, SURF_MEDIUM_OUT])
        sgn = -1.0 if entering else 1.0  # just beyond the boundary: against the normal when entering
        pos[j, 0] += t[k] * dirs[j, 0] + sgn * eps * gx
        pos[j, 1] += t[k] * dirs[j, 1] + sgn * eps * gy
        pos[j, 2] += t[k] * dirs[j, 2] + sgn * eps * gz
        rest[j] -= t[k]
        goes_on[k] = True


def auto_steps(media: np.ndarray, step: float, step_mfp: float) -> np.ndarray:
    """The marching step of each medium (scene units): `step`, or where it is 0 the smaller of `step_mfp` mean free
    paths at the medium's majorant (its densest point's largest sigma_t) and the shortest edge of its majorant
    cells (a density field varies on that scale: a fog falling by e^-6 over a long step is marched badly)."""
    if step > 0:
        return np.full(len(media), float(step))
    out = np.full(len(media), np.inf)
    for m in range(len(media)):
        if media[m, MED_MAJORANT] > 0:
            out[m] = step_mfp / media[m, MED_MAJORANT]
        dims = media[m, MED_MAJ + MAJ_DIMS:MED_MAJ + MAJ_DIMS + 3]
        if dims[0] > 0:
            extent = media[m, MED_MAJ + MAJ_HI:MED_MAJ + MAJ_HI + 3] - media[m, MED_MAJ + MAJ_LO:MED_MAJ + MAJ_LO + 3]
            out[m] = min(out[m], float(np.min(extent / dims)))
    return out


class RayMarcher:
    """The segment term of pointbased/camera_pass.render_pbl for `--method raymarch`: march() gives each camera
    segment's emitted and singly scattered radiance (layer "volume") and its marched transmittance; shadow() the
    marched transmittance of the surfaces' shadow rays. settings: config.RaymarchSettings."""

    layers = ("volume",)

    def __init__(self, built, settings):
        self.built = built
        self.steps = np.ascontiguousarray(auto_steps(built.media, settings.step, settings.step_mfp))
        self.shadow_steps = self.steps * settings.shadow_step_factor
        self.max_steps = int(settings.max_steps)
        self.through_dielectrics = bool(settings.shadows_through_dielectrics)

    def for_pass(self, p: int, caster):
        """The term for pass p (the ray marcher has no per-pass state)."""
        return self

    def march(self, caster, m: int, pos, dirs, tlen, rng, gather):
        """Segments of medium m from pos along dirs (unit) of length tlen; gather: which collect light (the others
        are only attenuated). rng: their random streams, advanced. Returns ((radiance (n, 3),) one per layer,
        transmittance (n, 3))."""
        bs = self.built
        n = len(pos)
        count = np.clip(np.ceil(tlen / self.steps[m]), 1, self.max_steps).astype(np.int64)
        count_g = np.where(gather, count, 0)
        first = np.concatenate([[0], np.cumsum(count_g)[:-1]]).astype(np.int64)
        total = int(count_g.sum())
        emitted, trans = np.zeros((n, 3)), np.ones((n, 3))
        s_pos, s_dir, s_dist, s_c = np.zeros((total, 3)), np.zeros((total, 3)), np.zeros(total), np.zeros((total, 3))
        s_light = np.full(total, -1, np.int64)
        _march(bs.media, bs.density_data, bs.lights, m, np.ascontiguousarray(pos), np.ascontiguousarray(dirs),
               np.ascontiguousarray(tlen), np.ascontiguousarray(gather), first, count, rng, emitted, trans, s_pos,
               s_dir, s_dist, s_c, s_light)
        live = np.flatnonzero(s_light >= 0)
        if len(live):
            seg = np.repeat(np.arange(n), count_g)[live]
            c = s_c[live] * self.shadow(caster, s_pos[live], s_dir[live], s_dist[live], s_light[live],
                                        np.full(len(live), m, np.int64))
            for ch in range(3):
                emitted[:, ch] += np.bincount(seg, weights=c[:, ch], minlength=n)
        return (emitted,), trans

    def shadow(self, caster, pos, dirs, dist, target, medium) -> np.ndarray:
        """Transmittance (n, 3) of shadow rays from pos along dirs toward light target at dist, starting in medium
        (-1: none): marched through each medium, passing null boundaries (MAX_CROSSINGS at most); 0 where a surface
        or another emitter blocks the ray."""
        bs = self.built
        n = len(pos)
        out = np.ones((n, 3))
        pos, rest, med = np.array(pos, float), np.array(dist, float), np.array(medium, np.int64)
        dirs, target = np.ascontiguousarray(dirs, float), np.ascontiguousarray(target, np.int64)
        alive = np.arange(n)
        for _ in range(MAX_CROSSINGS + 1):
            t, surf, ng, _ = closest_surface_hits(caster, bs, pos[alive], dirs[alive])
            tl, li = np.empty(len(alive)), np.empty(len(alive), np.int64)
            light_hits(bs.lights, pos[alive], dirs[alive], np.minimum(t, rest[alive]), tl, li, target[alive])
            goes_on = np.zeros(len(alive), np.bool_)
            _shadow_step(bs.media, bs.density_data, bs.surfaces, bs.eps, alive, pos, dirs, rest, med, t, surf,
                         np.ascontiguousarray(ng, float), li, self.shadow_steps, self.max_steps,
                         self.through_dielectrics, out, goes_on)
            alive = alive[goes_on]
            if not len(alive):
                return out
        out[alive] = 0.0  # too many crossings
        return out
