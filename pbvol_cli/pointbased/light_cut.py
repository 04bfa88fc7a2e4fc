"""Double and multiple scattering at a camera point summed over all volume samples by a stochastic light cut.

After Yuksel 2019 ("Stochastic Lightcuts"): the octree is refined cut_size times, the node of highest priority
(power x solid angle x transmittance: boxes near or around P first) first; a refined leaf is summed sample by
sample. Each node of the cut then contributes one representative sample drawn by importance toward P, weighted by
1 / its probability, so the estimate is unbiased whatever the cut: the cut only sets the noise. Every sample's
term is the exact per-sample estimator (sources.sample_terms): a node's phase lobes and 1/r^2 are never averaged
(with g = 0.9 lobes and 1/r^2 are convex and centroid approximations read low). Multiple scattering, smooth and
costly to look up, takes the cut as it stands after cut_size / MULTIPLE_CUT_SHARE refinements.

Double scattering's near field (within vs.r_near of P) is summed over every sample there instead (_near_field):
sources a few tenths of a mean free path from P, inside nodes the cut had not opened, were drawn rarely and weighted
heavily, and ruled the cut's noise.
"""

import math

import numpy as np
from numba import njit

from pbvol_cli.jit import as_runtime
from pbvol_cli.physics.phase import INV_4PI, phase_eval
from pbvol_cli.physics.sampling import rand
from pbvol_cli.pointbased.octree import (LEAF_WALK_STACK, LOBE_ALIGN, LOBE_CENTRE, LOBE_DIR, LOBE_EXT2, LOBE_HI,
                                         LOBE_LO, LOBE_POWER, LOBE_SPREAD2, next_leaf)
from pbvol_cli.pointbased.sources import NEAR_ALONG, sample_terms

CUT_CAP = 4096  # nodes a cut may hold at once (a node that would overflow it is used as it is)
MULTIPLE_CUT_SHARE = 4  # multiple scattering (smooth) uses the cut after cut_size / 4 refinements
LEAF_SCRATCH = 64  # a leaf's sample importances kept while its sample is drawn (leaves hold LEAF_SIZE, or a few more)
ROULETTE_POWER = 5.0  # a cut's node is kept surely where its power is at least this many times `roulette` of the
# cut's: a node the importance misjudges (near P) is then weighted by at most 1 / (its power share / this x roulette)
LINE_POINTS = 4  # points along a segment long next to its distance from P where its importance is judged
# a node whose box holds P is judged no nearer than a quarter of its extent or half the rms distance of its power
# from P, whichever is nearer (_node_importance)
BOX_NEAR, SPREAD_NEAR = 1.0 / 16.0, 0.25


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
def _lobe_and_phase(kind, g, dx, dy, dz, vx, vy, vz, r, q):
    """phase(d . m) x phase(m . w) for a source of beam direction d seeing P along v = P - source, |v| = r (m = v /
    r; the camera's direction w where r = 0): the source's lobe toward P times P's phase toward the camera."""
    if r > 0.0:
        mx, my, mz = vx / r, vy / r, vz / r
    else:
        mx, my, mz = q.wx, q.wy, q.wz
    return phase_eval(kind, g, dx * mx + dy * my + dz * mz) * phase_eval(kind, g, mx * q.wx + my * q.wy + mz * q.wz)


@njit(inline="always", cache=True)
def _node_importance(lobes, ch, q, kind, g, st_min):
    """How much node ch (its lobes row) may give double scattering at q (Query): power x lobe toward P (the node's
    mean direction, as aligned as its samples) x phase toward the camera x e^(-sigma r) / d^2, r from its centroid,
    d the distance to the box around its samples. Where that box holds P, d^2 is at least the smaller of BOX_NEAR x
    its squared half-diagonal and SPREAD_NEAR x (r^2 + its spread^2), the mean squared distance from P of a cloud
    of its spread about its centroid. In a dense medium long segments put nearly every box around P; the spread
    tells a node whose power lies near P from one that only reaches it. By the extent alone the wax candle's
    multiple term drew a child holding 0.72 of a node's light at 0.19, and bins read 10-20x high; by the spread
    alone a node of short segments far off with one long one passing by P reads too dim (docs/pbl.md, section
    12). Positive for every phase function here."""
    pw = lobes[ch, LOBE_POWER]
    rx, ry, rz = q.x - lobes[ch, LOBE_CENTRE], q.y - lobes[ch, LOBE_CENTRE + 1], q.z - lobes[ch, LOBE_CENTRE + 2]
    r2 = rx * rx + ry * ry + rz * rz
    r = math.sqrt(r2)
    if r > 0.0:
        mx, my, mz = rx / r, ry / r, rz / r
    else:
        mx, my, mz = q.wx, q.wy, q.wz
    align = lobes[ch, LOBE_ALIGN]
    lobe = (align * phase_eval(kind, g, lobes[ch, LOBE_DIR] * mx + lobes[ch, LOBE_DIR + 1] * my
                               + lobes[ch, LOBE_DIR + 2] * mz) + (1.0 - align) * INV_4PI)
    ex = max(lobes[ch, LOBE_LO] - q.x, 0.0, q.x - lobes[ch, LOBE_HI])
    ey = max(lobes[ch, LOBE_LO + 1] - q.y, 0.0, q.y - lobes[ch, LOBE_HI + 1])
    ez = max(lobes[ch, LOBE_LO + 2] - q.z, 0.0, q.z - lobes[ch, LOBE_HI + 2])
    floor = min(BOX_NEAR * lobes[ch, LOBE_EXT2], SPREAD_NEAR * (r2 + lobes[ch, LOBE_SPREAD2]))
    d2 = max(ex * ex + ey * ey + ez * ez, floor, 1e-30)
    return pw * lobe * phase_eval(kind, g, mx * q.wx + my * q.wy + mz * q.wz) * math.exp(-st_min * r) / d2


@njit(inline="always", cache=True)
def _sample_importance(i, vs, q, kind, g, st_min, ext_min2):
    """_node_importance of volume sample i as a line source: its power spread along its segment, 1/r^2 averaged
    along it (r at least its beam's radius and ext_min), the lobe (its own direction), the phase toward the camera
    and the transmittance taken at its point nearest P (or averaged along it, below). Judged at its centre with an
    extent of half its length (as before) a long segment read about ten times low where P lies near one end: on the
    milk a bounced segment 6 long (8 mean free paths), drawn at 1 in 1573 for 3 % of the estimate, made a bin read
    50x (docs/pbl.md)."""
    pw = vs.scat[i, 0] + vs.scat[i, 1] + vs.scat[i, 2]
    ln = vs.len[i]
    dx, dy, dz = vs.dir[i, 0], vs.dir[i, 1], vs.dir[i, 2]
    px, py, pz = q.x - vs.start[i, 0], q.y - vs.start[i, 1], q.z - vs.start[i, 2]
    tp = px * dx + py * dy + pz * dz  # P's offset along the segment's line from its start
    ex, ey, ez = px - tp * dx, py - tp * dy, pz - tp * dz
    r2 = max(ex * ex + ey * ey + ez * ez, vs.rb[i] ** 2, ext_min2)
    r0 = math.sqrt(r2)
    if ln > 1e-9 * r0:  # the mean over the segment of 1 / (r0^2 + (l - tp)^2)
        line = (math.atan((ln - tp) / r0) + math.atan(tp / r0)) / (r0 * ln)
    else:
        line = 1.0 / (r2 + tp * tp)
    tc = min(max(tp, 0.0), ln)
    cx, cy, cz = px - tc * dx, py - tc * dy, pz - tc * dz  # from the segment's nearest point to P
    rc = math.sqrt(cx * cx + cy * cy + cz * cz)
    if ln <= rc:  # P sees the segment under a narrow angle: lobe and phase at its nearest point
        return pw * _lobe_and_phase(kind, g, dx, dy, dz, cx, cy, cz, rc, q) * math.exp(-st_min * rc) * line
    # a segment long next to its distance: lobe x phase x transmittance averaged over LINE_POINTS points along it,
    # weighted by their 1/r^2. At its nearest point alone a segment passing by P sees P across its beam, far off
    # its forward lobe, though its upstream part shines at P: the candle's bins drew such a segment at 0.15 of a
    # leaf where it held 0.97 of the leaf's multiple term (docs/pbl.md)
    acc = 0.0
    wsum = 0.0
    for k in range(LINE_POINTS):
        t = ln * (k + 0.5) / LINE_POINTS
        ux, uy, uz = px - t * dx, py - t * dy, pz - t * dz
        rk2 = ux * ux + uy * uy + uz * uz
        rk = math.sqrt(rk2)
        w = 1.0 / max(rk2, r2)
        acc += w * _lobe_and_phase(kind, g, dx, dy, dz, ux, uy, uz, rk, q) * math.exp(-st_min * rk)
        wsum += w
    return pw * acc / wsum * line


@njit(cache=True)
def _representative(nd, vs, q, kind, g, st_min, ext_min2, u, imp, pws):
    """A sample of node nd drawn by descending with probabilities half proportional to each child's
    _node_importance and half to its power, then likewise among the leaf's samples (a light tree, after Conty
    Estevez and Kulla 2018, with a defensive mixture): sources whose lobes point at P and whose P-side phase
    points at the camera are found far more often than by power alone (g = 0.9: lobes 200x their mean), and at
    each level no child's probability falls below half its power share (importance alone, misjudged near P, made
    fireflies; over the levels that bounds a sample's weight by 2^levels times its power-proportional one. A
    one-sample mixture of the two whole descents, bounding it by twice, was measured and not kept: docs/pbl.md).
    imp, pws: scratch of LEAF_SCRATCH and 8 (a leaf's importances kept there between its two loops, where it
    fits). Returns (sample, 1 / its probability)."""
    tree, v_scat, lobes = vs.tree, vs.scat, vs.lobes
    order, first_child, n_children, start, end = tree[0], tree[6], tree[7], tree[8], tree[9]
    prob = 1.0
    while first_child[nd] >= 0:
        f0, nc = first_child[nd], n_children[nd]
        total = 0.0
        ptotal = 0.0
        for k in range(nc):
            ch = f0 + k
            pw = lobes[ch, LOBE_POWER]
            pws[k] = max(pw, 0.0)
            ptotal += pws[k]
            imp[k] = 0.0
            if pw <= 0.0:
                continue
            imp[k] = _node_importance(lobes, ch, q, kind, g, st_min)
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
    kept = end[nd] - start[nd] <= imp.shape[0]  # (a leaf beyond the octree's capacity may be larger)
    for k in range(start[nd], end[nd]):
        i = order[k]
        ptotal += v_scat[i, 0] + v_scat[i, 1] + v_scat[i, 2]
        si = _sample_importance(i, vs, q, kind, g, st_min, ext_min2)
        if kept:
            imp[k - start[nd]] = si
        total += si
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
            si = imp[k - start[nd]] if kept else _sample_importance(i, vs, q, kind, g, st_min, ext_min2)
            w += 0.5 * si / total
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


@njit(inline="always", cache=True)
def _roulette_odds(lobes, nd, q, kind, g, st_min, power_share, imp_total, power_total, roulette):
    """The probability that the cut's node nd (power_share: its power, channels summed) is evaluated: 1 where its
    _node_importance at q is at least `roulette` of the cut's total imp_total or its power at least
    ROULETTE_POWER x roulette of power_total; below both, the larger of the two shares over its threshold."""
    if roulette <= 0.0:
        return 1.0
    odds = power_share / (ROULETTE_POWER * roulette * power_total) if power_total > 0.0 else 1.0
    if imp_total > 0.0 and odds < 1.0:
        odds = max(odds, _node_importance(lobes, nd, q, kind, g, st_min) / (roulette * imp_total))
    return min(odds, 1.0)


@njit(cache=True)
def _cut_estimate(heap, hn, node_of, vs, med, q, rclamp, do_double, do_multiple, out_d, out_m, rng, ri, split,
                  roulette):
    """Each node of the cut contributes one representative sample, weighted by 1 / its probability (unbiased for
    the node's sum): drawn by importance toward P, by double scattering's kernel for either term (split:
    near_weight's; a far part needs no importance closer than half its radius; drawn by power, the multiple
    term's rare sources near P came with a node's whole weight). With roulette > 0 the cut's dim nodes are played
    by Russian roulette (_roulette_odds), a kept one weighted by 1 / its odds: most of a cut's nodes hold a
    hundredth of its light or less (lobes of g = 0.9 turned away from P, the body's far side), and each cost a
    descent and a sample's terms. Returns the samples evaluated."""
    power = vs.tree[5]
    lobes = vs.lobes
    sig_a, sig_s = med.sigma_a, med.sigma_s
    st_min = min(sig_a[0] + sig_s[0], min(sig_a[1] + sig_s[1], sig_a[2] + sig_s[2]))
    od = np.zeros(3)
    om = np.zeros(3)
    imp, pws = np.empty(LEAF_SCRATCH), np.empty(8)  # _representative's scratch
    imp_total, power_total = 0.0, 0.0
    if roulette > 0.0:
        for h in range(hn):
            nd = node_of[heap[h]]
            pw = power[nd, 0] + power[nd, 1] + power[nd, 2]
            if pw > 0.0:
                power_total += pw
                imp_total += _node_importance(lobes, nd, q, med.phase, med.g, st_min)
    n = 0
    for h in range(hn):
        nd = node_of[heap[h]]
        pw = power[nd, 0] + power[nd, 1] + power[nd, 2]
        if pw <= 0.0:
            continue
        odds = _roulette_odds(lobes, nd, q, med.phase, med.g, st_min, pw, imp_total, power_total, roulette)
        if odds < 1.0 and rand(rng, ri) >= odds:
            continue
        i, scale = _representative(nd, vs, q, med.phase, med.g, st_min, 0.25 * split * split, rand(rng, ri), imp,
                                   pws)
        if i < 0:
            continue
        scale /= odds
        for c in range(3):
            od[c] = 0.0
            om[c] = 0.0
        sample_terms(i, vs, med, q, rclamp, do_double, do_multiple, split, rand(rng, ri), od, om)
        n += 1
        for c in range(3):
            out_d[c] += scale * od[c]
            out_m[c] += scale * om[c]
    return n


@njit(cache=True)
def _near_field(vs, med, q, rclamp, out_d, out_m):
    """Double scattering's near part (near_weight with split = vs.r_near) from every sample whose segment comes
    within r_near of P in beam distance (sources.beam_distance: the stretch along its line divided by NEAR_ALONG):
    the octree's boxes widened by the farthest such point, walked like single scattering's. Returns the samples
    evaluated."""
    tree, v_start, v_dir, v_len = vs.tree, vs.start, vs.dir, vs.len
    order, start, end = tree[0], tree[8], tree[9]
    stack = np.empty(LEAF_WALK_STACK, np.int64)
    sp = np.ones(1, np.int64)
    stack[0] = 0
    n = 0
    R = vs.r_near
    reach = R * math.sqrt(1.0 + NEAR_ALONG * NEAR_ALONG)  # the farthest point of beam distance R
    while True:
        nd = next_leaf(tree, stack, sp, q.x, q.y, q.z, reach)
        if nd < 0:
            break
        for k in range(start[nd], end[nd]):
            i = order[k]
            qx, qy, qz = q.x - v_start[i, 0], q.y - v_start[i, 1], q.z - v_start[i, 2]
            tp = qx * v_dir[i, 0] + qy * v_dir[i, 1] + qz * v_dir[i, 2]
            across2 = qx * qx + qy * qy + qz * qz - tp * tp  # (P from the segment's line)
            along = max(-tp, tp - v_len[i], 0.0)  # (from P's foot to the segment)
            if across2 + (along / NEAR_ALONG) ** 2 >= R * R:  # no point of the segment within beam distance R
                continue
            n += 1
            sample_terms(i, vs, med, q, rclamp, as_runtime(True), as_runtime(False), R, 0.5, out_d, out_m)
    return n


@njit(cache=True)
def double_multiple(vs, med, q, cut_size, rclamp, do_double, do_multiple, out_d, out_m, rng, ri, ms_cut=-1,
                    roulette=0.0):
    """Adds double (out_d) and multiple (out_m) scattering at q (Query) from the volume samples vs (VolumeSamples)
    of med (Medium), by the stochastic light cut of the module docstring; rclamp: the smallest extent of a
    source's ball (scene units). With vs.r_near > 0 double scattering's kernel is split (sources.near_weight):
    its part within r_near of P is summed over every sample there, the cut takes the rest. Multiple scattering
    takes the cut after ms_cut refinements (-1: cut_size / MULTIPLE_CUT_SHARE; double's cut is then at least
    that). roulette: the share of double scattering's cut's importance below which a node is played by roulette
(_cut_estimate; 0: every node evaluated). The multiple term's cut keeps every node: the importance is double
scattering's kernel, and in a dense body, where the multiple term reaches many times farther than the transmittance
over one mean free path, roulette by it let the bounced generations' gather read 1.08 of its sources' power (a box
300 mean free paths thick: tests/pointbased/test_bounced.py). rng[ri] is the random state. Returns the number of samples evaluated (the cost)."""
    tree = vs.tree
    order, lo, hi, power = tree[0], tree[1], tree[2], tree[5]
    first_child, n_children, start, end = tree[6], tree[7], tree[8], tree[9]
    if first_child.shape[0] == 0:
        return 0
    sig_a, sig_s = med.sigma_a, med.sigma_s
    st_min = min(sig_a[0] + sig_s[0], min(sig_a[1] + sig_s[1], sig_a[2] + sig_s[2]))
    if ms_cut < 0:
        ms_cut = cut_size // MULTIPLE_CUT_SHARE
    cap = min(CUT_CAP, 8 * max(cut_size, ms_cut) + 64)
    node_of = np.empty(cap, np.int64)
    key = np.empty(cap)
    heap = np.empty(cap, np.int64)
    free = np.empty(cap, np.int64)
    node_of[0] = 0
    key[0] = 0.0
    hn = _heap_push(heap, 0, key, 0)
    n_slot, n_free, n_eval, n_refined = 1, 0, 0, 0
    ms_pending = do_multiple
    r_near = vs.r_near
    split = -r_near if do_double and r_near > 0.0 else 0.0
    if split < 0.0:
        n_eval += _near_field(vs, med, q, rclamp, out_d, out_m)
    while hn > 0:
        if ms_pending and n_refined >= ms_cut:
            n_eval += _cut_estimate(heap, hn, node_of, vs, med, q, rclamp, as_runtime(False), as_runtime(True),
                                    out_d, out_m, rng, ri, 0.0, 0.0)
            ms_pending = False
        if (n_refined >= cut_size or not do_double) and not ms_pending:
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
                sample_terms(order[k], vs, med, q, rclamp, do_double, ms_pending, split, rand(rng, ri), out_d,
                             out_m)
            continue
        for ch in range(first_child[nd], first_child[nd] + n_children[nd]):
            if n_free > 0:
                n_free -= 1
                e = free[n_free]
            else:
                e = n_slot
                n_slot += 1
            node_of[e] = ch
            key[e] = _node_priority(ch, lo, hi, power, q.x, q.y, q.z, st_min)
            hn = _heap_push(heap, hn, key, e)
    if do_double or ms_pending:  # (the multiple term alone: its cut was taken above)
        n_eval += _cut_estimate(heap, hn, node_of, vs, med, q, rclamp, do_double, ms_pending, out_d, out_m, rng,
                                ri, split, 0.0 if ms_pending else roulette)
    return n_eval
