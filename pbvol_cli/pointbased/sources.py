"""A volume sample as a source of double and multiple scattering at a camera point P (Wang et al. 2016, eqs. 5-6).

A volume sample scatters the power Phi^s = Phi sigma_s / sigma_t (1 - e^(-sigma_t l)) (W) along its segment, with
intensity Phi^s p(d . m) toward direction m. At P, toward the propagation direction w (W m^-3 sr^-1, per channel):
- double:   sigma_s p(m . w) Phi^s p(d . m) <e^(-sigma_t r) / r^2>, m = (P - x) / r, the average <> over a ball of
            the source's extent (inverse_square.attenuated_inv_r2_ball) rather than a clamped 1/r^2;
- multiple: Phi^s sigma_t^3 S_table(sigma_t (P - x), w) in the frame of (x, d) (multiple_scattering/table.py:
            scaled_lookup), corrected for the boundary by mirror images (source_terms).
A segment far from P is one point source at its centre; near P, or long in mean free paths for the table, it is
split into sub-segments, each with its exact share of the power (split_terms).
"""

import math
from collections import namedtuple

import numpy as np
from numba import njit

from pbvol_cli.jit import as_runtime
from pbvol_cli.multiple_scattering.table import scaled_lookup
from pbvol_cli.physics.phase import mean_cosine, phase_eval
from pbvol_cli.physics.sampling import stratified_depth
from pbvol_cli.pointbased.inverse_square import attenuated_inv_r2_ball
from pbvol_cli.pointbased.volume_samples import ENTRY_N, ENTRY_Q, EXIT_N, EXIT_Q, IMAGE_CURVED, IMAGE_FLAT

Source = namedtuple("Source", ["x", "y", "z", "dx", "dy", "dz", "pr", "pg", "pb", "extent"])
Source.__doc__ = """A point source: position, unit direction of its beam, scattered power (RGB, W), and the radius of
the ball its double scattering is smeared over (scene units)."""

NEAR_READ_TRANSPORT = 1.0  # the multiple term reads the table no nearer a source than its extent, and that at most
# this many transport mean free paths of the densest channel (source_terms)
NEAR_SUB = 8  # sub-points along a segment that is close to P (double scattering)
MS_CELL = 0.1  # mean free paths: segments longer than this are split for the multiple-scattering look-up
NEAR_ALONG = 3.0  # double scattering's near field reaches this many times farther along a source's beam than across
# it (beam_distance): a beam passing through P puts its upstream segments just beyond r_near, each a tiny share of
# the power, and the cut drew them rarely with large weights (the milk glass's tails, docs/pbl.md)


@njit(inline="always", cache=True)
def beam_distance(rx, ry, rz, dx, dy, dz):
    """The distance near_weight judges between a source point and P = the point + (rx, ry, rz): the part across
    the source's beam (unit direction d) as it is, the part along it divided by NEAR_ALONG."""
    a = rx * dx + ry * dy + rz * dz
    across2 = max(rx * rx + ry * ry + rz * rz - a * a, 0.0)
    return math.sqrt(across2 + (a / NEAR_ALONG) ** 2)


@njit(inline="always", cache=True)
def near_weight(r, split):
    """The share of double scattering's kernel at beam distance r (beam_distance) that a pass takes: split = 0, all of it; split = R > 0,
    the near field's, 1 within R/2 falling linearly to 0 at R (summed over every source there: light_cut's near
    pass); split = -R, the rest (by the stochastic cut). The two parts sum to 1 at every r."""
    if split == 0.0:
        return 1.0
    R = abs(split)
    s = 1.0 if r <= 0.5 * R else (2.0 * (1.0 - r / R) if r < R else 0.0)
    return s if split > 0.0 else 1.0 - s


@njit(inline="always", cache=True)
def transport_share(kind, g):
    """1 - mean cosine of the phase function (physics.phase.mean_cosine): sigma_t' = sigma_a + this x sigma_s."""
    return 1.0 - mean_cosine(kind, g)


@njit(inline="always", cache=True)
def on_flat_face(faces, nx, ny, nz, q):
    """Whether the plane n . x = q (unit n, either orientation) is one of faces (flat_faces.medium_faces's)."""
    for f in range(faces.shape[0]):
        c = nx * faces[f, 0] + ny * faces[f, 1] + nz * faces[f, 2]
        if abs(c) > 1.0 - 1e-6 and abs(q - c * faces[f, 3]) <= faces[f, 4]:
            return True
    return False


@njit(inline="always", cache=True)
def near_radius(src, depth, med, rclamp):
    """The radius (scene units) over which a source's light counts as spread: double scattering averages its 1/r^2
    over a ball of it, and the multiple term reads the table no nearer. The source's extent, shrunk toward its
    boundary plane to its depth there (depth, inf: no plane) but not below half the extent (a ball poking out of the
    medium puts light where no camera point gathers it; shrunk further, the bounced layer's gather on the boundary
    met spikes); at most NEAR_READ_TRANSPORT transport mean free paths of the densest channel (a beam many mean
    free paths wide, read at its radius, lost the light that diffuses within it: a box 1000 mean free paths thick
    read multiple 0.02 of 3+); at least rclamp."""
    c = src.extent if depth == np.inf else min(src.extent, max(depth, 0.5 * src.extent))
    st_t = 0.0  # (the densest channel's sigma_t')
    for k in range(3):
        st_t = max(st_t, med.sigma_a[k] + transport_share(med.phase, med.g) * med.sigma_s[k])
    return max(rclamp, min(c, NEAR_READ_TRANSPORT / max(st_t, 1e-30)))


@njit(cache=True)
def source_terms(src, plane, med, q, rclamp, do_double, do_multiple, tabs, split, out_d, out_m):
    """Double (into out_d) and multiple (into out_m) scattering at q (Query) from src (Source) in med (Medium).

    plane (PLANE_COLS,): the boundary's tangent planes n . x = q where the source's beam entered and leaves (normals
    outward, q = inf: none), the nearer of which is the source's boundary plane. The ball of double scattering
    shrinks to the source's depth below that plane, down to half its radius (a ball poking out of the medium puts
    part of the source's light where no camera point gathers it; shrunk further, the bounced layer's gather on the
    boundary itself met spikes), and is at least rclamp wide. split: which part of double scattering
    (near_weight); tabs: the medium's three tables (R, G, B)."""
    x, y, z, dx, dy, dz = src.x, src.y, src.z, src.dx, src.dy, src.dz
    px, py, pz, wx, wy, wz, pplane = q.x, q.y, q.z, q.wx, q.wy, q.wz, q.plane
    sig_a, sig_s, kind, g = med.sigma_a, med.sigma_s, med.phase, med.g
    nx, ny, nz, qn = plane[ENTRY_N], plane[ENTRY_N + 1], plane[ENTRY_N + 2], plane[ENTRY_Q]
    # the plane nearer this point, not the segment's centre: the last segment of a beam spans from near its entry
    # to its exit, and its points near the entry mirrored in the exit plane kept nearly all of the table's light
    if (plane[EXIT_Q] - (plane[EXIT_N] * x + plane[EXIT_N + 1] * y + plane[EXIT_N + 2] * z)
            < qn - (nx * x + ny * y + nz * z)):
        nx, ny, nz, qn = plane[EXIT_N], plane[EXIT_N + 1], plane[EXIT_N + 2], plane[EXIT_Q]
    rx, ry, rz = px - x, py - y, pz - z
    r2 = rx * rx + ry * ry + rz * rz
    r = math.sqrt(r2)
    part = near_weight(beam_distance(rx, ry, rz, dx, dy, dz), split) if do_double else 0.0
    near = near_radius(src, qn - (nx * x + ny * y + nz * z) if qn < np.inf else np.inf, med, rclamp)
    if part > 0.0 and r > 0.0:
        c = near
        mx, my, mz = rx / r, ry / r, rz / r
        lobe = phase_eval(kind, g, dx * mx + dy * my + dz * mz)
        f = phase_eval(kind, g, mx * wx + my * wy + mz * wz) * lobe * part
        out_d[0] += sig_s[0] * src.pr * f * attenuated_inv_r2_ball(r, c, sig_a[0] + sig_s[0])
        out_d[1] += sig_s[1] * src.pg * f * attenuated_inv_r2_ball(r, c, sig_a[1] + sig_s[1])
        out_d[2] += sig_s[2] * src.pb * f * attenuated_inv_r2_ball(r, c, sig_a[2] + sig_s[2])
    if do_multiple:
        # The table's medium is infinite. Corrected by the method of images twice: a mirror image of the source
        # (lobe mirrored) behind the source's boundary plane and another behind P's (the camera segment's nearer
        # end plane), each plane moved out by med.image_k transport mean free paths (image_planes.py: 0.25 on
        # small bodies' curved parts, 0.45 on flat faces, toward diffusion's 0.7104 on bodies many diffusion
        # lengths thick). Each image gives a
        # factor f = 1 - image / table in [0, 1] (the half-space's response is never negative); P's factor enters
        # as f_P^w, w = (1 - n . n_P) / 2: where both points are under the same plane it is the same image, counted
        # once, while a source under the far side of a body (n_P = -n) gets both (docs/pbl.md). A plane on a flat
        # face of the boundary (flat_faces.py) takes image_k's row IMAGE_FLAT.
        image = qn < np.inf
        image_p = pplane[3] < np.inf
        dn = 2.0 * (dx * nx + dy * ny + dz * nz)
        ex, ey, ez = dx - dn * nx, dy - dn * ny, dz - dn * nz
        ax, ay, az = pplane[0], pplane[1], pplane[2]
        dp = 2.0 * (dx * ax + dy * ay + dz * az)
        fx, fy, fz = dx - dp * ax, dy - dp * ay, dz - dp * az
        wp = 0.5 * (1.0 - (nx * ax + ny * ay + nz * az)) if image else 1.0
        flat_s = image and on_flat_face(med.faces, nx, ny, nz, qn)
        flat_p = image_p and on_flat_face(med.faces, ax, ay, az, pplane[3])
        # the table read no nearer the source than its extent, as double scattering's ball: a sample stands for
        # light spread over its kernel, and its table value a hundredth of a mean free path away was a rare spike
        # of hundreds of times the mean (the milk's tails, docs/pbl.md)
        cm = near
        sx, sy, sz = rx, ry, rz
        if r < cm:
            if r > 0.0:
                sx, sy, sz = rx * (cm / r), ry * (cm / r), rz * (cm / r)
            else:
                sx, sy, sz = cm * dx, cm * dy, cm * dz  # (at the source itself: ahead along its beam)
        for c in range(3):
            Pc = src.pr if c == 0 else (src.pg if c == 1 else src.pb)
            st = sig_a[c] + sig_s[c]
            v0 = scaled_lookup(tabs[c], Pc, st, sx, sy, sz, dx, dy, dz, wx, wy, wz)
            if v0 <= 0.0:
                continue
            v = v0
            transport_mfp = 1.0 / max(sig_a[c] + transport_share(kind, g) * sig_s[c], 1e-30)
            if image:
                k_s = med.image_k[IMAGE_FLAT if flat_s else IMAGE_CURVED, c]
                h = 2.0 * (max(qn - (nx * x + ny * y + nz * z), 0.0) + k_s * transport_mfp)
                vi = scaled_lookup(tabs[c], Pc, st, rx - h * nx, ry - h * ny, rz - h * nz, ex, ey, ez, wx, wy, wz)
                v *= min(max(1.0 - vi / v0, 0.0), 1.0)
            if image_p and wp > 0.0 and v > 0.0:
                k_p = med.image_k[IMAGE_FLAT if flat_p else IMAGE_CURVED, c]
                h = 2.0 * (max(pplane[3] - (ax * x + ay * y + az * z), 0.0) + k_p * transport_mfp)
                vi = scaled_lookup(tabs[c], Pc, st, rx - h * ax, ry - h * ay, rz - h * az, fx, fy, fz, wx, wy, wz)
                v *= min(max(1.0 - vi / v0, 0.0), 1.0) ** wp
            out_m[c] += v


@njit(cache=True)
def sample_terms(i, vs, med, q, rclamp, do_double, do_multiple, split, u, out_d, out_m):
    """Volume sample i of vs (VolumeSamples) as a source at q (split: near_weight's). Double scattering: one point
    far from P (beyond two segment lengths); near P NEAR_SUB points along the segment, each with its exact share
    of the power, so that 1/r^2 needs smoothing only at the beam's radius. Multiple scattering: the table is smooth
    on the scale of its cells, so near P one look-up per MS_CELL mean free paths of segment; far from P one
    look-up at a point drawn along the segment from u in [0, 1) (random_point_terms)."""
    v_centre, v_len, v_dir, v_scat = vs.centre, vs.len, vs.dir, vs.scat
    sig_a, sig_s = med.sigma_a, med.sigma_s
    cx, cy, cz = q.x - v_centre[i, 0], q.y - v_centre[i, 1], q.z - v_centre[i, 2]
    ln = v_len[i]
    far = cx * cx + cy * cy + cz * cz > 4.0 * ln * ln
    st_max = max(sig_a[0] + sig_s[0], max(sig_a[1] + sig_s[1], sig_a[2] + sig_s[2]))
    n_ms = min(NEAR_SUB, int(math.ceil(st_max * ln / MS_CELL))) if do_multiple else 0
    YES, NO = as_runtime(True), as_runtime(False)  # one compiled source_terms and split_terms for all calls
    if far or not do_double:
        dd = do_double and far  # (an expression among so many arguments trips numba's bytecode analysis)
        whole = Source(v_centre[i, 0], v_centre[i, 1], v_centre[i, 2], v_dir[i, 0], v_dir[i, 1], v_dir[i, 2],
                       v_scat[i, 0], v_scat[i, 1], v_scat[i, 2], max(0.5 * ln, vs.rb[i]))
        if n_ms <= 1:
            source_terms(whole, vs.plane[i], med, q, rclamp, dd, do_multiple, vs.tables, split, out_d, out_m)
            return
        if far and do_double:
            source_terms(whole, vs.plane[i], med, q, rclamp, YES, NO, vs.tables, split, out_d, out_m)
        if far:
            random_point_terms(i, u, vs, med, q, rclamp, split, out_d, out_m)
        else:
            split_terms(i, n_ms, vs, med, q, rclamp, NO, YES, split, out_d, out_m)
        return
    # near, double wanted
    n_near = as_runtime(NEAR_SUB)
    if n_ms == NEAR_SUB:
        split_terms(i, n_near, vs, med, q, rclamp, YES, do_multiple, split, out_d, out_m)
        return
    split_terms(i, n_near, vs, med, q, rclamp, YES, NO, split, out_d, out_m)
    if n_ms > 0:
        split_terms(i, n_ms, vs, med, q, rclamp, NO, YES, split, out_d, out_m)


@njit(cache=True)
def random_point_terms(i, u, vs, med, q, rclamp, split, out_d, out_m):
    """Multiple scattering from volume sample i as one point source at depth t along its segment, drawn from u by
    the density s e^(-s t) / (1 - e^(-s l)) of the medium's smallest extinction s (where the most persistent
    channel scatters), with each channel's power scattered at t over that density: an unbiased estimate of the
    segment's integral. Far from P the table barely changes along a segment, and one look-up costs what the
    MS_CELL split's eight did (the look-ups ruled the multiple term's cost)."""
    v_start, v_dir, v_power = vs.start, vs.dir, vs.power
    sig_a, sig_s = med.sigma_a, med.sigma_s
    ln = vs.len[i]
    s = min(sig_a[0] + sig_s[0], min(sig_a[1] + sig_s[1], sig_a[2] + sig_s[2]))
    frac = -math.expm1(-s * ln)
    t, pdf = stratified_depth(0, 1, u, s, ln, frac)
    pw = np.empty(3)
    for c in range(3):
        pw[c] = v_power[i, c] * sig_s[c] * math.exp(-(sig_a[c] + sig_s[c]) * t) / pdf
    src = Source(v_start[i, 0] + t * v_dir[i, 0], v_start[i, 1] + t * v_dir[i, 1], v_start[i, 2] + t * v_dir[i, 2],
                 v_dir[i, 0], v_dir[i, 1], v_dir[i, 2], pw[0], pw[1], pw[2], vs.rb[i])
    source_terms(src, vs.plane[i], med, q, rclamp, as_runtime(False), as_runtime(True), vs.tables, split, out_d,
                 out_m)


@njit(cache=True)
def split_terms(i, n, vs, med, q, rclamp, do_double, do_multiple, split, out_d, out_m):
    """Volume sample i as n point sources at the midpoints of equal sub-segments, each with its exact share of the
    power scattered, sigma_s/sigma_t (e^-st t0 - e^-st t1) times the power entering the segment."""
    v_start, v_dir, v_power = vs.start, vs.dir, vs.power
    sig_a, sig_s = med.sigma_a, med.sigma_s
    ln = vs.len[i]
    pw = np.empty(3)
    for k in range(n):
        t0, t1 = ln * k / n, ln * (k + 1) / n
        for c in range(3):
            st = sig_a[c] + sig_s[c]
            pw[c] = v_power[i, c] * (sig_s[c] / st * (math.exp(-st * t0) - math.exp(-st * t1)) if st > 0.0 else 0.0)
        tm = 0.5 * (t0 + t1)
        sub = Source(v_start[i, 0] + tm * v_dir[i, 0], v_start[i, 1] + tm * v_dir[i, 1],
                     v_start[i, 2] + tm * v_dir[i, 2], v_dir[i, 0], v_dir[i, 1], v_dir[i, 2], pw[0], pw[1], pw[2],
                     max(0.5 * (t1 - t0), vs.rb[i]))
        source_terms(sub, vs.plane[i], med, q, rclamp, do_double, do_multiple, vs.tables, split, out_d, out_m)
