"""Single scattering at camera points: beam x point (Wang et al. 2016, eq. 4, read as photon beams).

S_1(P, w) = sigma_s sum_v p(d_v . w) Phi_v e^(-sigma_t t_v(P)) / A_v over the beams whose kernel disc (area A_v,
perpendicular to the beam) holds P, in W m^-3 sr^-1 per RGB channel: the photon-beam estimate that the paper's
average over the boxes containing P approximates.

Two ways to the same sums: point by point (single_scattering: a walk of the octree for each point), or, for many
points at once, sample by sample (single_scattering_by_samples: each beam segment, or each leg of segments end to
end, visits the grid cells of the points its kernel cylinder may hold). A point's walk visits some 200 leaves and
tests ten samples for each that holds it (the leaves' boxes are loose around oblique cylinders); the second way
costs a pass over the samples, and pays from about one point per hundred samples (docs/pbl.md, section 4).
single_scattering_at_points takes the cheaper of the two for a set of points.
"""

import math

import numpy as np
from numba import njit

from pbvol_cli.physics.phase import phase_eval
from pbvol_cli.pointbased.octree import LEAF_WALK_STACK, next_leaf
from pbvol_cli.pointbased.volume_samples import END_EXTENSION, ENTRY_N, ENTRY_Q, NO_PLANE, Query

PLANE_PATH_MIN_COS = 0.1  # legs closer than this to grazing their entry plane are attenuated along their axis
GRID_CELL_RADII = 2.0  # the points' grid's cells, median kernel radii wide
GRID_MAX_CELLS = 1 << 21  # the points' grid (single_scattering_by_samples): cells at most, coarser cells beyond
POINTS_PER_SAMPLE_FOR_GRID = 0.01  # points per volume sample from which the sample-by-sample way is taken:
# on the oil sphere's 1.05 million samples the two ways cost the same at 6800 points (docs/pbl.md, section 4)


@njit(inline="always", cache=True)
def axial_extent(v_len, v_area, v_ends, i):
    """(t_lo, t_hi): the stretch of volume sample i's axis, from its start, that its kernel cylinder spans. v_*:
    VolumeSamples's arrays (the bundle is not passed to the inlined helpers: numba copies it at every call).

    A segment that starts (ends) on the boundary is continued backward (forward) by END_EXTENSION kernel radii:
    otherwise a point near the boundary misses the neighbouring beams whose discs reach it before they enter (after
    they leave), a deficit in dense media; continued, the kernel average is exact for a flat boundary."""
    ext = END_EXTENSION * math.sqrt(v_area[i] / math.pi)
    return (-ext if v_ends[i] & 1 else 0.0), v_len[i] + (ext if v_ends[i] & 2 else 0.0)


@njit(inline="always", cache=True)
def axis_offset(qx, qy, qz, ux, uy, uz):
    """(t, r^2): the offset q's position along the unit axis u and its squared distance from it."""
    t = qx * ux + qy * uy + qz * uz
    rx, ry, rz = qx - t * ux, qy - t * uy, qz - t * uz
    return t, rx * rx + ry * ry + rz * rz


@njit(inline="always", cache=True)
def beam_frame(v_start, v_dir, v_plane, v_area, v_power, sig_s, i):
    """What volume sample i's share of S_1 (beam_share) needs of the sample, once for all the points it reaches:
    (a_R, a_G, a_B) = sigma_s Phi / A per channel (m^-3), and its leg's entry plane n . x = q with the sample
    start's depth below it d0 and the cosine cn between the leg and the inward normal (scene units)."""
    inv_area = 1.0 / v_area[i]
    nx, ny, nz, q = v_plane[i, ENTRY_N], v_plane[i, ENTRY_N + 1], v_plane[i, ENTRY_N + 2], v_plane[i, ENTRY_Q]
    cn = -(nx * v_dir[i, 0] + ny * v_dir[i, 1] + nz * v_dir[i, 2])
    d0 = q - (nx * v_start[i, 0] + ny * v_start[i, 1] + nz * v_start[i, 2])
    return (sig_s[0] * v_power[i, 0] * inv_area, sig_s[1] * v_power[i, 1] * inv_area,
            sig_s[2] * v_power[i, 2] * inv_area, nx, ny, nz, q, d0, cn)


@njit(inline="always", cache=True)
def beam_share(a0, a1, a2, nx, ny, nz, q, d0, cn, ux, uy, uz, st0, st1, st2, phase, g, t, px, py, pz, wx, wy, wz,
               out):
    """Adds a volume sample's share of S_1 at P = (px, py, pz) toward w to out (3,) (a sample whose kernel holds
    P): its beam_frame (a, the plane, d0, cn), its direction u, sigma_t per channel (st), and t, P's offset along
    its axis from its start.

    The attenuation is taken over P's own path from the leg's entry plane (its depth below the plane / cos theta),
    not along the beam's axis: across a kernel disc of radius r the beams' paths differ by up to r tan(theta), and
    the disc's average of their exponentials exceeds the value at P by 2 I_1(x) / x, x = sigma_t r tan(theta)
    (docs/pbl.md). Grazing legs keep the axis: there the tangent plane's depth is a poor guide a little aside."""
    ph = phase_eval(phase, g, ux * wx + uy * wy + uz * wz)
    if cn > PLANE_PATH_MIN_COS:
        # P's depth below the plane where the leg entered, never above it: no beam carries more than the
        # power it entered with (a point beyond a curved boundary's tangent plane, or in the continuation)
        tt = (max(q - (nx * px + ny * py + nz * pz), 0.0) - d0) / cn
    else:
        tt = max(t, 0.0)  # the backward continuation of a grazing leg keeps its entry power
    out[0] += a0 * ph * math.exp(-st0 * tt)
    out[1] += a1 * ph * math.exp(-st1 * tt)
    out[2] += a2 * ph * math.exp(-st2 * tt)


@njit(cache=True)
def single_scattering(vs, med, q, out):
    """Adds S_1(P, w) to out (3,): the samples of the octree's leaves whose boxes hold P (beam_share where their
    kernel cylinder holds it).
    vs: VolumeSamples, med: Medium, q: Query."""
    tree, v_start, v_dir, v_len, v_area, v_ends = vs.tree, vs.start, vs.dir, vs.len, vs.area, vs.ends
    v_plane, v_power, sig_a, sig_s, phase, g = vs.plane, vs.power, med.sigma_a, med.sigma_s, med.phase, med.g
    px, py, pz, wx, wy, wz = q.x, q.y, q.z, q.wx, q.wy, q.wz
    st0, st1, st2 = sig_a[0] + sig_s[0], sig_a[1] + sig_s[1], sig_a[2] + sig_s[2]
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
            t_lo, t_hi = axial_extent(v_len, v_area, v_ends, i)
            if t < t_lo or t >= t_hi:
                continue
            rx, ry, rz = qx - t * v_dir[i, 0], qy - t * v_dir[i, 1], qz - t * v_dir[i, 2]
            if (rx * rx + ry * ry + rz * rz) * math.pi > v_area[i]:
                continue
            a0, a1, a2, nx, ny, nz, pq, d0, cn = beam_frame(v_start, v_dir, v_plane, v_area, v_power, sig_s, i)
            beam_share(a0, a1, a2, nx, ny, nz, pq, d0, cn, v_dir[i, 0], v_dir[i, 1], v_dir[i, 2], st0, st1, st2,
                       phase, g, t, px, py, pz, wx, wy, wz, out)


@njit(cache=True)
def point_grid(pts, cell):
    """The points (m, 3) sorted into a uniform grid of cubes `cell` wide (coarser where that would exceed
    GRID_MAX_CELLS): (lo (3,), the cell's side, dims (3,), cell_start (cells + 1,), cell_points (m,)): the points of
    cell (ix * dims[1] + iy) * dims[2] + iz are cell_points[cell_start[c]:cell_start[c + 1]]."""
    m = pts.shape[0]
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for j in range(m):
        for c in range(3):
            lo[c] = min(lo[c], pts[j, c])
            hi[c] = max(hi[c], pts[j, c])
    side = max(cell, 1e-12)
    ext = np.maximum(hi - lo, 0.0)
    while (math.floor(ext[0] / side) + 1) * (math.floor(ext[1] / side) + 1) * (math.floor(ext[2] / side) + 1) \
            > GRID_MAX_CELLS:
        side *= 1.25
    dims = np.empty(3, np.int64)
    for c in range(3):
        dims[c] = int(math.floor(ext[c] / side)) + 1
    n_cells = dims[0] * dims[1] * dims[2]
    cell_of = np.empty(m, np.int64)
    cell_start = np.zeros(n_cells + 1, np.int64)
    for j in range(m):
        ix = min(int((pts[j, 0] - lo[0]) / side), dims[0] - 1)
        iy = min(int((pts[j, 1] - lo[1]) / side), dims[1] - 1)
        iz = min(int((pts[j, 2] - lo[2]) / side), dims[2] - 1)
        cell_of[j] = (ix * dims[1] + iy) * dims[2] + iz
        cell_start[cell_of[j] + 1] += 1
    for c in range(n_cells):
        cell_start[c + 1] += cell_start[c]
    fill = cell_start[:-1].copy()
    cell_points = np.empty(m, np.int64)
    for j in range(m):  # in the points' order within a cell
        cell_points[fill[cell_of[j]]] = j
        fill[cell_of[j]] += 1
    return lo, side, dims, cell_start, cell_points


@njit(nogil=True, cache=True)
def _splat(vs, med, pts, wdir, lo, side, dims, cell_start, x_from, x_to, out):
    """Every volume sample's share added to the points of its kernel cylinder whose grid cells lie in the slab
    x_from <= ix < x_to (pts, wdir, out (m, 3) in the grid's order: point_grid's cell_points). The samples are
    taken in their order, so that each point's sum runs in the same order however the grid is cut in slabs (the
    same image for any thread count)."""
    v_start, v_dir, v_len, v_area, v_ends = vs.start, vs.dir, vs.len, vs.area, vs.ends
    v_plane, v_power, sig_a, sig_s, phase, g = vs.plane, vs.power, med.sigma_a, med.sigma_s, med.phase, med.g
    st0, st1, st2 = sig_a[0] + sig_s[0], sig_a[1] + sig_s[1], sig_a[2] + sig_s[2]
    half_diag = 0.5 * math.sqrt(3.0) * side
    for i in range(v_start.shape[0]):
        rb, area = math.sqrt(v_area[i] / math.pi), v_area[i]
        t_lo, t_hi = axial_extent(v_len, v_area, v_ends, i)
        sx, sy, sz = v_start[i, 0], v_start[i, 1], v_start[i, 2]
        ux, uy, uz = v_dir[i, 0], v_dir[i, 1], v_dir[i, 2]
        ax, ay, az = sx + t_lo * ux, sy + t_lo * uy, sz + t_lo * uz  # the cylinder's axis from a to b
        bx, by, bz = sx + t_hi * ux, sy + t_hi * uy, sz + t_hi * uz
        # the cells of the cylinder's box (inclusive ranges), the x range cut to the slab
        x0 = max(int(math.floor((min(ax, bx) - rb - lo[0]) / side)), x_from)
        x1 = min(int(math.floor((max(ax, bx) + rb - lo[0]) / side)), x_to - 1)
        y0 = max(int(math.floor((min(ay, by) - rb - lo[1]) / side)), 0)
        y1 = min(int(math.floor((max(ay, by) + rb - lo[1]) / side)), dims[1] - 1)
        z0 = max(int(math.floor((min(az, bz) - rb - lo[2]) / side)), 0)
        z1 = min(int(math.floor((max(az, bz) + rb - lo[2]) / side)), dims[2] - 1)
        if x0 > x1 or y0 > y1 or z0 > z1:
            continue
        reach2 = (rb + half_diag) ** 2  # a cell whose centre is farther from the axis holds no point of the disc
        a0, a1, a2, nx, ny, nz, pq, d0, cn = beam_frame(v_start, v_dir, v_plane, v_area, v_power, sig_s, i)
        for ix in range(x0, x1 + 1):
            cx = lo[0] + (ix + 0.5) * side - sx
            for iy in range(y0, y1 + 1):
                cy = lo[1] + (iy + 0.5) * side - sy
                row = (ix * dims[1] + iy) * dims[2]
                for iz in range(z0, z1 + 1):
                    cz = lo[2] + (iz + 0.5) * side - sz
                    t = min(max(cx * ux + cy * uy + cz * uz, t_lo), t_hi)
                    dx, dy, dz = cx - t * ux, cy - t * uy, cz - t * uz
                    if dx * dx + dy * dy + dz * dz > reach2:
                        continue
                    for j in range(cell_start[row + iz], cell_start[row + iz + 1]):
                        t, r2 = axis_offset(pts[j, 0] - sx, pts[j, 1] - sy, pts[j, 2] - sz, ux, uy, uz)
                        if t < t_lo or t >= t_hi or r2 * math.pi > area:  # not in its kernel cylinder
                            continue
                        beam_share(a0, a1, a2, nx, ny, nz, pq, d0, cn, ux, uy, uz, st0, st1, st2, phase, g, t,
                                   pts[j, 0], pts[j, 1], pts[j, 2], wdir[j, 0], wdir[j, 1], wdir[j, 2], out[j])


@njit(inline="always", cache=True)
def _ball_chord(ca, cb, qa, qb, qw, r2):
    """(lo, hi): where the line {(ca, cb, w)} runs within the ball of squared radius r2 about (qa, qb, qw) (lo > hi:
    nowhere)."""
    d2 = r2 - (ca - qa) ** 2 - (cb - qb) ** 2
    if d2 < 0.0:
        return np.inf, -np.inf
    h = math.sqrt(d2)
    return qw - h, qw + h


@njit(inline="always", cache=True)
def _in_cylinder(xs, ys, zs, j0, j1, sx, sy, sz, ux, uy, uz, t_lo, t_hi, area, hit, hit_t, nh, col_t, col_in):
    """Appends the points j0 <= j < j1 (coordinates xs, ys, zs) within the kernel cylinder of the axis from s along
    u, t_lo <= t < t_hi, of cross-section `area`, to hit (and their offsets t along the axis to hit_t) from index
    nh; returns the new count. Two loops: every point's offset and verdict into col_t, col_in (scratch of the
    points' count), which the compiler vectorises, then the points inside appended without a branch (about one
    point in seven is: a branch on it was mispredicted often). A tenth less time for single scattering than one
    loop that tests and appends (docs/pbl.md, section 12)."""
    n = j1 - j0
    for k in range(n):
        j = j0 + k
        t, rr = axis_offset(xs[j] - sx, ys[j] - sy, zs[j] - sz, ux, uy, uz)
        col_t[k] = t
        col_in[k] = (t >= t_lo) & (t < t_hi) & (rr * math.pi <= area)
    for k in range(n):
        hit[nh] = j0 + k
        hit_t[nh] = col_t[k]
        nh += np.int64(col_in[k])
    return nh


@njit(nogil=True, cache=True)
def _splat_legs(vs, med, pts, wdir, lo, side, dims, cell_start, x_from, x_to, out):
    """_splat's sums taken leg by leg (vs.leg_first, vs.leg_span: volume_samples.leg_table): a leg's segments are
    one kernel cylinder, and a point it holds takes the same share from whichever segment holds it, so each grid
    cell near the leg is visited once, where segment by segment the cells around every joint were visited twice
    (on the oil sphere 86 instead of 141 million points tested, a fifth less time). The cells within reach (the
    kernel radius and half a cell's diagonal) of the leg's axis are enumerated exactly: rows along the axis the leg
    crosses second fastest, columns of each row across the third, and in each column the range along the axis it
    runs most along, where the column's line meets the capsule around the axis (a cylinder and two end balls).
    A column's points in the cylinder are gathered first (_in_cylinder; one run of points where the grid's
    fastest axis is the column's), then their shares added in the points' order: the same sums, 0.86 -> 0.71 s
    on one thread for the oil sphere's pass (docs/pbl.md, section 12)."""
    v_start, v_dir, v_area = vs.start, vs.dir, vs.area
    v_plane, v_power, sig_a, sig_s, phase, g = vs.plane, vs.power, med.sigma_a, med.sigma_s, med.phase, med.g
    st0, st1, st2 = sig_a[0] + sig_s[0], sig_a[1] + sig_s[1], sig_a[2] + sig_s[2]
    half_diag = 0.5 * math.sqrt(3.0) * side
    lim_lo, lim_hi = np.zeros(3, np.int64), dims - 1
    lim_lo[0], lim_hi[0] = x_from, x_to - 1  # this thread's slab of cells along x
    stride = np.array([dims[1] * dims[2], dims[2], 1], np.int64)
    s, u, A, B = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    xs, ys, zs = pts[:, 0].copy(), pts[:, 1].copy(), pts[:, 2].copy()  # (contiguous: _in_cylinder's loop)
    hit, hit_t = np.empty(pts.shape[0], np.int64), np.empty(pts.shape[0])  # a column's points in the cylinder
    col_t, col_in = np.empty(pts.shape[0]), np.empty(pts.shape[0], np.bool_)  # _in_cylinder's scratch
    for leg in range(vs.leg_first.shape[0]):
        i = vs.leg_first[leg]
        area = v_area[i]
        t_lo, t_hi = vs.leg_span[leg, 0], vs.leg_span[leg, 1]
        for c in range(3):
            s[c], u[c] = v_start[i, c], v_dir[i, c]
            A[c], B[c] = s[c] + t_lo * u[c], s[c] + t_hi * u[c]  # the axis's ends
        # a cell whose centre is farther from the axis holds no point of the kernel (a hair wider: rounding)
        reach = (math.sqrt(area / math.pi) + half_diag) * (1.0 + 1e-9) + 1e-12 * side
        r2 = reach * reach
        w = 0  # the axes: w the one the leg runs most along, a the next, b the last
        if abs(u[1]) > abs(u[w]):
            w = 1
        if abs(u[2]) > abs(u[w]):
            w = 2
        a, b = (w + 1) % 3, (w + 2) % 3
        if abs(u[b]) > abs(u[a]):
            a, b = b, a
        a0, a1, a2, nx, ny, nz, pq, d0, cn = beam_frame(v_start, v_dir, v_plane, v_area, v_power, sig_s, i)
        ux, uy, uz, sx, sy, sz = u[0], u[1], u[2], s[0], s[1], s[2]
        one_uw2 = 1.0 - u[w] * u[w]
        ia0 = max(int(math.floor((min(A[a], B[a]) - reach - lo[a]) / side - 0.5)), lim_lo[a])
        ia1 = min(int(math.ceil((max(A[a], B[a]) + reach - lo[a]) / side - 0.5)), lim_hi[a])
        for ia in range(ia0, ia1 + 1):
            ca = lo[a] + (ia + 0.5) * side
            # the stretch of the axis within reach of the plane through the row's centres, and the row's columns
            if abs(u[a]) > 1e-12:
                ta, tb = (ca - reach - s[a]) / u[a], (ca + reach - s[a]) / u[a]
                ta, tb = max(min(ta, tb), t_lo), min(max(ta, tb), t_hi)
                if ta > tb:
                    continue
            elif abs(ca - s[a]) > reach:
                continue
            else:
                ta, tb = t_lo, t_hi
            pb0, pb1 = s[b] + ta * u[b], s[b] + tb * u[b]
            ib0 = max(int(math.floor((min(pb0, pb1) - reach - lo[b]) / side - 0.5)), lim_lo[b])
            ib1 = min(int(math.ceil((max(pb0, pb1) + reach - lo[b]) / side - 0.5)), lim_hi[b])
            for ib in range(ib0, ib1 + 1):
                cb = lo[b] + (ib + 0.5) * side
                # the column's range along w within reach of the axis from t_lo to t_hi: its end balls, and the
                # cylinder between them, whose squared distance is quadratic in x = w - s_w
                wlo, whi = _ball_chord(ca, cb, A[a], A[b], A[w], r2)
                lo2, hi2 = _ball_chord(ca, cb, B[a], B[b], B[w], r2)
                wlo, whi = min(wlo, lo2), max(whi, hi2)
                qa, qb = ca - s[a], cb - s[b]
                k0 = qa * u[a] + qb * u[b]  # the axial offset t = k0 + x u_w
                cc = qa * qa + qb * qb - k0 * k0 - r2
                bb = -2.0 * k0 * u[w]
                if one_uw2 > 1e-12:
                    disc = bb * bb - 4.0 * one_uw2 * cc
                    if disc >= 0.0:
                        sq = math.sqrt(disc)
                        x_lo, x_hi = (-bb - sq) / (2.0 * one_uw2), (-bb + sq) / (2.0 * one_uw2)
                        y0, y1 = (t_lo - k0) / u[w], (t_hi - k0) / u[w]  # (|u_w| >= 1 / sqrt(3))
                        x_lo, x_hi = max(x_lo, min(y0, y1)), min(x_hi, max(y0, y1))
                        if x_lo <= x_hi:
                            wlo, whi = min(wlo, x_lo + s[w]), max(whi, x_hi + s[w])
                elif cc <= 0.0:  # the axis along w: the column within reach all along it
                    y0, y1 = (t_lo - k0) / u[w], (t_hi - k0) / u[w]
                    wlo, whi = min(wlo, min(y0, y1) + s[w]), max(whi, max(y0, y1) + s[w])
                if wlo > whi:
                    continue
                iw0 = max(int(math.ceil((wlo - lo[w]) / side - 0.5)), lim_lo[w])
                iw1 = min(int(math.floor((whi - lo[w]) / side - 0.5)), lim_hi[w])
                if iw0 > iw1:  # (within reach beyond the grid only; iw1 may be negative)
                    continue
                base = ia * stride[a] + ib * stride[b]
                nh = 0
                if stride[w] == 1:  # the column's cells are one run of points
                    nh = _in_cylinder(xs, ys, zs, cell_start[base + iw0], cell_start[base + iw1 + 1], sx, sy, sz, ux,
                                      uy, uz, t_lo, t_hi, area, hit, hit_t, nh, col_t, col_in)
                else:
                    for iw in range(iw0, iw1 + 1):
                        cell = base + iw * stride[w]
                        nh = _in_cylinder(xs, ys, zs, cell_start[cell], cell_start[cell + 1], sx, sy, sz, ux, uy, uz,
                                          t_lo, t_hi, area, hit, hit_t, nh, col_t, col_in)
                for h in range(nh):
                    j = hit[h]
                    beam_share(a0, a1, a2, nx, ny, nz, pq, d0, cn, ux, uy, uz, st0, st1, st2, phase, g, hit_t[h],
                               xs[j], ys[j], zs[j], wdir[j, 0], wdir[j, 1], wdir[j, 2], out[j])


def single_scattering_by_samples(pool, threads, vs, med, pts, wdir):
    """S_1 at the points pts (m, 3) toward wdir (m, 3, unit), (m, 3): the same sums as single_scattering at each,
    taken sample by sample over a grid of the points (cells GRID_CELL_RADII median kernel radii wide), the grid cut
    in slabs of about equal points, one a thread (pool: a ThreadPoolExecutor, or None)."""
    m = len(pts)
    out = np.zeros((m, 3))
    if m == 0 or vs.start.shape[0] == 0:
        return out
    pts, wdir = np.ascontiguousarray(pts, np.float64), np.ascontiguousarray(wdir, np.float64)
    finite = np.isfinite(pts).all(axis=1)
    if not finite.all():  # a point at infinity (along an unbounded segment) is in no kernel, as the walk finds
        out[finite] = single_scattering_by_samples(pool, threads, vs, med, pts[finite], wdir[finite])
        return out
    cell = GRID_CELL_RADII * float(np.median(np.sqrt(vs.area / np.pi)))
    lo, side, dims, cell_start, cell_points = point_grid(pts, cell)
    pts, wdir = pts[cell_points], wdir[cell_points]  # a cell's points side by side
    sorted_out = np.zeros((m, 3))
    n_slabs = max(1, min(threads, int(dims[0])))
    splat = _splat_legs if len(vs.leg_first) else _splat  # (legs: the same sums, fewer cells visited)
    if pool is None or n_slabs == 1:
        splat(vs, med, pts, wdir, lo, side, dims, cell_start, 0, int(dims[0]), sorted_out)
    else:
        # slab edges at equal shares of the points, along x
        per_x = np.diff(cell_start[::dims[1] * dims[2]])  # points per x slice of cells
        edges = np.searchsorted(np.cumsum(per_x), np.arange(1, n_slabs) * m / n_slabs)
        bounds = np.unique(np.concatenate([[0], edges + 1, [dims[0]]]).clip(0, dims[0]))
        list(pool.map(lambda s: splat(vs, med, pts, wdir, lo, side, dims, cell_start, int(bounds[s]),
                                      int(bounds[s + 1]), sorted_out), range(len(bounds) - 1)))
    out[cell_points] = sorted_out
    return out


@njit(nogil=True, cache=True)
def _walk_points(idx, vs, med, pts, wdir, out):
    """single_scattering at the points idx of pts (toward wdir), into out (m, 3)."""
    for k in range(idx.shape[0]):
        j = idx[k]
        single_scattering(vs, med, Query(pts[j, 0], pts[j, 1], pts[j, 2], wdir[j, 0], wdir[j, 1], wdir[j, 2], NO_PLANE),
                          out[j])


def single_scattering_at_points(pool, threads, vs, med, pts, wdir, order=None):
    """S_1 at the points pts (m, 3) toward wdir (m, 3), (m, 3), the cheaper way: sample by sample
    (single_scattering_by_samples) from POINTS_PER_SAMPLE_FOR_GRID points per volume sample, else point by point on
    `threads` interleaved slices of `order` (a permutation of the points that keeps neighbours together: the walks
    then find the octree's nodes in cache; a function of the points giving it, called only then; None: as given).
    The same sums either way."""
    m = len(pts)
    if m >= POINTS_PER_SAMPLE_FOR_GRID * vs.start.shape[0]:
        return single_scattering_by_samples(pool, threads, vs, med, pts, wdir)
    out = np.zeros((m, 3))
    pts, wdir = np.ascontiguousarray(pts, np.float64), np.ascontiguousarray(wdir, np.float64)
    if callable(order):
        order = order(pts)
    idx = np.arange(m, dtype=np.int64) if order is None else np.asarray(order, np.int64)
    if pool is None or threads <= 1 or m < 64:
        _walk_points(idx, vs, med, pts, wdir, out)
    else:
        list(pool.map(lambda t: _walk_points(np.ascontiguousarray(idx[t::threads]), vs, med, pts, wdir, out),
                      range(threads)))
    return out
