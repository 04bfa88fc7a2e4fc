"""Unbiased volumetric path tracer (the reference every other method is checked against).

Wavefront structure: a batch of paths lives in flat arrays. Each step
  1. Embree casts the rays of the paths that need a triangle hit (one batched call);
  2. one numba kernel advances every live path as far as it can go without Python: through scattering
     events (free flights shorter than the conservative distance to any triangle need no cast), analytic
     spheres and lights (intersected in the kernel), surfaces, until the path needs a new triangle cast,
     emits a shadow ray, or dies;
  3. shadow rays are resolved the same way (cast, kernel, repeat while they cross null interfaces).

Physics:
- Homogeneous media with RGB coefficients: free-flight distances are sampled in one channel chosen with
  probability proportional to the path throughput, and weighted by the one-sample MIS (balance) over the
  three channels (spectral MIS), so the estimate stays unbiased when sigma_t differs per channel.
- Heterogeneous (density grid, exponential) and emissive media: delta tracking against a majorant with spectral
  tracking's weights, emission collected at every tentative collision, ratio tracking for shadow rays
  (render/media.py).
- Phase functions sampled exactly; smooth dielectrics with Fresnel (reflection or refraction chosen in
  proportion to F), total internal reflection, the (eta_i / eta_t)^2 radiance scale; mirrors; Lambertian.
- Next-event estimation at scattering events and diffuse surfaces, with power-heuristic MIS for area
  lights and the environment. Shadow rays cross null (index-matched) interfaces with the media's
  transmittance and are blocked by anything that refracts.
- Russian roulette from rr_depth on (on throughput with the eta^2 factors undone), a maximum depth.
- Order filter: each contribution is tagged with the number of volume scattering events on its path and
  kept only if that number is in the requested set (0, 1, 2, 3+).
"""

from __future__ import annotations

import math
import time
from collections import namedtuple

import numpy as np
from numba import njit, prange

from pbvol_cli.config import VolpathSettings
from pbvol_cli.geometry.distance_grid import mesh_distance_bound
from pbvol_cli.geometry.intersect import analytic_hit, mesh_shading_normal
from pbvol_cli.geometry.raycast import TriangleCaster
from pbvol_cli.geometry.scene_build import (
    DIELECTRIC,
    HOMOGENEOUS,
    MED_G,
    MED_KIND,
    MED_PHASE,
    MED_SEALED,
    MED_SIGMA_A,
    MIRROR,
    NULL,
    SPH_CENTER,
    SPH_RADIUS,
    SPH_SURFACE,
    SURF_ALBEDO,
    SURF_TYPE,
    BuiltScene,
)
from pbvol_cli.jit import as_runtime
from pbvol_cli.physics.fresnel import reflect, refract
from pbvol_cli.physics.lights import ENVIRONMENT, LIGHT_RGB, LIGHT_TYPE, emitted_toward, light_pdf, light_sample
from pbvol_cli.physics.phase import phase_eval, phase_sample
from pbvol_cli.physics.sampling import cosine_hemisphere, mix64, power_heuristic, rand, seed_state
from pbvol_cli.render.camera import generate_camera_rays
from pbvol_cli.render.interfaces import (
    dielectric_choice,
    dielectric_fresnel,
    incident_side,
    indices,
    medium_beyond,
    shadow_ray_length,
)
from pbvol_cli.render.media import flight_weight, free_flight, segment_transmittance, tentative_collision
from pbvol_cli.render.sample_sums import SampleSums

DEAD, NEED_CAST, CONTINUE = 0, 1, 2
INF = np.inf

# misc[] (path_settings) layout shared by the kernels
M_EPS, M_MAXDEPTH, M_RRDEPTH, M_ORDERS, M_MAXORDER, M_HASMESH, M_NLIGHTS, M_SPLIT, M_SPLIT_AIM = range(9)

# A split-off branch's record (Paths.sp_rec columns): where it starts and what it carries
R_POS, R_DIR, R_BETA, R_MEDIUM, R_DEPTH, R_ETA_SCALE = 0, 3, 6, 9, 10, 11
R_COLS = 12
SPLIT_STREAM = np.uint64(0x9E6C63D0676A9A99)  # a branch's random stream: mix64 of its parent's state xor this

# The kernels' bundles (numba reads them by field name or unpacks them in this order).
SceneTables = namedtuple("SceneTables", ["tri_surface", "tri_normals", "spheres", "surfaces", "media", "lights",
                                         "grid_params", "grid_cells", "density"])
PathState = namedtuple("PathState", ["pos", "dir", "beta", "L", "rng", "status", "medium", "depth", "nscat", "tpend",
                                     "prev_pos", "prev_pdf", "eta_scale", "tmaj"])
SplitState = namedtuple("SplitState", ["count", "rec", "rng"])  # the branches a path split off, in order
ShadowState = namedtuple("ShadowState", ["active", "pos", "dir", "tmax", "contrib", "medium", "light", "rng"])
SHADOW_STREAM = np.uint64(0xD1B54A32D192ED03)  # a shadow ray's ratio tracking: its path's state xor this
TriangleHits = namedtuple("TriangleHits", ["t", "prim", "u", "v", "ng"])


def orders_mask(orders: str | None) -> tuple[int, int]:
    """Parse '0', '1', '2', '3+', comma lists, 'all' -> (bitmask over 0,1,2,3+, highest order needed).

    The highest order is 1 << 30 when '3+' is included (no early termination).
    """
    if orders is None or orders.strip() in ("", "all"):
        return 0b1111, 1 << 30
    mask = 0
    for tok in orders.replace(" ", "").split(","):
        if tok in ("0", "1", "2"):
            mask |= 1 << int(tok)
        elif tok in ("3+", "3"):
            mask |= 1 << 3
        else:
            raise ValueError(f"unknown scattering order {tok!r}; expected 0, 1, 2, 3+ or a comma list")
    top = 1 << 30 if mask & 8 else max(k for k in range(3) if mask & (1 << k))
    return mask, top


class Paths:
    """Structure-of-arrays state of a batch of paths."""

    def __init__(self, n: int, split_slots: int = 1):
        self.pos = np.zeros((n, 3))
        self.dir = np.zeros((n, 3))
        self.beta = np.zeros((n, 3))
        self.L = np.zeros((n, 3))
        self.rng = np.zeros(n, np.uint64)
        self.pixel = np.zeros(n, np.int64)
        self.status = np.zeros(n, np.int8)
        self.medium = np.zeros(n, np.int32)
        self.depth = np.zeros(n, np.int32)
        self.nscat = np.zeros(n, np.int32)
        self.tpend = np.zeros(n)
        self.prev_pos = np.zeros((n, 3))
        self.prev_pdf = np.zeros(n)  # solid-angle pdf of the last non-specular sampling; 0 = no MIS
        self.eta_scale = np.zeros(n)
        self.tmaj = np.zeros(n)  # the majorant at the pending tentative collision (tracked media)
        # the branches a path splits off (at most one per interaction, and it splits at the first split_depth)
        self.sp_count = np.zeros(n, np.int32)
        self.sp_rec = np.zeros((n, max(split_slots, 1), R_COLS))
        self.sp_rng = np.zeros((n, max(split_slots, 1)), np.uint64)
        # shadow-ray slot: one per path and step
        self.sh_active = np.zeros(n, np.bool_)
        self.sh_pos = np.zeros((n, 3))
        self.sh_dir = np.zeros((n, 3))
        self.sh_tmax = np.zeros(n)
        self.sh_C = np.zeros((n, 3))
        self.sh_med = np.zeros(n, np.int32)
        self.sh_light = np.zeros(n, np.int32)  # target light (ignored as an occluder)
        self.sh_rng = np.zeros(n, np.uint64)  # ratio tracking's random stream
        # triangle hits from the last cast
        self.hit_t = np.zeros(n)
        self.hit_prim = np.zeros(n, np.int32)
        self.hit_u = np.zeros(n, np.float32)
        self.hit_v = np.zeros(n, np.float32)
        self.hit_ng = np.zeros((n, 3), np.float32)

    def state(self) -> PathState:
        return PathState(self.pos, self.dir, self.beta, self.L, self.rng, self.status, self.medium, self.depth,
                         self.nscat, self.tpend, self.prev_pos, self.prev_pdf, self.eta_scale, self.tmaj)

    def split(self) -> SplitState:
        return SplitState(self.sp_count, self.sp_rec, self.sp_rng)

    def shadow(self) -> ShadowState:
        return ShadowState(self.sh_active, self.sh_pos, self.sh_dir, self.sh_tmax, self.sh_C, self.sh_med,
                           self.sh_light, self.sh_rng)

    def hits(self) -> TriangleHits:
        return TriangleHits(self.hit_t, self.hit_prim, self.hit_u, self.hit_v, self.hit_ng)


# ----------------------------------------------------------------------------- kernel pieces


@njit(inline="always", cache=True)
def _order_ok(misc, n):
    return (int(misc[M_ORDERS]) >> min(n, 3)) & 1


@njit(inline="always", cache=True)
def _russian_roulette(misc, beta, eta_scale, depth, rng, i):
    """True if the path survives (its throughput rescaled). A path of zero throughput (a black surface, a medium
    that only absorbs) ends at once: its spectral-MIS weights would divide by zero."""
    q = max(beta[i, 0], max(beta[i, 1], beta[i, 2])) * eta_scale[i]
    if q <= 0.0:
        return False
    if depth[i] < misc[M_RRDEPTH]:
        return True
    if q >= 1.0:
        return True
    if rand(rng, i) >= q:
        return False
    beta[i, 0] /= q
    beta[i, 1] /= q
    beta[i, 2] /= q
    return True


@njit(inline="always", cache=True)
def _add_emission(L, beta, i, r, g, b, w):
    L[i, 0] += beta[i, 0] * r * w
    L[i, 1] += beta[i, 1] * g * w
    L[i, 2] += beta[i, 2] * b * w


@njit(cache=True)
def _nee(i, px, py, pz, kind, nx, ny, nz, dx, dy, dz, phase_kind, g, albedo, medium, S, misc, st, sh):
    """Next-event estimation from a scattering point (kind 0, phase toward -d... of propagation d) or a
    diffuse point (kind 1, facing normal n, albedo RGB). Fills the path's shadow slot; True if it did."""
    lights = S.lights
    beta, rng, nscat = st.beta, st.rng, st.nscat
    sh_active, sh_pos, sh_dir, sh_tmax, sh_C, sh_med, sh_light, sh_rng = sh
    nl = lights.shape[0]
    li = min(int(rand(rng, i) * nl), nl - 1)
    u1, u2 = rand(rng, i), rand(rng, i)
    # The random numbers are drawn even when the order filter discards the contribution, so that a render
    # restricted to some orders is exactly the matching part of the unrestricted render.
    if not _order_ok(misc, nscat[i]):
        return False
    wx, wy, wz, dist, Lr, Lg, Lb, pdf, delta = light_sample(lights, li, px, py, pz, u1, u2)
    if pdf <= 0.0 or (Lr == 0.0 and Lg == 0.0 and Lb == 0.0):
        return False
    pdf /= nl
    eps = misc[M_EPS]
    if kind == 0:
        f = phase_eval(phase_kind, g, dx * wx + dy * wy + dz * wz)
        fr = fg = fb = f
        ox, oy, oz = px, py, pz
    else:
        c = nx * wx + ny * wy + nz * wz
        if c <= 0.0:
            return False
        f = c / math.pi
        fr, fg, fb = albedo[0] * f, albedo[1] * f, albedo[2] * f
        ox, oy, oz = px + eps * nx, py + eps * ny, pz + eps * nz
    w = 1.0 if delta else power_heuristic(pdf, f)
    scale = w / pdf
    sh_C[i, 0] = beta[i, 0] * fr * Lr * scale
    sh_C[i, 1] = beta[i, 1] * fg * Lg * scale
    sh_C[i, 2] = beta[i, 2] * fb * Lb * scale
    sh_pos[i, 0], sh_pos[i, 1], sh_pos[i, 2] = ox, oy, oz
    sh_dir[i, 0], sh_dir[i, 1], sh_dir[i, 2] = wx, wy, wz
    sh_tmax[i] = shadow_ray_length(dist, eps)
    sh_med[i] = medium
    sh_light[i] = li
    sh_rng[i] = rng[i] ^ SHADOW_STREAM
    sh_active[i] = True
    return True


@njit(inline="always", cache=True)
def _split_off(i, sp, rng, px, py, pz, dx, dy, dz, b0, b1, b2, medium, depth, eta_scale):
    """Append a branch that starts at p in direction d with throughput b to path i's split-off branches; its
    random stream is drawn from the path's."""
    count, rec, sp_rng = sp
    k = count[i]
    rand(rng, i)  # the parent's stream moves on: two branches it splits off never share a stream
    sp_rng[i, k] = mix64(rng[i] ^ SPLIT_STREAM)
    rec[i, k, R_POS], rec[i, k, R_POS + 1], rec[i, k, R_POS + 2] = px, py, pz
    rec[i, k, R_DIR], rec[i, k, R_DIR + 1], rec[i, k, R_DIR + 2] = dx, dy, dz
    rec[i, k, R_BETA], rec[i, k, R_BETA + 1], rec[i, k, R_BETA + 2] = b0, b1, b2
    rec[i, k, R_MEDIUM], rec[i, k, R_DEPTH], rec[i, k, R_ETA_SCALE] = medium, depth, eta_scale
    count[i] = k + 1


@njit(inline="always", cache=True)
def _resume_branch(i, S, st, sp):
    """Path i's slot takes up the last branch the path split off (its radiance goes on adding to L[i]). Its split
    branches form a stack of increasing depth, so a slot never holds more than split_depth of them."""
    count, rec, sp_rng = sp
    pos, dirs, beta, L, rng, status, medium, depth, nscat, tpend, prev_pos, prev_pdf, eta_scale, tmaj = st
    k = count[i] - 1
    count[i] = k
    for c in range(3):
        pos[i, c] = rec[i, k, R_POS + c]
        dirs[i, c] = rec[i, k, R_DIR + c]
        beta[i, c] = rec[i, k, R_BETA + c]
    rng[i] = sp_rng[i, k]
    status[i] = CONTINUE
    medium[i] = int(rec[i, k, R_MEDIUM])
    depth[i] = int(rec[i, k, R_DEPTH])
    nscat[i] = 0  # only unscattered paths split
    prev_pdf[i] = 0.0  # a specular event
    eta_scale[i] = rec[i, k, R_ETA_SCALE]
    tpend[i] = INF
    if medium[i] >= 0:
        tpend[i] = free_flight(S.media, medium[i], beta, i, rng, S.density, pos, dirs, tmaj)


# phase_sample inlined into the path kernel (about 15 % of a scattering event's time in a dense medium); inlined
# everywhere, numba's array analysis rejects it in parallel kernels. Not cached itself: the kernel's cache holds it.
phase_sample_inline = njit(inline="always")(phase_sample.py_func)


@njit(cache=True)
def _path_advance(active, lo, hi, S, misc, st, sh, hits, sp):
    """Advance paths active[lo:hi] each until it needs a triangle cast, has emitted a shadow ray, or is dead.

    Splitting: at the first misc[M_SPLIT] interactions of a path that has not scattered, a smooth dielectric's
    reflection goes on as a branch of weight F while the path refracts with weight 1 - F (instead of one of the
    two chosen with probability F). A light seen in or through a smooth boundary is then no longer the noisiest
    part of the image (its mirror image on a glass: relative variance (1 - F) / F, about 24 a sample at normal
    incidence). With misc[M_SPLIT_AIM] only where the reflection points at a light (an analytic test that ignores
    occluders: unbiased either way). The branch is an ordinary path from there on, traced in its parent's slot once
    the parent has ended (last split off, first traced), its radiance added to the same L."""
    tri_surface, tri_normals, spheres, surfaces, media, lights, grid_params, grid_cells, density = S
    pos, dirs, beta, L, rng, status, medium, depth, nscat, tpend, prev_pos, prev_pdf, eta_scale, tmaj = st
    hit_t, hit_prim, hit_u, hit_v, hit_ng = hits
    eps = misc[M_EPS]
    has_mesh = misc[M_HASMESH] > 0.0
    split_depth = misc[M_SPLIT]
    nl = lights.shape[0]
    for j in range(lo, hi):
        i = active[j]
        fresh = status[i] == NEED_CAST
        while True:
            if status[i] == DEAD:  # the path ended: the last branch it split off takes its slot, or the slot ends
                if sp[0][i] == 0:
                    break
                _resume_branch(i, S, st, sp)
                fresh = False
            ox, oy, oz = pos[i, 0], pos[i, 1], pos[i, 2]
            dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
            m = medium[i]
            tp = tpend[i] if m >= 0 else INF
            # --- the closest event along the ray: scattering (tp), analytic hit, or triangle hit
            ta, akind, aidx = analytic_hit(spheres, lights, ox, oy, oz, dx, dy, dz, INF)
            if fresh:
                tm, prim = hit_t[i], hit_prim[i]
                fresh = False
            else:
                tm, prim = INF, -1
                if has_mesh:
                    need = min(tp, ta)
                    if not (need < mesh_distance_bound(grid_params, grid_cells, ox, oy, oz)):
                        status[i] = NEED_CAST
                        break
            tsurf = min(ta, tm)
            if m >= 0:
                if tp < tsurf:
                    px, py, pz = ox + tp * dx, oy + tp * dy, oz + tp * dz
                    if media[m, MED_KIND] != HOMOGENEOUS:
                        # ---------------- a tentative collision: emission, then a real or a null collision
                        real, e0, e1, e2 = tentative_collision(media, density, m, beta, i, px, py, pz, rng, tmaj[i])
                        if _order_ok(misc, nscat[i]):
                            L[i, 0] += e0
                            L[i, 1] += e1
                            L[i, 2] += e2
                        if not real:
                            if beta[i, 0] == 0.0 and beta[i, 1] == 0.0 and beta[i, 2] == 0.0:
                                status[i] = DEAD
                                continue
                            pos[i, 0], pos[i, 1], pos[i, 2] = px, py, pz
                            tpend[i] = free_flight(media, m, beta, i, rng, density, pos, dirs, tmaj)
                            if tm < INF:  # the same ray: its triangle hit is still ahead, tp nearer
                                hit_t[i] = tm - tp
                                fresh = True
                            continue
                    else:
                        flight_weight(media, m, beta, i, tp, True)
                    # ---------------- scattering event
                    nscat[i] += 1
                    depth[i] += 1
                    if depth[i] > misc[M_MAXDEPTH] or nscat[i] > misc[M_MAXORDER]:
                        status[i] = DEAD
                        continue
                    kind, g = int(media[m, MED_PHASE]), media[m, MED_G]
                    # MIS applies whenever the NEE strategy is on here, whether or not this sample contributed.
                    nee_on = media[m, MED_SEALED] == 0.0 and nl > 0
                    did_nee = False
                    if nee_on:
                        did_nee = _nee(i, px, py, pz, as_runtime(0), 0.0, 0.0, 0.0, dx, dy, dz, kind, g,
                                       media[m, MED_SIGMA_A:MED_SIGMA_A + 3], m, S, misc, st, sh)
                    wx, wy, wz, pdf = phase_sample_inline(kind, g, dx, dy, dz, rand(rng, i), rand(rng, i),
                                                          rand(rng, i))
                    prev_pos[i, 0], prev_pos[i, 1], prev_pos[i, 2] = px, py, pz
                    prev_pdf[i] = pdf if nee_on else 0.0
                    if not _russian_roulette(misc, beta, eta_scale, depth, rng, i):
                        status[i] = DEAD
                        continue
                    pos[i, 0], pos[i, 1], pos[i, 2] = px, py, pz
                    dirs[i, 0], dirs[i, 1], dirs[i, 2] = wx, wy, wz
                    tpend[i] = free_flight(media, m, beta, i, rng, density, pos, dirs, tmaj)
                    if did_nee:
                        status[i] = CONTINUE
                        break
                    continue
                if tsurf < INF and media[m, MED_KIND] == HOMOGENEOUS:
                    flight_weight(media, m, beta, i, tsurf, False)
            # ---------------- escape to the environment
            if tsurf == INF:
                for li in range(nl):
                    if lights[li, LIGHT_TYPE] == ENVIRONMENT and _order_ok(misc, nscat[i]):
                        w = 1.0
                        if prev_pdf[i] > 0.0:
                            w = power_heuristic(prev_pdf[i], light_pdf(lights, li, 0.0, 0.0, 0.0, dx, dy, dz, INF) / nl)
                        _add_emission(L, beta, i, lights[li, LIGHT_RGB], lights[li, LIGHT_RGB + 1],
                                      lights[li, LIGHT_RGB + 2], w)
                status[i] = DEAD
                continue
            hx, hy, hz = ox + tsurf * dx, oy + tsurf * dy, oz + tsurf * dz
            # ---------------- area light
            if tm > ta and akind == 2:
                if _order_ok(misc, nscat[i]):
                    e = emitted_toward(lights, aidx, dx, dy, dz, ox, oy, oz, ta)
                    if e > 0.0:
                        w = 1.0
                        if prev_pdf[i] > 0.0:
                            qx, qy, qz = hx - prev_pos[i, 0], hy - prev_pos[i, 1], hz - prev_pos[i, 2]
                            dist = math.sqrt(qx * qx + qy * qy + qz * qz)
                            w = power_heuristic(prev_pdf[i], light_pdf(lights, aidx, prev_pos[i, 0], prev_pos[i, 1],
                                                                       prev_pos[i, 2], dx, dy, dz, dist) / nl)
                        _add_emission(L, beta, i, lights[aidx, LIGHT_RGB], lights[aidx, LIGHT_RGB + 1],
                                      lights[aidx, LIGHT_RGB + 2], w * e)
                status[i] = DEAD
                continue
            # ---------------- a surface: geometric normal (exterior side) and shading normal
            if tm <= ta:
                s = tri_surface[prim]
                gx, gy, gz = float(hit_ng[i, 0]), float(hit_ng[i, 1]), float(hit_ng[i, 2])
                inv = 1.0 / math.sqrt(gx * gx + gy * gy + gz * gz)
                gx, gy, gz = gx * inv, gy * inv, gz * inv
                nx, ny, nz = mesh_shading_normal(tri_normals, prim, float(hit_u[i]), float(hit_v[i]))
            else:
                s = int(spheres[aidx, SPH_SURFACE])
                r = spheres[aidx, SPH_RADIUS]
                gx = (hx - spheres[aidx, SPH_CENTER]) / r
                gy = (hy - spheres[aidx, SPH_CENTER + 1]) / r
                gz = (hz - spheres[aidx, SPH_CENTER + 2]) / r
                inv = 1.0 / math.sqrt(gx * gx + gy * gy + gz * gz)
                gx, gy, gz = gx * inv, gy * inv, gz * inv
                nx, ny, nz = gx, gy, gz
            stype = surfaces[s, SURF_TYPE]
            entering, fgx, fgy, fgz, fnx, fny, fnz = incident_side(dx, dy, dz, gx, gy, gz, nx, ny, nz)
            if stype == NULL:
                medium[i] = medium_beyond(surfaces, s, entering)
                pos[i, 0], pos[i, 1], pos[i, 2] = hx - eps * fgx, hy - eps * fgy, hz - eps * fgz
                if medium[i] >= 0:
                    tpend[i] = free_flight(media, medium[i], beta, i, rng, density, pos, dirs, tmaj)
                continue
            depth[i] += 1
            if depth[i] > misc[M_MAXDEPTH]:
                status[i] = DEAD
                continue
            did_nee = False
            nee_on = False
            if stype == DIELECTRIC:
                split = False
                if nscat[i] == 0 and depth[i] <= split_depth:
                    eta_i, eta_t = indices(surfaces, s, entering)
                    cos_i, F, cos_t = dielectric_fresnel(eta_i, eta_t, dx, dy, dz, fnx, fny, fnz)
                    if 0.0 < F < 1.0:
                        rx, ry, rz = reflect(dx, dy, dz, fnx, fny, fnz)
                        r_out = rx * gx + ry * gy + rz * gz > 0.0
                        roff = eps if r_out else -eps
                        split = True
                        if misc[M_SPLIT_AIM] > 0.0:
                            _, ak_r, _ = analytic_hit(spheres, lights, hx + roff * gx, hy + roff * gy, hz + roff * gz,
                                                      rx, ry, rz, INF)
                            split = ak_r == 2
                if split:  # the reflection as a branch of weight F, the path refracts with weight 1 - F
                    # Russian roulette sees both branches' throughput without their split weights (as without
                    # the eta^2 factors): each branch lives as long as the chosen one would have
                    _split_off(i, sp, rng, hx + roff * gx, hy + roff * gy, hz + roff * gz, rx, ry, rz,
                               beta[i, 0] * F, beta[i, 1] * F, beta[i, 2] * F,
                               medium_beyond(surfaces, s, not r_out), depth[i], eta_scale[i] / F)
                    wx, wy, wz = refract(dx, dy, dz, fnx, fny, fnz, eta_t / eta_i, cos_i, cos_t)
                    refracted = True
                    beta[i, 0] *= 1.0 - F
                    beta[i, 1] *= 1.0 - F
                    beta[i, 2] *= 1.0 - F
                    eta_scale[i] /= 1.0 - F
                else:
                    wx, wy, wz, refracted, eta_i, eta_t = dielectric_choice(surfaces, s, entering, dx, dy, dz, fnx,
                                                                            fny, fnz, rand(rng, i))
                if refracted:  # radiance scales by (eta_i / eta_t)^2 across the interface
                    k = (eta_i / eta_t) ** 2
                    beta[i, 0] *= k
                    beta[i, 1] *= k
                    beta[i, 2] *= k
                    eta_scale[i] /= k
                prev_pdf[i] = 0.0
            elif stype == MIRROR:
                wx, wy, wz = reflect(dx, dy, dz, fnx, fny, fnz)
                beta[i, 0] *= surfaces[s, SURF_ALBEDO]
                beta[i, 1] *= surfaces[s, SURF_ALBEDO + 1]
                beta[i, 2] *= surfaces[s, SURF_ALBEDO + 2]
                prev_pdf[i] = 0.0
            else:  # DIFFUSE
                cur = medium[i]
                nee_on = (cur < 0 or media[cur, MED_SEALED] == 0.0) and nl > 0
                if nee_on:
                    did_nee = _nee(i, hx, hy, hz, as_runtime(1), fnx, fny, fnz, dx, dy, dz, as_runtime(0), 0.0,
                                   surfaces[s, SURF_ALBEDO:SURF_ALBEDO + 3], cur, S, misc, st, sh)
                wx, wy, wz = cosine_hemisphere(rand(rng, i), rand(rng, i), fnx, fny, fnz)
                c = wx * fnx + wy * fny + wz * fnz
                beta[i, 0] *= surfaces[s, SURF_ALBEDO]
                beta[i, 1] *= surfaces[s, SURF_ALBEDO + 1]
                beta[i, 2] *= surfaces[s, SURF_ALBEDO + 2]
                prev_pdf[i] = c / math.pi if nee_on else 0.0
                prev_pos[i, 0], prev_pos[i, 1], prev_pos[i, 2] = hx, hy, hz
            # side of the geometric surface the new direction leaves on decides the medium
            out_ext = wx * gx + wy * gy + wz * gz > 0.0
            if stype == DIELECTRIC:
                medium[i] = medium_beyond(surfaces, s, not out_ext)
            elif (out_ext != entering):  # opaque surface: a direction below the surface ends the path
                status[i] = DEAD
                continue
            off = eps if out_ext else -eps
            pos[i, 0], pos[i, 1], pos[i, 2] = hx + off * gx, hy + off * gy, hz + off * gz
            dirs[i, 0], dirs[i, 1], dirs[i, 2] = wx, wy, wz
            if not _russian_roulette(misc, beta, eta_scale, depth, rng, i):
                status[i] = DEAD
                continue
            if medium[i] >= 0:
                tpend[i] = free_flight(media, medium[i], beta, i, rng, density, pos, dirs, tmaj)
            if did_nee:
                status[i] = CONTINUE
                break


# Numba pitfall: arrays unpacked from a tuple inside a parallel function lose their writes in prange
# (numba 0.68). Parallel kernels therefore only loop and call an inner function that takes the tuples.


PATH_CHUNK = 256  # paths a kernel call advances: the tuples' arrays are unpacked (reference counts taken) once per
# call, which per path cost about as much as a path that misses everything


@njit(parallel=True, cache=True)
def advance_paths(active, S, misc, st, sh, hits, sp):
    n = active.shape[0]
    for c in prange((n + PATH_CHUNK - 1) // PATH_CHUNK):
        _path_advance(active, c * PATH_CHUNK, min(n, (c + 1) * PATH_CHUNK), S, misc, st, sh, hits, sp)


@njit(parallel=True, cache=True)
def advance_shadows(active, fresh_flags, S, misc, sh, hits, L):
    """Move shadow rays forward through null interfaces; add the unblocked ones to L.

    Leaves sh_active True (and fresh_flags[k] = 1) for rays that need a triangle cast.
    """
    n = active.shape[0]
    for c in prange((n + PATH_CHUNK - 1) // PATH_CHUNK):
        _shadow_advance(active, c * PATH_CHUNK, min(n, (c + 1) * PATH_CHUNK), fresh_flags, S, misc, sh, hits, L)


@njit(cache=True)
def _shadow_advance(active, lo, hi, fresh_flags, S, misc, sh, hits, L):
    tri_surface, tri_normals, spheres, surfaces, media, lights, grid_params, grid_cells, density = S
    sh_active, sh_pos, sh_dir, sh_tmax, sh_C, sh_med, sh_light, sh_rng = sh
    hit_t, hit_prim, hit_u, hit_v, hit_ng = hits
    eps = misc[M_EPS]
    has_mesh = misc[M_HASMESH] > 0.0
    for k in range(lo, hi):
        i = active[k]
        fresh = fresh_flags[k] == 1
        fresh_flags[k] = 0
        while True:
            ox, oy, oz = sh_pos[i, 0], sh_pos[i, 1], sh_pos[i, 2]
            dx, dy, dz = sh_dir[i, 0], sh_dir[i, 1], sh_dir[i, 2]
            tmax = sh_tmax[i]
            ta, akind, aidx = analytic_hit(spheres, lights, ox, oy, oz, dx, dy, dz, tmax, sh_light[i])
            if fresh:
                tm, prim = hit_t[i], hit_prim[i]
                fresh = False
            else:
                tm, prim = INF, -1
                if has_mesh and not (min(ta, tmax) < mesh_distance_bound(grid_params, grid_cells, ox, oy, oz)):
                    fresh_flags[k] = 1
                    break
            t = min(ta, tm)
            m = sh_med[i]
            if t >= tmax:
                if m >= 0 and tmax < INF:
                    segment_transmittance(media, density, m, ox, oy, oz, dx, dy, dz, tmax, sh_rng, i, sh_C)
                elif m >= 0:
                    sh_C[i, 0] = sh_C[i, 1] = sh_C[i, 2] = 0.0
                L[i, 0] += sh_C[i, 0]
                L[i, 1] += sh_C[i, 1]
                L[i, 2] += sh_C[i, 2]
                sh_active[i] = False
                break
            if tm <= ta:
                s = tri_surface[prim]
                gx, gy, gz = float(hit_ng[i, 0]), float(hit_ng[i, 1]), float(hit_ng[i, 2])
            elif akind == 1:
                s = int(spheres[aidx, SPH_SURFACE])
                hx, hy, hz = ox + t * dx, oy + t * dy, oz + t * dz
                gx, gy = hx - spheres[aidx, SPH_CENTER], hy - spheres[aidx, SPH_CENTER + 1]
                gz = hz - spheres[aidx, SPH_CENTER + 2]
            else:
                s = -1
            if s < 0 or surfaces[s, SURF_TYPE] != NULL:
                sh_active[i] = False  # blocked
                break
            if m >= 0:
                segment_transmittance(media, density, m, ox, oy, oz, dx, dy, dz, t, sh_rng, i, sh_C)
            inv = 1.0 / math.sqrt(gx * gx + gy * gy + gz * gz)
            gx, gy, gz = gx * inv, gy * inv, gz * inv
            entering = dx * gx + dy * gy + dz * gz < 0.0
            sh_med[i] = medium_beyond(surfaces, s, entering)
            sgn = -1.0 if entering else 1.0
            sh_pos[i, 0] = ox + t * dx + sgn * eps * gx
            sh_pos[i, 1] = oy + t * dy + sgn * eps * gy
            sh_pos[i, 2] = oz + t * dz + sgn * eps * gz
            sh_tmax[i] = tmax - t


@njit(parallel=True, cache=True)
def init_paths(n, st):
    for i in prange(n):
        _init_path(np.int64(i), st)  # (int64: prange's uint64 index would compile a second copy)


@njit(cache=True)
def _init_path(i, st):
    pos, dirs, beta, L, rng, status, medium, depth, nscat, tpend, prev_pos, prev_pdf, eta_scale, tmaj = st
    beta[i, 0] = beta[i, 1] = beta[i, 2] = 1.0
    L[i, 0] = L[i, 1] = L[i, 2] = 0.0
    status[i] = NEED_CAST
    medium[i] = -1
    depth[i] = 0
    nscat[i] = 0
    tpend[i] = INF
    prev_pdf[i] = 0.0
    eta_scale[i] = 1.0


# ----------------------------------------------------------------------------- driver


def _cast_into(caster: TriangleCaster, idx, origins, dirs, hits):
    t, prim, u, v, ng = caster.closest_hit(origins[idx], dirs[idx])
    hits.t[idx], hits.prim[idx], hits.u[idx], hits.v[idx], hits.ng[idx] = t, prim, u, v, ng


def _run_batch(P: Paths, n: int, caster: TriangleCaster, S, misc) -> tuple[int, int]:
    """Trace the first n paths of P (positions, directions and random streams set) to their end, with every
    branch they split off; their radiance accumulates in P.L. Returns (rays cast, kernel steps)."""
    init_paths(n, P.state())
    st, sh, hits, sp = P.state(), P.shadow(), P.hits(), P.split()
    P.status[n:] = DEAD
    P.sh_active[:] = False
    P.sp_count[:n] = 0
    casts = steps = 0
    active = np.arange(n)  # the paths still alive, ascending: each step scans these, not the whole batch
    while True:
        status = P.status[active]
        need = active[status == NEED_CAST]
        if len(need) and not caster.empty:
            _cast_into(caster, need, P.pos, P.dir, hits)
            casts += len(need)
        elif len(need):
            P.hit_t[need] = INF
            P.hit_prim[need] = -1
        active = active[status != DEAD]
        if len(active) == 0:
            break
        advance_paths(active, S, misc, st, sh, hits, sp)
        steps += 1
        sh_idx = active[P.sh_active[active]]  # (a path that left a shadow ray may have ended since)
        fresh = np.zeros(len(sh_idx), np.int8)
        while len(sh_idx):
            advance_shadows(sh_idx, fresh, S, misc, sh, hits, P.L)
            keep = P.sh_active[sh_idx]
            sh_idx, fresh = sh_idx[keep], fresh[keep]
            if len(sh_idx):
                _cast_into(caster, sh_idx, P.sh_pos, P.sh_dir, hits)
                casts += len(sh_idx)
                fresh[:] = 1
    return casts, steps


SPLIT_DEPTH = VolpathSettings.model_fields["split_depth"].default
SPLIT_RULE = VolpathSettings.model_fields["split_rule"].default


def path_settings(bs: BuiltScene, max_depth: int, rr_depth: int, orders: str | None,
                  split_depth: int = 0, split_rule: str = "auto") -> np.ndarray:
    """The kernels' settings (columns M_*): ray offset, maximum depth, Russian roulette's start, the scattering
    orders kept (a bitmask over 0, 1, 2, 3+) and the highest needed, whether there are triangles, the lights, and
    how many interactions of an unscattered path split (0: none) and whether only reflections aimed at a light
    do (split_rule: "lights", or "auto" in a scene with triangles, where every branch's segment costs a ray cast;
    "all": every one)."""
    mask, top = orders_mask(orders)
    misc = np.zeros(9)
    misc[M_SPLIT] = split_depth
    misc[M_SPLIT_AIM] = float(split_rule == "lights" or (split_rule == "auto" and len(bs.faces) > 0))
    misc[M_EPS], misc[M_MAXDEPTH], misc[M_RRDEPTH] = bs.eps, max_depth, rr_depth
    misc[M_ORDERS], misc[M_MAXORDER] = mask, top
    misc[M_HASMESH] = float(len(bs.faces) > 0)
    misc[M_NLIGHTS] = len(bs.lights)
    return misc


@njit(parallel=True, cache=True)
def _seed_streams(seed, stream, n, rng):
    for k in prange(n):
        rng[k] = seed_state(seed, stream, k)


def trace_radiance(bs: BuiltScene, caster: TriangleCaster, origins: np.ndarray, dirs: np.ndarray, seed: int,
                   orders: str | None, max_depth: int = 1000, rr_depth: int = 8,
                   batch_paths: int = 262144) -> np.ndarray:
    """Radiance (n, 3) arriving at origins from dirs (the rays start outside every medium), one path each, with
    the contributions of the requested scattering orders (volume scattering events on the path) only. Path k's
    random stream depends only on (seed, k). Emission met by the first segment counts like any other."""
    n_all = len(origins)
    out = np.zeros((n_all, 3))
    if n_all == 0:
        return out
    misc = path_settings(bs, max_depth, rr_depth, orders)
    S = scene_tuple(bs)
    P = Paths(min(batch_paths, n_all))
    for a in range(0, n_all, batch_paths):
        n = min(batch_paths, n_all - a)
        P.pos[:n], P.dir[:n] = origins[a:a + n], dirs[a:a + n]
        _seed_streams(seed, 0x7A0 + a // batch_paths, n, P.rng)
        _run_batch(P, n, caster, S, misc)
        out[a:a + n] = P.L[:n]
    return out


def scene_tuple(bs: BuiltScene) -> SceneTables:
    return SceneTables(bs.tri_surface, bs.tri_normals, bs.spheres, bs.surfaces, bs.media, bs.lights,
                       bs.grid_params, bs.grid_cells, bs.density_data)


def render_volpath(bs: BuiltScene, spp: int, seed: int, max_depth: int, rr_depth: int, orders: str | None,
                   batch_paths: int, threads: int, time_limit: float | None = None, progress=None,
                   first_sample: int = 0, split_depth: int = SPLIT_DEPTH, split_rule: str = SPLIT_RULE):
    """Render samples first_sample .. first_sample + spp - 1 of every pixel; returns (image (H, W, 3) float64, spp
    actually rendered, statistics dict; stats["sums"]: their render/sample_sums.SampleSums, which merge exactly
    with other ranges').

    progress(done_paths, total_paths) is called after every batch.
    """
    W, H = bs.resolution
    npix = W * H
    misc = path_settings(bs, max_depth, rr_depth, orders, split_depth, split_rule)
    S = scene_tuple(bs)
    caster = TriangleCaster(bs.vertices, bs.faces, threads)
    total = npix * spp
    if split_depth > 0:  # the branches' slots take about as much memory as the rest of a path's state
        batch_paths = max(1024, batch_paths // 2)
    # Batches hold whole passes (all pixels, one or more samples) so a time limit leaves equal counts.
    per_batch = max(npix, (batch_paths // npix) * npix) if npix <= batch_paths else batch_paths
    P = Paths(min(per_batch, total), split_depth)
    sums = SampleSums()
    current = np.zeros((npix, 3))  # the sample being filled (one path per pixel: values placed, not added)
    t0 = time.perf_counter()
    done = 0
    casts = 0
    steps = 0
    start = first_sample * npix
    while done < total:
        n = min(per_batch, total - done)
        generate_camera_rays(bs.camera, seed, start + done, n, P.pos, P.dir, P.pixel, P.rng)
        c_, s_ = _run_batch(P, n, caster, S, misc)
        casts, steps = casts + c_, steps + s_
        k0 = 0
        while k0 < n:  # the batch's samples, or its share of them (a batch smaller than the image)
            k1 = min(n, k0 + npix - (done + k0) % npix)
            current[P.pixel[k0:k1]] = P.L[k0:k1]
            if (done + k1) % npix == 0:
                sums.add_sample(first_sample + (done + k1) // npix - 1, current)
            k0 = k1
        done += n
        if progress is not None:
            progress(done, total)
        if time_limit is not None and time.perf_counter() - t0 > time_limit and done % npix == 0:
            break
    caster.close()
    spp_done = done // npix
    image = sums.total() if sums.nodes else np.zeros((npix, 3))
    img = (image / max(spp_done, 1)).reshape(H, W, 3)
    elapsed = time.perf_counter() - t0
    return img, spp_done, {"time_s": elapsed, "paths": done, "casts": casts, "steps": steps, "sums": sums}
