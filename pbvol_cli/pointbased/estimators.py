"""In-scattered radiance per unit length at a camera point P toward the camera (Wang et al. 2016, eqs. 4-6).

All three are S(P, w_c) in W m^-3 sr^-1, per RGB channel, for the medium holding P; w_c is the propagation direction
toward the camera. Volume sample v: segment start s_v, direction d_v, length l_v, beam power Phi_v at its start,
cross-section A_v (kernel 1/A_v), scattered power Phi_v^s = Phi_v sigma_s/sigma_t (1 - exp(-sigma_t l_v)).
- single:   sigma_s p(d_v . w_c) Phi_v exp(-sigma_t t) / A_v, for the beams whose cross-section holds P
            (t = (P - s_v) . d_v in [0, l_v], continued at the boundary; the attenuation over P's own path from the
            leg's entry plane): the photon-beam estimate the paper's box average approximates.
- double:   sigma_s p(m . w_c) Phi^s p(d . m) <exp(-sigma_t r)/r^2>, m = (P - x)/r, where <> averages over a ball of
            the source's extent (attenuated_inv_r2_ball) rather than clamping 1/r^2; segments near P are split.
- multiple: Phi^s sigma_t^3 [S_table(sigma_t (P - x), w_c) in the frame of (x, d) minus the same for the mirror
            image of (x, d) in the boundary plane nearest the source]: the table's medium is infinite, and light
            that crosses the boundary there scatters back (index-matched furnace: 2.02 without the image, 0.98
            with it); what a dielectric boundary reflects is the bounced term (bounced.py).
Double and multiple sum over all volume samples by a stochastic light cut (double_multiple): a few nodes of the
octree, each represented by one sample drawn at random and weighted by its inverse probability, so the sum is
unbiased whatever the cut; the cut only sets the noise. Double scattering's near field (near_weight: within a few
beam radii of P) is summed over every sample there instead (_near_field): it ruled the cut's noise.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pbvol_cli.multiple_scattering.table import scaled_lookup
from pbvol_cli.physics.phase import phase_eval
from pbvol_cli.physics.sampling import rand

INV_4PI = 1.0 / (4.0 * math.pi)


END_EXTENSION = 3.0  # kernel radii by which segments on the boundary are continued (single scattering)


PLANE_PATH_MIN_COS = 0.1  # single scattering: legs closer than this to grazing their entry plane use the axis

LEAF_WALK_STACK = 128  # depth-first stack of the octree walks (8 children a level: ample)


@njit(inline="always", cache=True)
def next_leaf(tree, stack, sp, px, py, pz, margin):
    """The octree walk shared by single scattering and double's near field: pops the stack (its size in sp[0],
    start with the root on it) until a leaf whose box, widened by margin, holds P, and returns it; -1 when done."""
    lo, hi, first_child, n_children = tree[1], tree[2], tree[6], tree[7]
    while sp[0] > 0:
        sp[0] -= 1
        nd = stack[sp[0]]
        if (px < lo[nd, 0] - margin or px > hi[nd, 0] + margin or py < lo[nd, 1] - margin
                or py > hi[nd, 1] + margin or pz < lo[nd, 2] - margin or pz > hi[nd, 2] + margin):
            continue
        if first_child[nd] < 0:
            return nd
        for ch in range(first_child[nd], first_child[nd] + n_children[nd]):
            if sp[0] < stack.shape[0]:
                stack[sp[0]] = ch
                sp[0] += 1
    return -1


@njit(cache=True)
def single_scattering(tree, v_start, v_dir, v_len, v_power, v_area, v_ends, v_plane, sig_a, sig_s, kind, g, px, py,
                      pz, wx, wy, wz, out):
    """Beam x point: every beam whose kernel disc (area v_area, perpendicular to the beam) holds P. A segment
    starting (ending) on the boundary is continued backward (forward) by END_EXTENSION kernel radii: a point near
    the boundary otherwise misses the neighbouring beams whose discs reach it before they enter (after they
    leave), an 11% deficit in dense media (wax, 8 mean free paths across); continued, the kernel average is
    exact for a flat boundary, and the camera points are inside the medium anyway."""
    order, start, end = tree[0], tree[8], tree[9]
    stack = np.empty(LEAF_WALK_STACK, np.int64)
    sp = np.ones(1, np.int64)
    stack[0] = 0
    while True:
        nd = next_leaf(tree, stack, sp, px, py, pz, 0.0)
        if nd < 0:
            break
        for k in range(start[nd], end[nd]):
            i = order[k]
            qx, qy, qz = px - v_start[i, 0], py - v_start[i, 1], pz - v_start[i, 2]
            t = qx * v_dir[i, 0] + qy * v_dir[i, 1] + qz * v_dir[i, 2]
            ext = END_EXTENSION * math.sqrt(v_area[i] / math.pi)
            if t < (-ext if v_ends[i] & 1 else 0.0) or t >= v_len[i] + (ext if v_ends[i] & 2 else 0.0):
                continue
            rx, ry, rz = qx - t * v_dir[i, 0], qy - t * v_dir[i, 1], qz - t * v_dir[i, 2]
            if (rx * rx + ry * ry + rz * rz) * math.pi > v_area[i]:
                continue
            ph = phase_eval(kind, g, v_dir[i, 0] * wx + v_dir[i, 1] * wy + v_dir[i, 2] * wz) / v_area[i]
            # the attenuation over P's own path from the leg's entry plane (its depth below it / cos theta), not
            # along the beam's axis: across a kernel disc of radius r the beams' paths differ by up to
            # r tan(theta), and the disc's average of their exponentials exceeds the value at P by 2 I_1(x) / x,
            # x = sigma_t r tan(theta) (wax slab lit at 60 degrees: single 1.12-1.15 of volpath's order 1, 1.006
            # now). Grazing legs keep the axis: there the tangent plane's depth is a poor guide a little aside.
            cn = -(v_plane[i, 0] * v_dir[i, 0] + v_plane[i, 1] * v_dir[i, 1] + v_plane[i, 2] * v_dir[i, 2])
            tt = t
            if cn > PLANE_PATH_MIN_COS:
                tt = (v_plane[i, 0] * (v_start[i, 0] - px) + v_plane[i, 1] * (v_start[i, 1] - py)
                      + v_plane[i, 2] * (v_start[i, 2] - pz)) / cn
            for c in range(3):
                out[c] += sig_s[c] * ph * v_power[i, c] * math.exp(-(sig_a[c] + sig_s[c]) * tt)


@njit(inline="always", cache=True)
def inv_r2_ball(r, c):
    """Mean of 1/|P - x|^2 over x uniform in a ball of radius c, |P| = r: the 1/r^2 of a source smeared over its
    extent instead of a hard clamp (3/c^2 at the centre, continuous, -> 1/r^2 far away):
    3/(2 r c^3) [r c + (c^2 - r^2)/2 ln((c + r)/|c - r|)]."""
    if c <= 0.0 or r > 4.0 * c:
        return 1.0 / (r * r) if r > 0.0 else np.inf
    if r < 1e-6 * c:
        return 3.0 / (c * c)
    if abs(r - c) < 1e-9 * c:
        return 1.5 / (c * c)
    return 1.5 / (r * c ** 3) * (r * c + 0.5 * (c * c - r * r) * math.log((c + r) / abs(c - r)))


_GL_X = np.array([-0.9324695142031521, -0.6612093864662645, -0.2386191860831969, 0.2386191860831969,
                  0.6612093864662645, 0.9324695142031521])
_GL_W = np.array([0.1713244923791704, 0.3607615730481386, 0.4679139345726910, 0.4679139345726910,
                  0.3607615730481386, 0.1713244923791704])


@njit(inline="always", cache=True)
def _expint_e1(x):
    """E1(x) = int_x^inf e^-t / t dt, x > 0 (Abramowitz & Stegun 5.1.53 and 5.1.56: error < 2e-7)."""
    if x <= 1.0:
        return (-math.log(x) - 0.57721566 + x * (0.99999193 + x * (-0.24991055 + x * (0.05519968 + x * (
            -0.00976004 + x * 0.00107857)))))
    num = x * (x * (x * (x + 8.5733287401) + 18.0590169730) + 8.6347608925) + 0.2677737343
    den = x * (x * (x * (x + 9.5733223454) + 25.6329561486) + 21.0996530827) + 3.9584969228
    return num / den * math.exp(-x) / x


@njit(inline="always", cache=True)
def _exp_over_r(a, b, s):
    """int_a^b e^(-s t) / t dt, 0 < a < b, s >= 0: Gauss-Legendre where the interval is narrow (the difference of
    E1's would cancel), E1's otherwise."""
    if b < 4.0 * a:
        h, m = 0.5 * (b - a), 0.5 * (b + a)
        acc = 0.0
        for k in range(6):
            t = m + h * _GL_X[k]
            acc += _GL_W[k] * math.exp(-s * t) / t
        return h * acc
    if s * b < 1e-6:
        return math.log(b / a) - s * (b - a)
    return _expint_e1(s * a) - _expint_e1(s * b)


@njit(cache=True)
def attenuated_inv_r2_ball(r, c, s):
    """Mean of e^(-s |P - x|) / |P - x|^2 over x uniform in a ball of radius c, |P| = r (s: extinction, 1/length):
    a point source's attenuated 1/r^2 smeared over the source's extent. Unlike e^(-s r) inv_r2_ball(r, c), it
    keeps the kernel's integral over space (4 pi / s): smoothing 1/r^2 alone moves the near field's weight to
    where the attenuation at the centre distance is stronger, and lost 13% of double scattering in wax when the
    beams are 0.35 mean free paths wide. Spherical shells about P: the shell of radius t holds 4 pi t^2 of ball
    for t < c - r, pi t (c^2 - (t - r)^2) / r for |c - r| < t < c + r."""
    if c <= 0.0 or r > 4.0 * c:
        return math.exp(-s * r) / (r * r) if r > 0.0 else np.inf
    if s * (r + c) < 1e-7:
        return inv_r2_ball(r, c)
    if r < 1e-4 * c:  # P at the centre: 4 pi int_0^c e^-st dt
        return 3.0 / (c ** 3) * (-math.expm1(-s * c)) / s
    inner = 4.0 * math.pi * (-math.expm1(-s * (c - r))) / s if r < c else 0.0
    a, b = abs(c - r), c + r
    if r > c and s * a > 2.0:
        # outside the ball and many mean free paths from it the closed form below cancels: with t = a + u,
        # c^2 - (t - r)^2 = u (2c - u), integrated over the part of [0, 2c] where e^-su matters (two panels)
        top = min(2.0 * c, 16.0 / s)
        acc = 0.0
        for lo_, hi_ in ((0.0, 0.25 * top), (0.25 * top, top)):
            h, m = 0.5 * (hi_ - lo_), 0.5 * (hi_ + lo_)
            for k in range(6):
                u = m + h * _GL_X[k]
                acc += h * _GL_W[k] * u * (2.0 * c - u) / (a + u) * math.exp(-s * u)
        shell = math.pi / r * math.exp(-s * a) * acc
        return 3.0 / (4.0 * math.pi * c ** 3) * shell
    ea, eb = math.exp(-s * a), math.exp(-s * b)
    # (pi / r) int_a^b [(c^2 - r^2)/t - t + 2 r] e^-st dt
    lin = (a / s + 1.0 / (s * s)) * ea - (b / s + 1.0 / (s * s)) * eb
    const = (ea - eb) / s
    cap = (c * c - r * r) * _exp_over_r(a, b, s) if a > 0.0 else 0.0
    shell = math.pi / r * (cap - lin + 2.0 * r * const)
    return 3.0 / (4.0 * math.pi * c ** 3) * (inner + shell)


@njit(inline="always", cache=True)
def near_weight(r, split):
    """The share of double scattering's kernel at distance r that a pass takes: split = 0, all of it; split = R > 0,
    the near field's, 1 within R/2 falling linearly to 0 at R (summed over every source there: double_multiple's
    near pass); split = -R, the rest (by the stochastic cut). The two parts sum to 1 at every r."""
    if split == 0.0:
        return 1.0
    R = abs(split)
    s = 1.0 if r <= 0.5 * R else (2.0 * (1.0 - r / R) if r < R else 0.0)
    return s if split > 0.0 else 1.0 - s


@njit(cache=True)
def _source(x, y, z, dx, dy, dz, Pr, Pg, Pb, px, py, pz, wx, wy, wz, sig_a, sig_s, kind, g, rclamp, extent,
            do_double, do_multiple, tabs, out_d, out_m, nx, ny, nz, q, mx, my, mz, q2, split, pplane):
    """Double and multiple scattering at P from a point source of scattered power (Pr, Pg, Pb) along d, smeared over
    a ball of radius `extent` (the beam's radius or half its length) for double scattering; (n, q), (m, q2): the
    boundary's tangent planes n . x = q where the source's beam entered and left (normals outward), the nearer
    of which is the source's boundary plane (q = inf: none), for the multiple term's image. The ball
    shrinks to the source's depth below that plane, down to half its radius (a ball poking out of the medium puts
    part of the source's light where no camera point gathers it: 7% of wax's double scattering under beams 0.35
    mean free paths wide; shrunk further, to rclamp, the bounced layer's gather on the boundary itself met 100x
    spikes), and is at least rclamp wide. split: which part of double scattering (near_weight). pplane: P's
    boundary plane (n_x, n_y, n_z, q; q = inf: none), for the multiple term's second image."""
    # the plane nearer this point (not the segment's centre: a segment long in mean free paths, the last of a
    # beam, spans from near its entry to its exit, and its points near the entry mirrored in the exit plane
    # kept nearly all of the table's light: a non-absorbing index-matched slab under a white sky, 2.32 for 1,
    # 2.09 with this and 0.93 with the table's window too, multiple_scattering.table.domain_taper)
    if q2 - (mx * x + my * y + mz * z) < q - (nx * x + ny * y + nz * z):
        nx, ny, nz, q = mx, my, mz, q2
    align = 1.0
    rx, ry, rz = px - x, py - y, pz - z
    r2 = rx * rx + ry * ry + rz * rz
    r = math.sqrt(r2)
    part = near_weight(r, split) if do_double else 0.0
    if part > 0.0 and r > 0.0:
        c = max(rclamp, extent)
        if q < np.inf:
            c = max(rclamp, min(extent, max(q - (nx * x + ny * y + nz * z), 0.5 * extent)))
        mx, my, mz = rx / r, ry / r, rz / r
        lobe = align * phase_eval(kind, g, dx * mx + dy * my + dz * mz) + (1.0 - align) * INV_4PI
        f = phase_eval(kind, g, mx * wx + my * wy + mz * wz) * lobe * part
        out_d[0] += sig_s[0] * Pr * f * attenuated_inv_r2_ball(r, c, sig_a[0] + sig_s[0])
        out_d[1] += sig_s[1] * Pg * f * attenuated_inv_r2_ball(r, c, sig_a[1] + sig_s[1])
        out_d[2] += sig_s[2] * Pb * f * attenuated_inv_r2_ball(r, c, sig_a[2] + sig_s[2])
    if do_multiple:
        # the table's infinite medium, corrected for the boundary by the method of images twice: a mirror image
        # of the source (mirrored lobe) behind the source's boundary plane and another behind P's (pplane: the
        # camera segment's nearer end plane), each plane moved out by IMAGE_EXTRAPOLATION transport mean free
        # paths. Each image gives a factor f = 1 - image / table in [0, 1] (the half-space's response is never
        # negative); P's factor enters as f_P^w, w = (1 - n . n_P) / 2: where both points are under the same
        # plane it is the same image, counted once, while a source under the far side of a body (n_P = -n) gets
        # both. Index-matched sphere 7.7 mean free paths in radius under a directional light, multiple / 3+,
        # source's image alone -> both: lit from the camera's side 0.76 -> 0.98, from behind 3.9 -> 1.27
        image = q < np.inf
        image_p = pplane[3] < np.inf
        dn = 2.0 * (dx * nx + dy * ny + dz * nz)
        ex, ey, ez = dx - dn * nx, dy - dn * ny, dz - dn * nz
        ax, ay, az = pplane[0], pplane[1], pplane[2]
        dp = 2.0 * (dx * ax + dy * ay + dz * az)
        fx, fy, fz = dx - dp * ax, dy - dp * ay, dz - dp * az
        wp = 0.5 * (1.0 - (nx * ax + ny * ay + nz * az)) if image else 1.0
        for c in range(3):
            Pc = Pr if c == 0 else (Pg if c == 1 else Pb)
            st = sig_a[c] + sig_s[c]
            v0 = scaled_lookup(tabs[c], Pc, st, rx, ry, rz, dx, dy, dz, wx, wy, wz)
            if v0 <= 0.0:
                continue
            v = v0
            zb = IMAGE_EXTRAPOLATION / max(sig_a[c] + transport_share(kind, g) * sig_s[c], 1e-30)
            if image:
                h = 2.0 * (max(q - (nx * x + ny * y + nz * z), 0.0) + zb)
                vi = scaled_lookup(tabs[c], Pc, st, rx - h * nx, ry - h * ny, rz - h * nz, ex, ey, ez, wx, wy, wz)
                v *= min(max(1.0 - vi / v0, 0.0), 1.0)
            if image_p and wp > 0.0 and v > 0.0:
                h = 2.0 * (max(pplane[3] - (ax * x + ay * y + az * z), 0.0) + zb)
                vi = scaled_lookup(tabs[c], Pc, st, rx - h * ax, ry - h * ay, rz - h * az, fx, fy, fz, wx, wy, wz)
                v *= min(max(1.0 - vi / v0, 0.0), 1.0) ** wp
            out_m[c] += v


IMAGE_EXTRAPOLATION = 0.25  # transport mean free paths by which the image planes lie beyond the boundary
NO_PLANE = np.array([0.0, 0.0, 1.0, np.inf])  # pplane where a camera segment has no boundary plane


@njit(inline="always", cache=True)
def transport_share(kind, g):
    """1 - mean cosine of the phase function: sigma_t' = sigma_a + this x sigma_s (Henyey-Greenstein and Schlick:
    g; the others are treated as symmetric)."""
    return 1.0 - g if kind == 1 or kind == 2 else 1.0


NEAR_SUB = 8  # sub-points along a segment that is close to P (double scattering)
MS_CELL = 0.1  # mean free paths: segments longer than this are split for the multiple-scattering look-up


@njit(cache=True)
def _segment_source(i, v_start, v_dir, v_len, v_power, v_centre, v_scat, v_rb, v_plane, sig_a, sig_s, kind, g, px,
                    py, pz,
                    wx, wy, wz, rclamp, do_double, do_multiple, tabs, out_d, out_m, split, pplane):
    """A volume sample as a source (split: near_weight's). Double scattering: one point far from P; near P (closer than two segment
    lengths) NEAR_SUB points along the segment, each with its exact share sigma_s/sigma_t (e^-st t0 - e^-st t1) of
    the power, so that 1/r^2 needs clamping only at the beam radius. Multiple scattering: the table is smooth on
    the scale of its cells, so one look-up per MS_CELL mean free paths of segment."""
    cx, cy, cz = px - v_centre[i, 0], py - v_centre[i, 1], pz - v_centre[i, 2]
    ln = v_len[i]
    far = cx * cx + cy * cy + cz * cz > 4.0 * ln * ln
    st_max = max(sig_a[0] + sig_s[0], max(sig_a[1] + sig_s[1], sig_a[2] + sig_s[2]))
    n_ms = min(NEAR_SUB, int(math.ceil(st_max * ln / MS_CELL))) if do_multiple else 0
    if far or not do_double:
        dd = do_double and far  # (an expression among so many arguments trips numba's bytecode analysis)
        if n_ms <= 1:
            _source(v_centre[i, 0], v_centre[i, 1], v_centre[i, 2], v_dir[i, 0], v_dir[i, 1], v_dir[i, 2],
                    v_scat[i, 0], v_scat[i, 1], v_scat[i, 2], px, py, pz, wx, wy, wz, sig_a, sig_s, kind, g,
                    rclamp, max(0.5 * ln, v_rb[i]), dd, do_multiple, tabs, out_d, out_m,
                    v_plane[i, 0],
                    v_plane[i, 1], v_plane[i, 2], v_plane[i, 3], v_plane[i, 4], v_plane[i, 5],
                    v_plane[i, 6], v_plane[i, 7], split, pplane)
            return
        if far and do_double:
            _source(v_centre[i, 0], v_centre[i, 1], v_centre[i, 2], v_dir[i, 0], v_dir[i, 1], v_dir[i, 2],
                    v_scat[i, 0], v_scat[i, 1], v_scat[i, 2], px, py, pz, wx, wy, wz, sig_a, sig_s, kind, g,
                    rclamp, max(0.5 * ln, v_rb[i]), True, False, tabs, out_d, out_m, v_plane[i, 0],
                    v_plane[i, 1], v_plane[i, 2], v_plane[i, 3], v_plane[i, 4], v_plane[i, 5],
                    v_plane[i, 6], v_plane[i, 7], split, pplane)
        _split_source(i, n_ms, v_start, v_dir, v_len, v_power, v_rb, v_plane, sig_a, sig_s, kind, g, px, py, pz, wx,
                      wy, wz,
                      rclamp, False, True, tabs, out_d, out_m, split, pplane)
        return
    # near, double wanted
    if n_ms == NEAR_SUB:
        _split_source(i, NEAR_SUB, v_start, v_dir, v_len, v_power, v_rb, v_plane, sig_a, sig_s, kind, g, px, py, pz,
                      wx, wy,
                      wz, rclamp, True, do_multiple, tabs, out_d, out_m, split, pplane)
        return
    _split_source(i, NEAR_SUB, v_start, v_dir, v_len, v_power, v_rb, v_plane, sig_a, sig_s, kind, g, px, py, pz, wx,
                  wy, wz,
                  rclamp, True, False, tabs, out_d, out_m, split, pplane)
    if n_ms > 0:
        _split_source(i, n_ms, v_start, v_dir, v_len, v_power, v_rb, v_plane, sig_a, sig_s, kind, g, px, py, pz, wx,
                      wy, wz,
                      rclamp, False, True, tabs, out_d, out_m, split, pplane)


@njit(cache=True)
def _split_source(i, n, v_start, v_dir, v_len, v_power, v_rb, v_plane, sig_a, sig_s, kind, g, px, py, pz, wx, wy,
                  wz, rclamp,
                  do_double, do_multiple, tabs, out_d, out_m, split, pplane):
    """Segment i as n point sources at the midpoints of equal sub-segments, each with its exact share of the power
    scattered, sigma_s/sigma_t (e^-st t0 - e^-st t1) times the power entering the segment."""
    ln = v_len[i]
    pw = np.empty(3)
    for q in range(n):
        t0, t1 = ln * q / n, ln * (q + 1) / n
        for c in range(3):
            st = sig_a[c] + sig_s[c]
            pw[c] = v_power[i, c] * (sig_s[c] / st * (math.exp(-st * t0) - math.exp(-st * t1)) if st > 0.0 else 0.0)
        tm = 0.5 * (t0 + t1)
        _source(v_start[i, 0] + tm * v_dir[i, 0], v_start[i, 1] + tm * v_dir[i, 1], v_start[i, 2] + tm * v_dir[i, 2],
                v_dir[i, 0], v_dir[i, 1], v_dir[i, 2], pw[0], pw[1], pw[2], px, py, pz, wx, wy, wz, sig_a, sig_s,
                kind, g, rclamp, max(0.5 * (t1 - t0), v_rb[i]), do_double, do_multiple, tabs, out_d, out_m,
                v_plane[i, 0],
                    v_plane[i, 1], v_plane[i, 2], v_plane[i, 3], v_plane[i, 4], v_plane[i, 5],
                    v_plane[i, 6], v_plane[i, 7], split, pplane)


CUT_CAP = 4096  # nodes a cut may hold at once (a node that would overflow it is used as it is)


@njit(inline="always", cache=True)
def _node_priority(nd, lo, hi, power, px, py, pz, st_min):
    """How much using node nd through one random representative may cost in variance: its power x the solid
    angle its box subtends from P (R^2 / d_min^2, d_min the distance to the box, at least R/10, so that boxes
    holding P come first) x the transmittance over d_min."""
    hx, hy, hz = 0.5 * (hi[nd, 0] - lo[nd, 0]), 0.5 * (hi[nd, 1] - lo[nd, 1]), 0.5 * (hi[nd, 2] - lo[nd, 2])
    R2 = hx * hx + hy * hy + hz * hz
    vx = px - 0.5 * (lo[nd, 0] + hi[nd, 0])
    vy = py - 0.5 * (lo[nd, 1] + hi[nd, 1])
    vz = pz - 0.5 * (lo[nd, 2] + hi[nd, 2])
    ex, ey, ez = max(0.0, abs(vx) - hx), max(0.0, abs(vy) - hy), max(0.0, abs(vz) - hz)
    dmin2 = max(ex * ex + ey * ey + ez * ez, 0.01 * R2, 1e-30)
    return (power[nd, 0] + power[nd, 1] + power[nd, 2]) * R2 / dmin2 * math.exp(-st_min * math.sqrt(dmin2))


@njit(inline="always", cache=True)
def _heap_push(heap, n, key, e):
    heap[n] = e
    k = n
    while k > 0:
        p = (k - 1) >> 1
        if key[heap[p]] >= key[heap[k]]:
            break
        heap[p], heap[k] = heap[k], heap[p]
        k = p
    return n + 1


@njit(inline="always", cache=True)
def _heap_pop(heap, n, key):
    """Removes the top (largest key); returns the new size."""
    n -= 1
    heap[0] = heap[n]
    k = 0
    while True:
        a, b = 2 * k + 1, 2 * k + 2
        m = k
        if a < n and key[heap[a]] > key[heap[m]]:
            m = a
        if b < n and key[heap[b]] > key[heap[m]]:
            m = b
        if m == k:
            break
        heap[m], heap[k] = heap[k], heap[m]
        k = m
    return n


@njit(inline="always", cache=True)
def _importance(x, y, z, dx, dy, dz, align, power, ext2, px, py, pz, wx, wy, wz, kind, g, st_min):
    """How much a source (a node: centroid, mean direction with alignment, power summed over RGB, squared extent)
    may give double scattering at P toward w: power x lobe toward P x phase toward the camera x e^-sigma r / r^2,
    r^2 at least the extent. Positive for every phase function here (none vanishes)."""
    rx, ry, rz = px - x, py - y, pz - z
    r2 = rx * rx + ry * ry + rz * rz
    r = math.sqrt(r2)
    if r > 0.0:
        mx, my, mz = rx / r, ry / r, rz / r
    else:
        mx, my, mz = wx, wy, wz
    lobe = align * phase_eval(kind, g, dx * mx + dy * my + dz * mz) + (1.0 - align) * INV_4PI
    return power * lobe * phase_eval(kind, g, mx * wx + my * wy + mz * wz) * math.exp(-st_min * r) / max(r2, ext2)


@njit(cache=True)
def _representative_importance(nd, tree, v_dir, v_len, v_centre, v_scat, v_rb, v_plane, px, py, pz, wx, wy, wz, kind, g,
                               st_min, ext_min2, u):
    """A sample of node nd drawn by descending with probabilities half proportional to each child's _importance
    and half to its power, then likewise among the leaf's samples (a light tree, after Conty Estevez and Kulla
    2018, with a defensive mixture): sources whose lobes point at P and whose P-side phase points at the camera
    are found far more often than by power alone (g = 0.9: lobes 200x their mean), and no sample's weight exceeds
    twice its power-proportional one (importance alone, misjudged near P, made fireflies). Returns (sample,
    1 / its probability)."""
    order, lo, hi, centre, dirsum, power = tree[0], tree[1], tree[2], tree[3], tree[4], tree[5]
    first_child, n_children, start, end = tree[6], tree[7], tree[8], tree[9]
    imp = np.empty(8)
    pws = np.empty(8)
    prob = 1.0
    while first_child[nd] >= 0:
        f0, nc = first_child[nd], n_children[nd]
        total = 0.0
        ptotal = 0.0
        for k in range(nc):
            ch = f0 + k
            pw = power[ch, 0] + power[ch, 1] + power[ch, 2]
            pws[k] = max(pw, 0.0)
            ptotal += pws[k]
            imp[k] = 0.0
            if pw <= 0.0:
                continue
            sx, sy, sz = dirsum[ch, 0], dirsum[ch, 1], dirsum[ch, 2]
            sn = math.sqrt(sx * sx + sy * sy + sz * sz)
            if sn > 0.0:
                dx, dy, dz, a = sx / sn, sy / sn, sz / sn, min(1.0, sn / pw)
            else:
                dx, dy, dz, a = 0.0, 0.0, 1.0, 0.0
            hx, hy, hz = hi[ch, 0] - lo[ch, 0], hi[ch, 1] - lo[ch, 1], hi[ch, 2] - lo[ch, 2]
            imp[k] = _importance(centre[ch, 0], centre[ch, 1], centre[ch, 2], dx, dy, dz, a, pw,
                                 0.25 * (hx * hx + hy * hy + hz * hz), px, py, pz, wx, wy, wz, kind, g, st_min)
            total += imp[k]
        if not ptotal > 0.0:
            return -1, 0.0
        for k in range(nc):  # the mixture, in place
            imp[k] = 0.5 * pws[k] / ptotal + (0.5 * imp[k] / total if total > 0.0 else 0.5 * pws[k] / ptotal)
        acc = 0.0
        pick = -1
        for k in range(nc):
            if imp[k] > 0.0:
                pick = k
                if u < acc + imp[k]:
                    break
            acc += imp[k]
        acc = 0.0
        for k in range(pick):
            acc += imp[k]
        u = min(max((u - acc) / imp[pick], 0.0), 1.0 - 1e-16)
        prob *= imp[pick]
        nd = f0 + pick
    total = 0.0
    ptotal = 0.0
    for k in range(start[nd], end[nd]):
        i = order[k]
        pw = v_scat[i, 0] + v_scat[i, 1] + v_scat[i, 2]
        ptotal += pw
        total += _importance(v_centre[i, 0], v_centre[i, 1], v_centre[i, 2], v_dir[i, 0], v_dir[i, 1], v_dir[i, 2],
                             1.0, pw, max(v_rb[i] ** 2, 0.25 * v_len[i] ** 2, ext_min2), px, py, pz, wx, wy, wz, kind, g, st_min)
    if not ptotal > 0.0:
        return -1, 0.0
    acc = 0.0
    last = -1
    last_w = 0.0
    for k in range(start[nd], end[nd]):
        i = order[k]
        pw = v_scat[i, 0] + v_scat[i, 1] + v_scat[i, 2]
        w = 0.5 * pw / ptotal
        if total > 0.0:
            w += 0.5 * _importance(v_centre[i, 0], v_centre[i, 1], v_centre[i, 2], v_dir[i, 0], v_dir[i, 1],
                                   v_dir[i, 2], 1.0, pw, max(v_rb[i] ** 2, 0.25 * v_len[i] ** 2, ext_min2), px, py, pz, wx, wy,
                                   wz, kind, g, st_min) / total
        else:
            w += 0.5 * pw / ptotal
        if w > 0.0:
            last, last_w = i, w
            if u < acc + w:
                return i, 1.0 / (prob * w)
        acc += w
    if last < 0:
        return -1, 0.0
    return last, 1.0 / (prob * last_w)


@njit(cache=True)
def _cut_estimate(heap, hn, node_of, tree, v_start, v_dir, v_len, v_power, v_centre, v_scat, v_rb, v_plane, sig_a,
                  sig_s, kind,
                  g, px, py, pz, wx, wy, wz, rclamp, do_double, do_multiple, tabs, out_d, out_m, rng, ri, split, pplane):
    """Each node of the cut contributes one representative sample, weighted by 1 / its probability (unbiased for
    the node's sum): drawn by importance toward P, by double scattering's kernel for either term (split:
    near_weight's; a far part needs no importance closer than half its radius).
    Returns the samples evaluated."""
    power = tree[5]
    st_min = min(sig_a[0] + sig_s[0], min(sig_a[1] + sig_s[1], sig_a[2] + sig_s[2]))
    od = np.zeros(3)
    om = np.zeros(3)
    n = 0
    for h in range(hn):
        nd = node_of[heap[h]]
        if power[nd, 0] + power[nd, 1] + power[nd, 2] <= 0.0:
            continue
        # importance toward P by double scattering's kernel, for the multiple term's cut too: drawn by power, the
        # rare sources near P came with a node's whole weight, and a thick furnace's multiple layer at 8 spp read
        # 0.94 with a median of 0.76 and a highest pixel of 2.3 (a 400-refinement cut: 0.79). Diffusion's fall-off
        # (1/r, 1/r^2) as the importance left a pixel-to-pixel spread of 17-22%, this kernel 9% (power: 17%)
        i, scale = _representative_importance(nd, tree, v_dir, v_len, v_centre, v_scat, v_rb, v_plane, px, py,
                                              pz, wx, wy, wz, kind, g, st_min, 0.25 * split * split,
                                              rand(rng, ri))
        if i < 0:
            continue
        for c in range(3):
            od[c] = 0.0
            om[c] = 0.0
        _segment_source(i, v_start, v_dir, v_len, v_power, v_centre, v_scat, v_rb, v_plane, sig_a, sig_s, kind, g,
                        px, py, pz,
                        wx, wy, wz, rclamp, do_double, do_multiple, tabs, od, om, split, pplane)
        n += 1
        for c in range(3):
            out_d[c] += scale * od[c]
            out_m[c] += scale * om[c]
    return n


@njit(cache=True)
def _near_field(tree, v_start, v_dir, v_len, v_power, v_centre, v_scat, v_rb, v_plane, sig_a, sig_s, kind, g, px, py,
                pz, wx, wy, wz, rclamp, r_near, tabs, out_d, out_m, pplane):
    """Double scattering's near part (near_weight with split = r_near) from every sample whose segment passes
    within r_near of P: the octree's boxes widened by r_near, walked like single scattering's. Returns the
    samples evaluated."""
    order, start, end = tree[0], tree[8], tree[9]
    stack = np.empty(LEAF_WALK_STACK, np.int64)
    sp = np.ones(1, np.int64)
    stack[0] = 0
    n = 0
    R = r_near
    while True:
        nd = next_leaf(tree, stack, sp, px, py, pz, R)
        if nd < 0:
            break
        for k in range(start[nd], end[nd]):
            i = order[k]
            qx, qy, qz = px - v_start[i, 0], py - v_start[i, 1], pz - v_start[i, 2]
            t = min(max(qx * v_dir[i, 0] + qy * v_dir[i, 1] + qz * v_dir[i, 2], 0.0), v_len[i])
            rx, ry, rz = qx - t * v_dir[i, 0], qy - t * v_dir[i, 1], qz - t * v_dir[i, 2]
            if rx * rx + ry * ry + rz * rz >= R * R:
                continue
            n += 1
            _segment_source(i, v_start, v_dir, v_len, v_power, v_centre, v_scat, v_rb, v_plane, sig_a, sig_s, kind,
                            g, px, py, pz, wx, wy, wz, rclamp, True, False, tabs, out_d, out_m, r_near, pplane)
    return n


MULTIPLE_CUT_SHARE = 4  # multiple scattering (smooth) uses the cut after cut_size / 4 refinements


@njit(cache=True)
def double_multiple(tree, v_start, v_dir, v_len, v_power, v_centre, v_scat, v_rb, v_plane, sig_a, sig_s, kind, g,
                    px, py, pz, wx, wy, wz, cut_size, rclamp, r_near, do_double, do_multiple, tabs, out_d, out_m, rng,
                    ri, pplane):
    """Double and multiple scattering at P by a stochastic light cut (after Yuksel 2019, "Stochastic Lightcuts"):
    the cut is made by refining cut_size times the node of highest priority (power x solid angle x transmittance:
    boxes near or around P first; a leaf refined is summed sample by sample); each node of the cut then
    contributes one representative sample (_cut_estimate). Every sample's term is the exact per-sample estimator
    (_segment_source), so the estimate is unbiased for any cut: a node's phase lobes and 1/r^2 are never averaged
    (with g = 0.9 lobes and 1/r^2, centroid approximations were 10-25% low). Multiple scattering, smooth and
    costly to look up, takes the cut as it stands after cut_size / MULTIPLE_CUT_SHARE refinements.
    With r_near > 0 double scattering's kernel is split (near_weight): its part within r_near of P is summed over
    every sample there (_near_field), the cut takes the rest. The near field ruled the cut's noise: sources a few
    tenths of a mean free path from P, inside nodes the cut had not opened, were drawn rarely and weighted
    heavily (one estimate's relative standard deviation 1.4-4.7 in milk, medians a third of the mean).
    rng[ri] is the random state. Returns the number of samples evaluated (the cost)."""
    order, lo, hi, power = tree[0], tree[1], tree[2], tree[5]
    first_child, n_children, start, end = tree[6], tree[7], tree[8], tree[9]
    if first_child.shape[0] == 0:
        return 0
    st_min = min(sig_a[0] + sig_s[0], min(sig_a[1] + sig_s[1], sig_a[2] + sig_s[2]))
    cap = min(CUT_CAP, 8 * cut_size + 64)
    node_of = np.empty(cap, np.int64)
    key = np.empty(cap)
    heap = np.empty(cap, np.int64)
    free = np.empty(cap, np.int64)
    node_of[0] = 0
    key[0] = 0.0
    hn = _heap_push(heap, 0, key, 0)
    n_slot, n_free, n_eval, n_refined = 1, 0, 0, 0
    ms_cut = cut_size // MULTIPLE_CUT_SHARE
    ms_pending = do_multiple
    split = -r_near if do_double and r_near > 0.0 else 0.0
    if split < 0.0:
        n_eval += _near_field(tree, v_start, v_dir, v_len, v_power, v_centre, v_scat, v_rb, v_plane, sig_a, sig_s,
                              kind, g, px, py, pz, wx, wy, wz, rclamp, r_near, tabs, out_d, out_m, pplane)
    while hn > 0:
        if ms_pending and n_refined >= ms_cut:
            n_eval += _cut_estimate(heap, hn, node_of, tree, v_start, v_dir, v_len, v_power, v_centre, v_scat, v_rb,
                                    v_plane,
                                    sig_a, sig_s, kind, g, px, py, pz, wx, wy, wz, rclamp, False, True, tabs,
                                    out_d, out_m, rng, ri, 0.0, pplane)
            ms_pending = False
        if n_refined >= cut_size or not (do_double or ms_pending):
            break
        e = heap[0]
        nd = node_of[e]
        if first_child[nd] >= 0 and hn - 1 + n_children[nd] > cap:
            break
        n_refined += 1
        hn = _heap_pop(heap, hn, key)
        free[n_free] = e
        n_free += 1
        if first_child[nd] < 0:  # a leaf: its samples exactly
            n_eval += end[nd] - start[nd]
            for k in range(start[nd], end[nd]):
                _segment_source(order[k], v_start, v_dir, v_len, v_power, v_centre, v_scat, v_rb, v_plane, sig_a,
                                sig_s, kind,
                                g, px, py, pz, wx, wy, wz, rclamp, do_double, ms_pending, tabs, out_d, out_m, split, pplane)
            continue
        for ch in range(first_child[nd], first_child[nd] + n_children[nd]):
            if n_free > 0:
                n_free -= 1
                e = free[n_free]
            else:
                e = n_slot
                n_slot += 1
            node_of[e] = ch
            key[e] = _node_priority(ch, lo, hi, power, px, py, pz, st_min)
            hn = _heap_push(heap, hn, key, e)
    n_eval += _cut_estimate(heap, hn, node_of, tree, v_start, v_dir, v_len, v_power, v_centre, v_scat, v_rb,
                            v_plane, sig_a,
                            sig_s, kind, g, px, py, pz, wx, wy, wz, rclamp, do_double, ms_pending, tabs, out_d, out_m,
                            rng, ri, split, pplane)
    return n_eval
