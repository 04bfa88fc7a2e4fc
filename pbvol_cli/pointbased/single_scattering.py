"""Single scattering at a camera point: beam x point (Wang et al. 2016, eq. 4, read as photon beams).

S_1(P, w) = sigma_s sum_v p(d_v . w) Phi_v e^(-sigma_t t_v(P)) / A_v over the beams whose kernel disc (area A_v,
perpendicular to the beam) holds P, in W m^-3 sr^-1 per RGB channel: the photon-beam estimate that the paper's
average over the boxes containing P approximates.
"""

import math

import numpy as np
from numba import njit

from pbvol_cli.physics.phase import phase_eval
from pbvol_cli.pointbased.octree import LEAF_WALK_STACK, next_leaf
from pbvol_cli.pointbased.volume_samples import END_EXTENSION, ENTRY_N, ENTRY_Q

PLANE_PATH_MIN_COS = 0.1  # legs closer than this to grazing their entry plane are attenuated along their axis


@njit(cache=True)
def single_scattering(vs, med, q, out):
    """Adds S_1(P, w) to out (3,). vs: VolumeSamples, med: Medium, q: Query.

    A segment that starts (ends) on the boundary is continued backward (forward) by END_EXTENSION kernel radii:
    otherwise a point near the boundary misses the neighbouring beams whose discs reach it before they enter (after
    they leave), a deficit in dense media; continued, the kernel average is exact for a flat boundary. The
    attenuation is taken over P's own path from the leg's entry plane (its depth below the plane / cos theta), not
    along the beam's axis: across a kernel disc of radius r the beams' paths differ by up to r tan(theta), and the
    disc's average of their exponentials exceeds the value at P by 2 I_1(x) / x, x = sigma_t r tan(theta)
    (docs/pbl.md). Grazing legs keep the axis: there the tangent plane's depth is a poor guide a little aside."""
    tree, v_start, v_dir, v_len, v_power, v_area = vs.tree, vs.start, vs.dir, vs.len, vs.power, vs.area
    v_ends, v_plane = vs.ends, vs.plane
    sig_a, sig_s = med.sigma_a, med.sigma_s
    px, py, pz, wx, wy, wz = q.x, q.y, q.z, q.wx, q.wy, q.wz
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
            ph = phase_eval(med.phase, med.g, v_dir[i, 0] * wx + v_dir[i, 1] * wy + v_dir[i, 2] * wz) / v_area[i]
            nx, ny, nz, q = v_plane[i, ENTRY_N], v_plane[i, ENTRY_N + 1], v_plane[i, ENTRY_N + 2], v_plane[i, ENTRY_Q]
            cn = -(nx * v_dir[i, 0] + ny * v_dir[i, 1] + nz * v_dir[i, 2])
            if cn > PLANE_PATH_MIN_COS:
                # P's depth below the plane where the leg entered, never above it: no beam carries more than the
                # power it entered with (a point beyond a curved boundary's tangent plane, or in the continuation)
                depth_p = max(q - (nx * px + ny * py + nz * pz), 0.0)
                tt = (depth_p - (q - (nx * v_start[i, 0] + ny * v_start[i, 1] + nz * v_start[i, 2]))) / cn
            else:
                tt = max(t, 0.0)  # the backward continuation of a grazing leg keeps its entry power
            for c in range(3):
                out[c] += sig_s[c] * ph * v_power[i, c] * math.exp(-(sig_a[c] + sig_s[c]) * tt)
