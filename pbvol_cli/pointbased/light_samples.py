"""Light surface samples and light volume samples (Wang et al. 2016, sec. 3.4-3.5), read as photon beams.

Surface sample j (blue noise on the outer layer of a medium-holding object, area A_j) is connected to each light:
irradiance E_j (direct, with visibility), plus indirect light path traced from one direction per sample. The
transmitted part (Fresnel T) refracts inward and is followed through transparent layers to the medium: a beam of
power Phi_j = E_j A_j T, cross-section A_perp = A_j |cos theta_t| at the medium's entry (beams.py: into_media),
then cut into volume samples and followed through internal reflections (beams.py: beam_segments).

Units: power in W (scene radiance units x scene area), lengths in scene units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.intersect import closest_surface_hits, light_hits, visible
from pbvol_cli.geometry.raycast import TriangleCaster
from pbvol_cli.geometry.scene_build import (DIELECTRIC, NULL, SPH_SURFACE, SURF_MEDIUM_IN, SURF_MEDIUM_OUT, SURF_TYPE,
                                           BuiltScene)
from pbvol_cli.physics.lights import light_sample
from pbvol_cli.physics.sampling import cosine_directions, rand, seed_state
from pbvol_cli.pointbased.beams import Beams, beam_segments, concatenate_beams, into_media, thin_by_power
from pbvol_cli.pointbased.gather import morton_order
from pbvol_cli.pointbased.surface_samples import SHARING_RADIUS, poisson_disk, share_among_neighbours
from pbvol_cli.pointbased.volume_samples import PLANE_COLS
from pbvol_cli.render.interfaces import shadow_ray_length
from pbvol_cli.render.volpath import trace_radiance


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
    v_plane: np.ndarray  # (m, PLANE_COLS) the boundary's tangent planes where the segment's beam enters and leaves
    #                      (volume_samples: ENTRY_N, ENTRY_Q, EXIT_N, EXIT_Q), n . x = q on each, n outward
    v_returned: np.ndarray  # (m,) int8: 1 where the light scattered in a medium before it reached the surface
    #                         sample (the medium's light that left it and a table sends back): the bounced layer's
    v_leg: np.ndarray  # (m,) the leg each segment belongs to (one beam between two boundary points; single
    #                    scattering takes a leg's segments as one cylinder: single_scattering._splat_legs)

    FIELDS = ("s_pos", "s_nrm", "s_surface", "s_area", "s_irradiance", "v_start", "v_dir", "v_len", "v_power",
              "v_area", "v_medium", "v_ends", "v_plane", "v_returned", "v_leg")

    def arrays(self) -> dict:
        return {k: getattr(self, k) for k in self.FIELDS}

    @classmethod
    def from_arrays(cls, d: dict) -> "LightSamples":
        ls = cls(**{k: d[k] for k in cls.FIELDS})
        n, m = len(ls.s_pos), len(ls.v_start)
        shapes_ok = (ls.s_nrm.shape == (n, 3) and ls.s_irradiance.shape == (n, 3) and ls.v_dir.shape == (m, 3)
                     and ls.v_power.shape == (m, 3) and len(ls.v_len) == m and len(ls.v_area) == m
                     and len(ls.v_ends) == m and ls.v_plane.shape == (m, PLANE_COLS) and len(ls.v_returned) == m
                     and ls.v_leg.shape == (m,))
        if not shapes_ok or not all(np.all(np.isfinite(getattr(ls, k))) for k in ("v_start", "v_power", "v_len")):
            raise ValueError("inconsistent light samples")
        return ls


def outer_layer_surfaces(bs: BuiltScene) -> np.ndarray:
    """Surfaces on the outside of medium-holding shapes: those of a shape that bounds a medium somewhere, with
    vacuum on their exterior (a glass of liquid: the glass's outside and the liquid's free surface)."""
    surf = bs.surfaces
    holds = {int(bs.surface_shape[k]) for k in range(len(surf))
             if surf[k, SURF_MEDIUM_IN] >= 0 or surf[k, SURF_MEDIUM_OUT] >= 0}
    return np.array([k for k in range(len(surf)) if int(bs.surface_shape[k]) in holds
                     and surf[k, SURF_MEDIUM_OUT] < 0 and surf[k, SURF_TYPE] in (DIELECTRIC, NULL)], np.int64)


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


@dataclass
class EnteringLight:
    """The light that reaches the media through their outer layers: the surface samples and the beams they send
    in (beams.py: Beams), with each beam's surface sample (an index into pos)."""
    pos: np.ndarray  # (n, 3) surface samples on the outer layers
    nrm: np.ndarray  # (n, 3) exterior normals
    sid: np.ndarray  # (n,) surface ids
    area: float  # the area each sample represents
    spacing: float  # the samples' minimum distance
    irradiance: np.ndarray  # (n, 3) direct and indirect
    beams: Beams  # light that has not scattered in a medium before it reached the sample
    beam_source: np.ndarray
    returned: Beams  # light that has (the bounced layer's)
    returned_source: np.ndarray


def entering_light(caster, bs: BuiltScene, surface_samples: int, max_reflections: int, max_layers: int, seed: int,
                   advance=lambda: None, returned_orders: str = "1,2,3+") -> EnteringLight:
    """Surface samples on every medium-holding object's outer layer, lit by every light (advance() after each) and by
    indirect light (advance() after it), and the beams their transmitted light makes in the media."""
    outer = outer_layer_surfaces(bs)
    if len(outer) == 0:
        raise ValueError("no medium-holding object with a transparent boundary to place light samples on")
    tri = np.isin(bs.tri_surface, outer)
    sph = bs.spheres[np.isin(bs.spheres[:, SPH_SURFACE].astype(np.int64), outer)]
    advance()
    pos, nrm, sid, area, spacing = poisson_disk(bs.vertices, bs.faces[tri], bs.tri_normals[tri],
                                                bs.tri_surface[tri], sph, surface_samples, seed)
    n = len(pos)
    eps = bs.eps
    irr = np.zeros((n, 3))
    beams, returned = [], []  # (Beams, their samples' indices)
    layer_rng = np.random.default_rng([seed, 0x1A7E])  # Fresnel choices inside transparent layers

    def enter(vis, wdir, E, into):
        b, src = into_media(caster, bs, pos[vis], nrm[vis], sid[vis], wdir, E, area, max_layers, max_reflections,
                            layer_rng, with_source=True)
        into.append((b, np.asarray(vis, np.int64)[src]))

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
        # chance): each sample's indirect power is shared among its neighbours, the total kept
        for E in (E0, E1):
            shared = np.zeros_like(E)
            share_among_neighbours(pos[vis], E, SHARING_RADIUS * spacing, shared)
            E[:] = shared
    enter(vis, wdir, E0, beams)
    enter(vis, wdir, E1, returned)
    advance()
    b, r = concatenate_beams([b for b, _ in beams]), concatenate_beams([b for b, _ in returned])
    return EnteringLight(pos, nrm, sid, area, spacing, irr, b, np.concatenate([s for _, s in beams]), r,
                         np.concatenate([s for _, s in returned]))


def step_counter(progress, steps: int):
    """A function that counts one step each call and reports (done, steps) to progress, if given."""
    done = [0]

    def advance():
        done[0] += 1
        if progress is not None:
            progress(min(done[0], steps), steps)

    return advance


def place_light_samples(bs: BuiltScene, surface_samples: int, segments: int, max_reflections: int,
                        max_layers: int, seed: int, threads: int = 2, progress=None,
                        returned_orders: str = "1,2,3+", in_space_order: bool = False) -> LightSamples:
    """Surface samples on every medium-holding object's outer layer, their beams and the volume samples.
    progress(done, total), if given, is called after each step (lights, indirect light, reflection passes).
    returned_orders: the scattering orders the returned light (v_returned) keeps (tests compare it with volpath
    --orders). in_space_order: the volume samples stored along a Morton curve through their centres, for a set
    that is cached and used by many renders: the octree each render builds over them (volume_samples.SampleSet)
    then reads them in sequence instead of at random (0.4 s to sort a million, 0.1 s saved each render)."""
    steps = len(bs.lights) + 2 + max_reflections + 1
    advance = step_counter(progress, steps)
    caster = TriangleCaster(bs.vertices, bs.faces, threads)
    try:
        light = entering_light(caster, bs, surface_samples, max_reflections, max_layers, seed, advance,
                               returned_orders)
        parts = []
        for b, s_off, adv in ((light.beams, 0, advance), (light.returned, 0x2E7, None)):
            seg = segments
            if s_off:
                # the returned light is diffuse and smooth, like the boundary's bounced light: fewer beams and
                # segments (docs/pbl.md)
                keep, power = thin_by_power(b.power, RETURNED_BEAMS, np.random.default_rng([seed, 0x2E8]))
                b = Beams(b.pos[keep], b.dir[keep], power, b.medium[keep], b.area[keep], b.normal[keep])
                seg = max(1, segments // 4)
            parts.append(beam_segments(caster, bs, b, seg, max_reflections, seed + s_off, adv))
    finally:
        caster.close()
    parts[1]["leg"] += int(parts[0]["leg"].max()) + 1 if len(parts[0]["leg"]) else 0
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    flag = np.concatenate([np.zeros(len(parts[0]["len"]), np.int8), np.ones(len(parts[1]["len"]), np.int8)])
    if in_space_order:
        order = morton_order(cat["start"] + 0.5 * cat["len"][:, None] * cat["dir"])
        cat = {k: v[order] for k, v in cat.items()}
        flag = flag[order]
    if progress is not None:
        progress(steps, steps)
    return LightSamples(light.pos, light.nrm, light.sid, np.full(len(light.pos), light.area), light.irradiance,
                        cat["start"], cat["dir"], cat["len"], cat["power"],
                        cat["area"], cat["medium"], cat["ends"], cat["plane"], flag, cat["leg"])
