"""Caustics on diffuse surfaces from photons: a surface term of pbl's camera paths.

A small light seen from a diffuse surface through glass (the table beside a wine glass) is a caustic. Camera paths
find it only by chance after a diffuse bounce, as fireflies that the per-pixel path counts can chase but not smooth
(docs/pbl.md, the wine glass). Here each pass traces photons from the emitters (sphere and quad lights) toward the
scene's smooth surfaces, through their reflections and refractions and the media's transmittance, to the first
diffuse surface they meet. Camera paths gather them there with a kernel a few pixel footprints wide, and no longer
count an emitter that a path finds after a diffuse bounce. The two estimates split the same paths:

    emitter -> (smooth interfaces, unscattered transmittance through media)+ -> diffuse surface

carried by photons; the same paths without a smooth interface are the shadow rays' (direct light), and the light
the media scatter is the light samples' (the medium terms camera paths gather after a diffuse bounce). The kernel's
radius shrinks with the pass index as r^2 ~ (p + 1)^(-1/3) (progressive photon mapping's alpha = 2/3, Knaus and
Zwicker 2011, with independent passes), so its blur fades as the passes add up. Biased by that blur, like pbl's other
terms; consistent.

Units: photon power in W (flux), positions and radii in scene units, the gathered irradiance in W / unit^2.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.intersect import closest_surface_hits, light_hits
from pbvol_cli.geometry.scene_build import (CAM_POS, DIELECTRIC, DIFFUSE, MED_SIGMA_A, MED_SIGMA_S, MIRROR,
                                           SPH_CENTER, SPH_RADIUS, SPH_SURFACE, SURF_ALBEDO, SURF_TYPE, BuiltScene)
from pbvol_cli.physics.fresnel import reflect
from pbvol_cli.physics.lights import (LIGHT_AREA, LIGHT_E1, LIGHT_E2, LIGHT_P0, LIGHT_RADIUS, LIGHT_RGB,
                                     LIGHT_TWO_SIDED, LIGHT_TYPE, QUAD, SPHERE, quad_normal)
from pbvol_cli.physics.sampling import around, rand, seed_state, uniform_sphere
from pbvol_cli.pointbased.peak_deflections import MAX_TURNS, draw_deflections, peak_rates
from pbvol_cli.render.interfaces import dielectric_choice, incident_side, medium_beyond

CAUSTIC_STREAM = 0xCA057  # the photons' random streams (seed_state's stream, plus the pass index)
SHRINK_ALPHA = 2.0 / 3.0  # pass p's kernel area is pass 0's times (p + 1)^(alpha - 1)
CELL_RADII = 2.0  # the grid's cells are this many kernel radii wide (at the photons' median distance from the
# camera): a query scans the 2 x 2 x 2 cells its disc overlaps
MAX_REACH = 1.0  # radii are capped at this many cells (a query scans at most 3 x 3 x 3: those of paths after a
# diffuse bounce, whose footprint is wide)
CELL_CAP = 64  # photons a grid cell keeps at most, each of a fuller cell kept with probability cap / count and its
# power divided by that (unbiased): a large light's broad caustic (the bumpy sphere's) put hundreds in a kernel,
# and gathering them cost 4 s a pass, where a few dozen are as good against the camera paths' own noise. (Per
# cell, not per bucket: a sparse cell sharing a bucket with a crowded one would keep few photons of large power.)
MAX_RADIUS = 0.02  # and at this share of the scene's extent: in a small image a few pixel footprints span an object,
# and a kernel that wide gathers a floor's photons on the objects standing on it (a 10 x 10 image read 1.6 % bright)
MIN_PHOTONS = 1 << 14  # photons a pass traces at least (a small image's photons per pixel are few in all)
PLANE_SLACK = 0.25  # photons count within this many radii of the query's tangent plane, normals within 60 degrees

# the photons, sorted by grid bucket: a bucket's photons are order[start[b]:start[b + 1]]
CausticMap = namedtuple("CausticMap", ["pos", "power", "normal", "cell_ix", "start", "cell", "radius_scale", "box",
                                       "max_radius"])
CausticMap.__doc__ = """A pass's caustic photons: pos (n, 3), power (n, 3, W), normal (n, 3: the diffuse surface's
normal on the side the photon arrived from), cell_ix (n, 3) their grid cells, start (buckets + 1) the bucket
offsets (photons sorted by bucket), cell the grid's cell size and radius_scale the kernel radius per unit of
(distance from the camera x pixel angle), this pass's shrink included (scene units), box (2, 3) the photons'
bounding box (most queries lie far from every photon: they stop there), max_radius the kernel's largest radius."""


def caustic_target(bs: BuiltScene):
    """(centre (3,), radius) of a sphere bounding every smooth (non-diffuse) surface, or None where there is none, or
    no diffuse surface to receive a caustic: the photons are aimed at it, since a caustic path's first surface is
    a smooth one."""
    smooth = np.flatnonzero(bs.surfaces[:, SURF_TYPE] != DIFFUSE)
    if len(smooth) == 0 or len(smooth) == len(bs.surfaces):
        return None
    pts = np.zeros((0, 3))
    if len(bs.faces):
        tri = np.isin(bs.tri_surface, smooth)
        pts = bs.vertices[bs.faces[tri]].reshape(-1, 3).astype(float)
    balls = np.array([s for s in bs.spheres if int(s[SPH_SURFACE]) in smooth]).reshape(-1, bs.spheres.shape[1])
    c, r = balls[:, SPH_CENTER:SPH_CENTER + 3], balls[:, SPH_RADIUS]
    lo = np.min(np.concatenate([pts, c - r[:, None]]), axis=0)
    hi = np.max(np.concatenate([pts, c + r[:, None]]), axis=0)
    centre = 0.5 * (lo + hi)
    # the farthest point from the box's centre: a sphere's own radius for one analytic sphere
    reach = max(np.linalg.norm(pts - centre, axis=1).max(initial=0.0),
                (np.linalg.norm(c - centre, axis=1) + r).max(initial=0.0))
    return centre, float(reach) * (1.0 + 1e-6) + bs.eps


def emitter_weights(lights: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """Each light's share of the photons: sphere and quad lights (the emitters camera paths can meet) in proportion
    to their radiance's mean over the channels x area x the solid angle the target subtends at their centre; 0 for
    the others (a point or directional light cannot be met, nor can the environment carry photons here)."""
    w = np.zeros(len(lights))
    for k, row in enumerate(lights):
        if row[LIGHT_TYPE] not in (SPHERE, QUAD):
            continue
        if row[LIGHT_TYPE] == SPHERE:
            c = row[LIGHT_P0:LIGHT_P0 + 3]
        else:
            c = row[LIGHT_P0:LIGHT_P0 + 3] + 0.5 * (row[LIGHT_E1:LIGHT_E1 + 3] + row[LIGHT_E2:LIGHT_E2 + 3])
        d = float(np.linalg.norm(centre - c))
        cos_max = math.sqrt(max(0.0, 1.0 - (radius / d) ** 2)) if d > radius else -1.0
        w[k] = float(np.mean(row[LIGHT_RGB:LIGHT_RGB + 3])) * row[LIGHT_AREA] * 2.0 * math.pi * (1.0 - cos_max)
    total = w.sum()
    return w / total if total > 0 else w


# (numba's parallel loops call a plain kernel per photon: tuples returned by inlined helpers inside prange trip its
# array analysis, and the camera pass's kernels follow the same pattern)
@njit(parallel=True, cache=True)
def _emit(lights, cdf, probs, centre, radius, n, seed, stream, eps, pos, dirs, power, alive, skip, rng):
    for i in prange(n):
        _emit_one(i, lights, cdf, probs, centre, radius, n, seed, stream, eps, pos, dirs, power, alive, skip, rng)


@njit(cache=True)
def _emit_one(i, lights, cdf, probs, centre, radius, n, seed, stream, eps, pos, dirs, power, alive, skip, rng):
    """Photon i leaves a point of light k (drawn by cdf) uniform in area, in a direction uniform in the cone toward
    the target sphere (centre, radius); its power is L cos / (P(k) pdf_area pdf_dir n), W."""
    st = np.empty(1, np.uint64)
    st[0] = seed_state(seed, stream, i)
    u = rand(st, 0)
    k = 0
    while k < cdf.shape[0] - 1 and u >= cdf[k]:
        k += 1
    u1, u2 = rand(st, 0), rand(st, 0)
    if lights[k, LIGHT_TYPE] == SPHERE:
        nx, ny, nz = uniform_sphere(u1, u2)
        r = lights[k, LIGHT_RADIUS]
        x = lights[k, LIGHT_P0] + r * nx
        y = lights[k, LIGHT_P0 + 1] + r * ny
        z = lights[k, LIGHT_P0 + 2] + r * nz
        side = 1.0
    else:
        x = lights[k, LIGHT_P0] + u1 * lights[k, LIGHT_E1] + u2 * lights[k, LIGHT_E2]
        y = lights[k, LIGHT_P0 + 1] + u1 * lights[k, LIGHT_E1 + 1] + u2 * lights[k, LIGHT_E2 + 1]
        z = lights[k, LIGHT_P0 + 2] + u1 * lights[k, LIGHT_E1 + 2] + u2 * lights[k, LIGHT_E2 + 2]
        nx, ny, nz = quad_normal(lights, k)
        side = 1.0
        if lights[k, LIGHT_TWO_SIDED] > 0.0:  # a side drawn at random: its power doubled
            side = 2.0
            if rand(st, 0) < 0.5:
                nx, ny, nz = -nx, -ny, -nz
    vx, vy, vz = centre[0] - x, centre[1] - y, centre[2] - z
    d = math.sqrt(vx * vx + vy * vy + vz * vz)
    u3, u4 = rand(st, 0), rand(st, 0)
    if d <= radius:
        wx, wy, wz = uniform_sphere(u3, u4)
        pdf_dir = 1.0 / (4.0 * math.pi)
    else:
        cos_max = math.sqrt(max(0.0, 1.0 - (radius / d) ** 2))
        wx, wy, wz = around(1.0 - u3 * (1.0 - cos_max), 2.0 * math.pi * u4, vx / d, vy / d, vz / d)
        pdf_dir = 1.0 / (2.0 * math.pi * (1.0 - cos_max))
    cos_l = wx * nx + wy * ny + wz * nz
    alive[i] = cos_l > 0.0
    f = side * cos_l * lights[k, LIGHT_AREA] / (probs[k] * pdf_dir * n) if alive[i] else 0.0
    for c in range(3):
        power[i, c] = lights[k, LIGHT_RGB + c] * f
    pos[i, 0], pos[i, 1], pos[i, 2] = x + eps * nx, y + eps * ny, z + eps * nz
    dirs[i, 0], dirs[i, 1], dirs[i, 2] = wx, wy, wz
    skip[i] = k
    rng[i] = st[0]


@njit(parallel=True, cache=True)
def _photon_step(surfaces, media, pos, dirs, power, medium, smooth, alive, rng, t, surf, ng, ns, tl, eps, stored,
                 s_pos, s_normal):
    for i in prange(pos.shape[0]):
        _photon_step_one(i, surfaces, media, pos, dirs, power, medium, smooth, alive, rng, t, surf, ng, ns, tl, eps,
                         stored, s_pos, s_normal)


@njit(cache=True)
def _photon_step_one(i, surfaces, media, pos, dirs, power, medium, smooth, alive, rng, t, surf, ng, ns, tl, eps,
                     stored, s_pos, s_normal):
    """One interaction of each live photon: it dies where it meets an emitter or nothing; its power takes the
    medium's transmittance over t; at a diffuse surface it is stored (stored[i], at s_pos[i] with s_normal[i],
    facing it) if it crossed a smooth interface before, and dies; at a smooth one it reflects or refracts by
    Fresnel (a mirror's albedo on its power) and goes on."""
    stored[i] = False
    if not alive[i]:
        return
    if tl[i] < t[i] or not np.isfinite(t[i]) or surf[i] < 0:
        alive[i] = False
        return
    m = medium[i]
    if m >= 0:
        for c in range(3):
            power[i, c] *= math.exp(-(media[m, MED_SIGMA_A + c] + media[m, MED_SIGMA_S + c]) * t[i])
    dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
    hx, hy, hz = pos[i, 0] + t[i] * dx, pos[i, 1] + t[i] * dy, pos[i, 2] + t[i] * dz
    s = surf[i]
    entering, gx, gy, gz, nx, ny, nz = incident_side(dx, dy, dz, ng[i, 0], ng[i, 1], ng[i, 2], ns[i, 0], ns[i, 1],
                                                     ns[i, 2])
    stype = surfaces[s, SURF_TYPE]
    if stype == DIFFUSE:
        alive[i] = False
        if smooth[i] > 0:
            stored[i] = True
            s_pos[i, 0], s_pos[i, 1], s_pos[i, 2] = hx, hy, hz
            s_normal[i, 0], s_normal[i, 1], s_normal[i, 2] = gx, gy, gz
        return
    st = np.empty(1, np.uint64)
    st[0] = rng[i]
    through = False
    if stype == MIRROR:
        wx, wy, wz = reflect(dx, dy, dz, nx, ny, nz)
        for c in range(3):
            power[i, c] *= surfaces[s, SURF_ALBEDO + c]
    elif stype == DIELECTRIC:
        wx, wy, wz, through, _, _ = dielectric_choice(surfaces, s, entering, dx, dy, dz, nx, ny, nz, rand(st, 0))
    else:  # a null boundary
        wx, wy, wz, through = dx, dy, dz, True
    rng[i] = st[0]
    o = -eps if through else eps
    if through:
        medium[i] = medium_beyond(surfaces, s, entering)
    pos[i, 0], pos[i, 1], pos[i, 2] = hx + o * gx, hy + o * gy, hz + o * gz
    dirs[i, 0], dirs[i, 1], dirs[i, 2] = wx, wy, wz
    smooth[i] += 1


def trace_photons(bs: BuiltScene, caster, n: int, seed: int, pass_index: int, max_depth: int,
                  deflect: bool = True):
    """n photons of pass pass_index traced to the diffuse surfaces they reach through smooth interfaces (at most
    max_depth of them), turned by the truncated peak's deflections in a truncated medium where deflect
    (peak_deflections.py: photons carry the light paths with no wider scattering, as the camera paths do). Returns
    (pos (m, 3), power (m, 3) W, normal (m, 3): facing the side they arrived from), the stored photons only; None
    where the scene has no smooth surface or no emitter."""
    target = caustic_target(bs)
    if target is None or n <= 0:
        return None
    centre, radius = target
    probs = emitter_weights(bs.lights, centre, radius)
    if not np.any(probs > 0):
        return None
    cdf = np.cumsum(probs)
    cdf[np.flatnonzero(probs > 0)[-1]:] = 2.0  # (no draw past the last emitter, whatever the rounding)
    pos, dirs, power = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    alive, skip, rng = np.empty(n, np.bool_), np.empty(n, np.int64), np.empty(n, np.uint64)
    _emit(bs.lights, cdf, probs, centre, radius, n, seed, CAUSTIC_STREAM + pass_index, bs.eps, pos, dirs, power, alive,
          skip, rng)
    medium, smooth = np.full(n, -1, np.int64), np.zeros(n, np.int64)
    rates = peak_rates(bs.media) if deflect else None
    turns, steps = np.zeros(n, np.int64), np.zeros(n, np.int64)  # each photon's deflections and interactions
    out_pos, out_power, out_normal = [], [], []
    for _ in range(max_depth + 1 + (MAX_TURNS if rates is not None else 0)):  # (a deflection is no interaction)
        live = np.flatnonzero(alive & (steps <= max_depth))
        if len(live) == 0:
            break
        pos, dirs, power, medium, smooth, rng, skip, turns, steps = (
            pos[live], dirs[live], power[live], medium[live], smooth[live], rng[live], skip[live], turns[live],
            steps[live])
        alive = np.ones(len(live), np.bool_)
        t, surf, ng, ns = closest_surface_hits(caster, bs, pos, dirs)
        tl, li = np.empty(len(pos)), np.empty(len(pos), np.int64)
        light_hits(bs.lights, pos, dirs, t, tl, li, skip)
        turned = np.zeros(0, np.int64)
        if rates is not None:  # turned before what they would meet: moved there, no interaction this step
            turned, d, new_dir, advanced = draw_deflections(rates, bs.media, dirs, np.minimum(t, tl), medium, turns,
                                                            rng)
            rng[turned] = advanced
            alive[turned] = False
        stored, s_pos, s_normal = np.empty(len(pos), np.bool_), np.empty((len(pos), 3)), np.empty((len(pos), 3))
        _photon_step(bs.surfaces, bs.media, pos, dirs, power, medium, smooth, alive, rng, t, surf, ng, ns, tl, bs.eps,
                     stored, s_pos, s_normal)
        steps += 1
        if len(turned):
            m = medium[turned]
            sigma_t = bs.media[m, MED_SIGMA_A:MED_SIGMA_A + 3] + bs.media[m, MED_SIGMA_S:MED_SIGMA_S + 3]
            power[turned] *= np.exp(-sigma_t * d[:, None])
            pos[turned] += d[:, None] * dirs[turned]
            dirs[turned] = new_dir
            turns[turned] += 1
            steps[turned] -= 1
            alive[turned] = True
        out_pos.append(s_pos[stored])
        out_power.append(power[stored])
        out_normal.append(s_normal[stored])
        skip = np.full(len(pos), -1, np.int64)  # (only the first segment starts on an emitter)
    if not out_pos:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(out_pos), np.concatenate(out_power), np.concatenate(out_normal)


def radius_scale(radius_px: float, pixel_angle: float, pass_index: int) -> float:
    """The kernel radius per unit of distance from the camera in pass pass_index: radius_px pixel footprints,
    shrunk as (p + 1)^((alpha - 1) / 2)."""
    return radius_px * pixel_angle * (pass_index + 1.0) ** ((SHRINK_ALPHA - 1.0) / 2.0)


def build_map(photons, scale: float, camera_pos: np.ndarray, max_radius: float = np.inf,
              rng: np.random.Generator | None = None) -> CausticMap | None:
    """The photons (trace_photons' tuple) in a hashed grid whose cells are CELL_RADII kernel radii at their median
    distance from the camera (scale: radius per unit of that distance), thinned to about CELL_CAP a cell by rng's
    uniform numbers (None: kept all). None where photons is None (the scene has no caustic path); a map of
    no photons where none was stored (its caustic is then zero, and still replaces the camera paths' emitters
    found after a diffuse bounce)."""
    if photons is None:
        return None
    pos, power, normal = photons
    cell = CELL_RADII * float(np.median(np.linalg.norm(pos - camera_pos, axis=1))) * scale if len(pos) else 1.0
    cell = max(min(cell, CELL_RADII * max_radius), 1e-9)
    ix = np.floor(pos / cell).astype(np.int64)
    buckets = 1 << max(4, int(len(pos) - 1).bit_length())
    b = _bucket(ix, buckets)
    if rng is not None and len(pos):
        keep_p = np.minimum(1.0, CELL_CAP / _cell_counts(ix))
        keep = rng.random(len(pos)) < keep_p
        pos, normal, ix, b = pos[keep], normal[keep], ix[keep], b[keep]
        power = power[keep] / keep_p[keep, None]
    order = np.argsort(b, kind="stable")
    start = np.zeros(buckets + 1, np.int64)
    np.cumsum(np.bincount(b, minlength=buckets), out=start[1:])
    box = np.array([pos.min(0), pos.max(0)]) if len(pos) else np.zeros((2, 3))
    return CausticMap(np.ascontiguousarray(pos[order]), np.ascontiguousarray(power[order]),
                      np.ascontiguousarray(normal[order]), np.ascontiguousarray(ix[order]), start, cell, scale, box,
                      float(max_radius))


def _cell_counts(ix: np.ndarray) -> np.ndarray:
    """How many of the photons share each photon's cell (ix: (n, 3) cell indices)."""
    rel = ix - ix.min(axis=0)
    if rel.max() < (1 << 21):  # the three indices packed in one int64, exactly
        _, inverse, counts = np.unique((rel[:, 0] << 42) | (rel[:, 1] << 21) | rel[:, 2], return_inverse=True,
                                       return_counts=True)
    else:
        _, inverse, counts = np.unique(ix, axis=0, return_inverse=True, return_counts=True)
    return counts[inverse.ravel()]


@njit(cache=True)
def _hash(ix, iy, iz, buckets):
    h = (ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791)
    return h & (buckets - 1)


def _bucket(ix: np.ndarray, buckets: int) -> np.ndarray:
    return (((ix[:, 0] * 73856093) ^ (ix[:, 1] * 19349663) ^ (ix[:, 2] * 83492791)) & (buckets - 1)).astype(np.int64)


@njit(inline="always", cache=True)
def _near_box(box, x, y, z, r):
    """Whether (x, y, z) lies within r of the box (2, 3)."""
    return (box[0, 0] - r <= x <= box[1, 0] + r and box[0, 1] - r <= y <= box[1, 1] + r
            and box[0, 2] - r <= z <= box[1, 2] + r)


@njit(parallel=True, cache=True)
def _gather(pos, power, normal, cell_ix, start, cell, box, max_radius, points, facing, radii, out):
    """out[q] = sum over the photons within r = radii[q] (at most MAX_REACH cells and max_radius) of points[q],
    near its tangent plane and on the side facing[q] faces (PLANE_SLACK), of power x 2 / (pi r^2) (1 - d^2 / r^2)
    (Epanechnikov's kernel over the disc: irradiance, W / unit^2)."""
    buckets = start.shape[0] - 1
    for q in prange(points.shape[0]):
        r = min(radii[q], MAX_REACH * cell, max_radius)
        r2 = r * r
        if pos.shape[0] == 0 or not _near_box(box, points[q, 0], points[q, 1], points[q, 2], r):
            continue
        x, y, z = points[q, 0], points[q, 1], points[q, 2]
        fx, fy, fz = facing[q, 0], facing[q, 1], facing[q, 2]
        e0 = e1 = e2 = 0.0
        for ax in range(int(math.floor((x - r) / cell)), int(math.floor((x + r) / cell)) + 1):
            for ay in range(int(math.floor((y - r) / cell)), int(math.floor((y + r) / cell)) + 1):
                for az in range(int(math.floor((z - r) / cell)), int(math.floor((z + r) / cell)) + 1):
                    b = _hash(ax, ay, az, buckets)
                    for j in range(start[b], start[b + 1]):
                        if cell_ix[j, 0] != ax or cell_ix[j, 1] != ay or cell_ix[j, 2] != az:
                            continue  # another cell in the same bucket
                        dx, dy, dz = pos[j, 0] - x, pos[j, 1] - y, pos[j, 2] - z
                        d2 = dx * dx + dy * dy + dz * dz
                        if d2 >= r2:
                            continue
                        if normal[j, 0] * fx + normal[j, 1] * fy + normal[j, 2] * fz < 0.5:
                            continue
                        if abs(dx * fx + dy * fy + dz * fz) > PLANE_SLACK * r:
                            continue
                        w = 1.0 - d2 / r2
                        e0 += power[j, 0] * w
                        e1 += power[j, 1] * w
                        e2 += power[j, 2] * w
        k = 2.0 / (math.pi * r2)
        out[q, 0], out[q, 1], out[q, 2] = e0 * k, e1 * k, e2 * k


def irradiance(cmap: CausticMap, points: np.ndarray, facing: np.ndarray, distance: np.ndarray) -> np.ndarray:
    """The caustic irradiance (n, 3, W / unit^2) at points (n, 3) on diffuse surfaces, from the side their normal
    facing (n, 3) points to, seen from distance (n,) along the camera path (the kernel's radius: that distance x
    cmap.radius_scale, at most MAX_REACH cells)."""
    out = np.zeros((len(points), 3))
    if len(points):
        _gather(cmap.pos, cmap.power, cmap.normal, cmap.cell_ix, cmap.start, cmap.cell, cmap.box, cmap.max_radius,
                np.ascontiguousarray(points, np.float64), np.ascontiguousarray(facing, np.float64),
                np.ascontiguousarray(distance * cmap.radius_scale, np.float64), out)
    return out


def caustic_map(bs: BuiltScene, caster, photons: int, radius_px: float, pixel_angle: float, seed: int,
                pass_index: int, max_depth: int, deflect: bool = True) -> CausticMap | None:
    """Pass pass_index's caustic map: `photons` photons (at least MIN_PHOTONS) traced (trace_photons, deflect: the
    truncated peak's deflections) in a grid, thinned where they crowd (build_map), None where the scene has no
    caustic path."""
    scale = radius_scale(radius_px, pixel_angle, pass_index)
    return build_map(trace_photons(bs, caster, max(photons, MIN_PHOTONS), seed, pass_index, max_depth, deflect), scale,
                     bs.camera[CAM_POS:CAM_POS + 3], MAX_RADIUS * bs.extent,
                     np.random.default_rng([seed, pass_index, CAUSTIC_STREAM]))
