"""In-scattered radiance per unit length at a camera point P toward the camera (Wang et al. 2016, eqs. 4-6).

All three are S(P, w_c) in W m^-3 sr^-1, per RGB channel, for the medium holding P; w_c is the propagation direction
toward the camera. Volume sample v: segment start s_v, direction d_v, length l_v, beam power Phi_v at its start,
cross-section A_v (kernel 1/A_v), scattered power Phi_v^s = Phi_v sigma_s/sigma_t (1 - exp(-sigma_t l_v)).
- single:   sigma_s p(d_v . w_c) Phi_v exp(-sigma_t t) / A_v, for the beams whose cross-section holds P
            (t = (P - s_v) . d_v in [0, l_v]): the photon-beam estimate the paper's box average approximates.
- double:   sigma_s p(m . w_c) Phi^s p(d . m) exp(-sigma_t r) <1/r^2> over a tree cut, m = (P - x)/r, where <1/r^2>
            averages 1/r^2 over a ball of the source's extent (inv_r2_ball) rather than clamping it.
- multiple: Phi^s sigma_t^3 S_table(sigma_t (P - x), w_c) in the frame of (x, d), over the same cut.
The cut keeps a node when (solid angle of its box from P) x 4 pi p(m . w_c) < tau, and never a node whose box holds P.
A kept node's samples may point different ways (beams from an environment, internal reflections): with alignment
a = |sum of power-weighted directions| / total weight, their phase lobes are replaced by a p(d_mean . m) + (1 - a)/(4 pi),
normalised and with the mixture's first moment a g (exact when the beams are parallel); the table look-up for
multiple scattering uses the mean direction.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pbvol_cli.multiple_scattering.table import scaled_lookup
from pbvol_cli.physics.phase import phase_eval

INV_4PI = 1.0 / (4.0 * math.pi)


@njit(cache=True)
def single_scattering(tree, v_start, v_dir, v_len, v_power, v_area, sig_a, sig_s, kind, g, px, py, pz,
                      wx, wy, wz, out):
    order, lo, hi = tree[0], tree[1], tree[2]
    first_child, n_children, start, end = tree[6], tree[7], tree[8], tree[9]
    stack = np.empty(128, np.int64)
    sp = 1
    stack[0] = 0
    while sp > 0:
        sp -= 1
        nd = stack[sp]
        if (px < lo[nd, 0] or px > hi[nd, 0] or py < lo[nd, 1] or py > hi[nd, 1] or pz < lo[nd, 2]
                or pz > hi[nd, 2]):
            continue
        if first_child[nd] >= 0:
            for ch in range(first_child[nd], first_child[nd] + n_children[nd]):
                if sp < 128:
                    stack[sp] = ch
                    sp += 1
            continue
        for k in range(start[nd], end[nd]):
            i = order[k]
            qx, qy, qz = px - v_start[i, 0], py - v_start[i, 1], pz - v_start[i, 2]
            t = qx * v_dir[i, 0] + qy * v_dir[i, 1] + qz * v_dir[i, 2]
            if t < 0.0 or t >= v_len[i]:
                continue
            rx, ry, rz = qx - t * v_dir[i, 0], qy - t * v_dir[i, 1], qz - t * v_dir[i, 2]
            if (rx * rx + ry * ry + rz * rz) * math.pi > v_area[i]:
                continue
            ph = phase_eval(kind, g, v_dir[i, 0] * wx + v_dir[i, 1] * wy + v_dir[i, 2] * wz) / v_area[i]
            for c in range(3):
                out[c] += sig_s[c] * ph * v_power[i, c] * math.exp(-(sig_a[c] + sig_s[c]) * t)


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


@njit(cache=True)
def _source(x, y, z, dx, dy, dz, Pr, Pg, Pb, px, py, pz, wx, wy, wz, sig_a, sig_s, kind, g, rclamp,
            do_double, do_multiple, tabs, out_d, out_m, align=1.0):
    """Double and multiple scattering at P from a point source of scattered power (Pr, Pg, Pb) along d (mean
    direction of a node with alignment `align`: its lobe is blended toward isotropic, see the module doc)."""
    rx, ry, rz = px - x, py - y, pz - z
    r2 = rx * rx + ry * ry + rz * rz
    r = math.sqrt(r2)
    if do_double and r > 0.0:
        mx, my, mz = rx / r, ry / r, rz / r
        lobe = align * phase_eval(kind, g, dx * mx + dy * my + dz * mz) + (1.0 - align) * INV_4PI
        f = phase_eval(kind, g, mx * wx + my * wy + mz * wz) * lobe * inv_r2_ball(r, rclamp)
        out_d[0] += sig_s[0] * Pr * f * math.exp(-(sig_a[0] + sig_s[0]) * r)
        out_d[1] += sig_s[1] * Pg * f * math.exp(-(sig_a[1] + sig_s[1]) * r)
        out_d[2] += sig_s[2] * Pb * f * math.exp(-(sig_a[2] + sig_s[2]) * r)
    if do_multiple:
        out_m[0] += scaled_lookup(tabs[0], Pr, sig_a[0] + sig_s[0], rx, ry, rz, dx, dy, dz, wx, wy, wz)
        out_m[1] += scaled_lookup(tabs[1], Pg, sig_a[1] + sig_s[1], rx, ry, rz, dx, dy, dz, wx, wy, wz)
        out_m[2] += scaled_lookup(tabs[2], Pb, sig_a[2] + sig_s[2], rx, ry, rz, dx, dy, dz, wx, wy, wz)


NEAR_SUB = 8  # sub-points along a segment that is close to P


@njit(cache=True)
def _segment_source(i, v_start, v_dir, v_len, v_power, v_centre, v_scat, v_rb, sig_a, sig_s, kind, g, px, py, pz,
                    wx, wy, wz, rclamp, do_double, do_multiple, tabs, out_d, out_m):
    """A volume sample as a source: one point far from P; near P (closer than two segment lengths) NEAR_SUB
    points along the segment, each with its exact share sigma_s/sigma_t (e^-st t0 - e^-st t1) of the power, so
    that 1/r^2 needs clamping only at the beam radius."""
    cx, cy, cz = px - v_centre[i, 0], py - v_centre[i, 1], pz - v_centre[i, 2]
    ln = v_len[i]
    if cx * cx + cy * cy + cz * cz > 4.0 * ln * ln:
        _source(v_centre[i, 0], v_centre[i, 1], v_centre[i, 2], v_dir[i, 0], v_dir[i, 1], v_dir[i, 2],
                v_scat[i, 0], v_scat[i, 1], v_scat[i, 2], px, py, pz, wx, wy, wz, sig_a, sig_s, kind, g,
                max(rclamp, max(0.5 * ln, v_rb[i])), do_double, do_multiple, tabs, out_d, out_m)
        return
    pw = np.empty(3)
    for q in range(NEAR_SUB):
        t0, t1 = ln * q / NEAR_SUB, ln * (q + 1) / NEAR_SUB
        for c in range(3):
            st = sig_a[c] + sig_s[c]
            pw[c] = v_power[i, c] * (sig_s[c] / st * (math.exp(-st * t0) - math.exp(-st * t1)) if st > 0.0 else 0.0)
        tm = 0.5 * (t0 + t1)
        _source(v_start[i, 0] + tm * v_dir[i, 0], v_start[i, 1] + tm * v_dir[i, 1], v_start[i, 2] + tm * v_dir[i, 2],
                v_dir[i, 0], v_dir[i, 1], v_dir[i, 2], pw[0], pw[1], pw[2], px, py, pz, wx, wy, wz, sig_a, sig_s,
                kind, g, max(rclamp, max(0.5 * (t1 - t0), v_rb[i])), do_double, do_multiple, tabs, out_d, out_m)


@njit(cache=True)
def double_multiple(tree, v_start, v_dir, v_len, v_power, v_centre, v_scat, v_rb, sig_a, sig_s, kind, g,
                    px, py, pz, wx, wy, wz, tau, rclamp, do_double, do_multiple, tabs, out_d, out_m):
    order, lo, hi, centre, dirsum, power = tree[0], tree[1], tree[2], tree[3], tree[4], tree[5]
    first_child, n_children, start, end = tree[6], tree[7], tree[8], tree[9]
    stack = np.empty(256, np.int64)
    sp = 1
    stack[0] = 0
    while sp > 0:
        sp -= 1
        nd = stack[sp]
        inside = (lo[nd, 0] <= px <= hi[nd, 0] and lo[nd, 1] <= py <= hi[nd, 1] and lo[nd, 2] <= pz <= hi[nd, 2])
        leaf = first_child[nd] < 0
        if not inside and not leaf:
            cx, cy, cz = px - centre[nd, 0], py - centre[nd, 1], pz - centre[nd, 2]
            d2 = cx * cx + cy * cy + cz * cz
            hx, hy, hz = hi[nd, 0] - lo[nd, 0], hi[nd, 1] - lo[nd, 1], hi[nd, 2] - lo[nd, 2]
            h2 = 0.25 * (hx * hx + hy * hy + hz * hz)
            d = math.sqrt(d2)
            crit = math.pi * h2 / d2 * 4.0 * math.pi * phase_eval(kind, g, (cx * wx + cy * wy + cz * wz) / d)
            if crit < tau:
                sx, sy, sz = dirsum[nd, 0], dirsum[nd, 1], dirsum[nd, 2]
                sn = math.sqrt(sx * sx + sy * sy + sz * sz)
                wsum = power[nd, 0] + power[nd, 1] + power[nd, 2]
                if sn > 0.0 and wsum > 0.0:
                    _source(centre[nd, 0], centre[nd, 1], centre[nd, 2], sx / sn, sy / sn, sz / sn, power[nd, 0],
                            power[nd, 1], power[nd, 2], px, py, pz, wx, wy, wz, sig_a, sig_s, kind, g,
                            max(rclamp, math.sqrt(h2)), do_double, do_multiple, tabs, out_d, out_m, min(1.0, sn / wsum))
                continue
        if not leaf:
            for ch in range(first_child[nd], first_child[nd] + n_children[nd]):
                if sp < 256:
                    stack[sp] = ch
                    sp += 1
            continue
        for k in range(start[nd], end[nd]):
            _segment_source(order[k], v_start, v_dir, v_len, v_power, v_centre, v_scat, v_rb, sig_a, sig_s, kind, g,
                            px, py, pz, wx, wy, wz, rclamp, do_double, do_multiple, tabs, out_d, out_m)
