"""An octree over point samples, as flat arrays (Wang et al. 2016, sec. 3.4-3.5).

Nodes are created parents first; children of a node are contiguous. Per node: the bounding box of its samples'
boxes (lo, hi), the power-weighted centroid, the power-weighted sum of directions (its length / total weight
measures how aligned they are), the RGB power sum, the range of its samples in `order`, and its children.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

LEAF_SIZE = 8
LEAF_WALK_STACK = 128  # depth-first stack of next_leaf's walks (8 children a level: ample)
# a node's row of node_lobes: its power-weighted centroid, mean direction (unit), alignment (|dirsum| / power, at most
# 1), power (R + G + B), and the box around its samples (their own extent: the segment and its beam's radius, not
# single scattering's wider kernel boxes) as its squared half-diagonal and its corners; what a light-cut descent reads
# of each child, in one record (the arrays of Octree, read child by child, were one cache miss each); and the spread
# of its power about the centroid: the power-weighted mean squared distance of the points along its segments
LOBE_CENTRE, LOBE_DIR, LOBE_ALIGN, LOBE_POWER, LOBE_EXT2, LOBE_LO, LOBE_HI, LOBE_SPREAD2, LOBE_COLS = \
    0, 3, 6, 7, 8, 9, 12, 15, 16


@dataclass
class Octree:
    order: np.ndarray  # (n,) sample indices, leaves' samples contiguous
    lo: np.ndarray  # (nodes, 3)
    hi: np.ndarray
    centre: np.ndarray  # (nodes, 3) power-weighted centroid
    dirsum: np.ndarray  # (nodes, 3) power-weighted sum of unit directions
    power: np.ndarray  # (nodes, 3)
    first_child: np.ndarray  # (nodes,) -1 for leaves
    n_children: np.ndarray
    start: np.ndarray  # (nodes,) range in order
    end: np.ndarray

    def arrays(self):
        return (self.order, self.lo, self.hi, self.centre, self.dirsum, self.power, self.first_child,
                self.n_children, self.start, self.end)


@njit(cache=True)
def _build(pts, order, node_start, node_end, first_child, n_children, leaf_size):
    """Split nodes into octants of their points' bounding box; returns the node count."""
    cap = node_start.shape[0]
    n_nodes = 1
    node_start[0], node_end[0] = 0, pts.shape[0]
    stack = np.empty(cap, np.int64)
    sp = 0
    stack[sp] = 0
    sp += 1
    tmp = np.empty(pts.shape[0], np.int64)
    while sp > 0:
        sp -= 1
        nd = stack[sp]
        a, b = node_start[nd], node_end[nd]
        first_child[nd] = -1
        n_children[nd] = 0
        if b - a <= leaf_size or n_nodes + 8 > cap:
            continue
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for k in range(a, b):
            for c in range(3):
                v = pts[order[k], c]
                lo[c] = min(lo[c], v)
                hi[c] = max(hi[c], v)
        if hi[0] - lo[0] <= 0 and hi[1] - lo[1] <= 0 and hi[2] - lo[2] <= 0:
            continue  # all at one point: a leaf, however many
        mid = 0.5 * (lo + hi)
        counts = np.zeros(8, np.int64)
        octs = np.empty(b - a, np.int64)
        for k in range(a, b):
            o = 0
            for c in range(3):
                if pts[order[k], c] > mid[c]:
                    o |= 1 << c
            octs[k - a] = o
            counts[o] += 1
        offs = np.zeros(9, np.int64)
        for o in range(8):
            offs[o + 1] = offs[o] + counts[o]
        fill = offs[:8].copy()
        for k in range(a, b):
            o = octs[k - a]
            tmp[a + fill[o]] = order[k]
            fill[o] += 1
        for k in range(a, b):
            order[k] = tmp[k]
        first_child[nd] = n_nodes
        for o in range(8):
            if counts[o] == 0:
                continue
            node_start[n_nodes], node_end[n_nodes] = a + offs[o], a + offs[o + 1]
            n_children[nd] += 1
            stack[sp] = n_nodes
            sp += 1
            n_nodes += 1
    return n_nodes


@njit(cache=True)
def _aggregate(order, start, end, first_child, n_children, n_nodes, pts, box_lo, box_hi, dirs, power,
               lo, hi, centre, dirsum, pw):
    for nd in range(n_nodes - 1, -1, -1):  # children were created after their parents
        for c in range(3):
            lo[nd, c], hi[nd, c] = np.inf, -np.inf
            centre[nd, c] = dirsum[nd, c] = pw[nd, c] = 0.0
        wsum = 0.0
        if first_child[nd] < 0:
            for k in range(start[nd], end[nd]):
                i = order[k]
                w = power[i, 0] + power[i, 1] + power[i, 2]
                wsum += w
                for c in range(3):
                    lo[nd, c] = min(lo[nd, c], box_lo[i, c])
                    hi[nd, c] = max(hi[nd, c], box_hi[i, c])
                    centre[nd, c] += w * pts[i, c]
                    dirsum[nd, c] += w * dirs[i, c]
                    pw[nd, c] += power[i, c]
        else:
            for ch in range(first_child[nd], first_child[nd] + n_children[nd]):
                w = pw[ch, 0] + pw[ch, 1] + pw[ch, 2]
                wsum += w
                for c in range(3):
                    lo[nd, c] = min(lo[nd, c], lo[ch, c])
                    hi[nd, c] = max(hi[nd, c], hi[ch, c])
                    centre[nd, c] += w * centre[ch, c]
                    dirsum[nd, c] += dirsum[ch, c]
                    pw[nd, c] += pw[ch, c]
        for c in range(3):
            centre[nd, c] = centre[nd, c] / wsum if wsum > 0 else 0.5 * (lo[nd, c] + hi[nd, c])


def build_octree(points, box_lo, box_hi, dirs, power, leaf_size: int = LEAF_SIZE) -> Octree:
    """Octree over samples at `points` with bounding boxes [box_lo, box_hi], unit directions and RGB power."""
    return aggregate_octree(octree_skeleton(points, leaf_size), points, box_lo, box_hi, dirs, power)


def octree_skeleton(points, leaf_size: int = LEAF_SIZE) -> Octree:
    """The octree's structure over `points` (order, children, ranges); its per-node boxes and sums are left empty
    for aggregate_octree (which may take the samples already in the tree's order)."""
    n = len(points)
    # every split at the box's midpoint leaves points on both sides of an axis: internal nodes have two children or
    # more, so there are fewer nodes than 2n (a node that would overflow the cap anyway stays a leaf)
    cap = 2 * n + 1024
    order = np.arange(n, dtype=np.int64)
    start, end = np.zeros(cap, np.int64), np.zeros(cap, np.int64)
    fc, nc = np.full(cap, -1, np.int64), np.zeros(cap, np.int64)
    m = _build(np.ascontiguousarray(points, np.float64), order, start, end, fc, nc, leaf_size) if n else 0
    empty = np.zeros((0, 3))
    return Octree(order, empty, empty, empty, empty, empty, fc[:m].copy(), nc[:m].copy(), start[:m].copy(),
                  end[:m].copy())


def aggregate_octree(skeleton: Octree, points, box_lo, box_hi, dirs, power) -> Octree:
    """The skeleton's nodes filled: boxes, power-weighted centroids and direction sums, power sums. The samples'
    arrays are indexed through skeleton.order (an identity order: they are stored in the tree's order)."""
    m = len(skeleton.start)
    lo, hi = np.zeros((m, 3)), np.zeros((m, 3))
    centre, dirsum, pw = np.zeros((m, 3)), np.zeros((m, 3)), np.zeros((m, 3))
    if m:
        _aggregate(skeleton.order, skeleton.start, skeleton.end, skeleton.first_child, skeleton.n_children, m,
                   np.ascontiguousarray(points, np.float64), np.asarray(box_lo, float), np.asarray(box_hi, float),
                   np.asarray(dirs, float), np.asarray(power, float), lo, hi, centre, dirsum, pw)
    return Octree(skeleton.order, lo, hi, centre, dirsum, pw, skeleton.first_child, skeleton.n_children,
                  skeleton.start, skeleton.end)


@njit(inline="always", cache=True)
def next_leaf(tree, stack, sp, px, py, pz, margin):
    """A depth-first walk to the leaves whose box, widened by margin, holds P (tree: Octree.arrays()). Pops the
    stack (its size in sp[0]; start with the root on it) until such a leaf, and returns it; -1 when done."""
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
def _node_extents(tree, box_lo, box_hi):
    """Each node's box around its samples' boxes [box_lo, box_hi] (sample order[k] at box_lo[order[k]]), as
    (squared half-diagonal (nodes,), lo (nodes, 3), hi (nodes, 3)); children come after parents: leaves first."""
    order, first_child, n_children, start, end = tree[0], tree[6], tree[7], tree[8], tree[9]
    n = first_child.shape[0]
    lo, hi = np.full((n, 3), np.inf), np.full((n, 3), -np.inf)
    ext2 = np.zeros(n)
    for nd in range(n - 1, -1, -1):
        if first_child[nd] < 0:
            for k in range(start[nd], end[nd]):
                i = order[k]
                for c in range(3):
                    lo[nd, c] = min(lo[nd, c], box_lo[i, c])
                    hi[nd, c] = max(hi[nd, c], box_hi[i, c])
        else:
            for ch in range(first_child[nd], first_child[nd] + n_children[nd]):
                for c in range(3):
                    lo[nd, c] = min(lo[nd, c], lo[ch, c])
                    hi[nd, c] = max(hi[nd, c], hi[ch, c])
        if end[nd] > start[nd]:
            hx, hy, hz = hi[nd, 0] - lo[nd, 0], hi[nd, 1] - lo[nd, 1], hi[nd, 2] - lo[nd, 2]
            ext2[nd] = 0.25 * (hx * hx + hy * hy + hz * hz)
    return ext2, lo, hi


@njit(cache=True)
def _node_lobes(tree, ext2, blo, bhi, points, length, weight):
    order, centre, dirsum, power, start, end = tree[0], tree[3], tree[4], tree[5], tree[8], tree[9]
    n = centre.shape[0]
    out = np.zeros((n, LOBE_COLS))
    for nd in range(n):
        pw = power[nd, 0] + power[nd, 1] + power[nd, 2]
        out[nd, LOBE_POWER] = pw
        if pw > 0.0 and length.shape[0] > 0:  # about the centroid, summed directly (no cancellation)
            acc = 0.0
            for k in range(start[nd], end[nd]):
                i = order[k]
                dx, dy, dz = points[i, 0] - centre[nd, 0], points[i, 1] - centre[nd, 1], points[i, 2] - centre[nd, 2]
                w = weight[i, 0] + weight[i, 1] + weight[i, 2]
                acc += w * (dx * dx + dy * dy + dz * dz + length[i] * length[i] / 12.0)
            out[nd, LOBE_SPREAD2] = acc / pw
        for c in range(3):
            out[nd, LOBE_CENTRE + c] = centre[nd, c]
        out[nd, LOBE_EXT2] = ext2[nd]
        for c in range(3):
            out[nd, LOBE_LO + c] = blo[nd, c]
            out[nd, LOBE_HI + c] = bhi[nd, c]
        sx, sy, sz = dirsum[nd, 0], dirsum[nd, 1], dirsum[nd, 2]
        sn = math.sqrt(sx * sx + sy * sy + sz * sz)
        if pw > 0.0 and sn > 0.0:
            out[nd, LOBE_DIR], out[nd, LOBE_DIR + 1], out[nd, LOBE_DIR + 2] = sx / sn, sy / sn, sz / sn
            out[nd, LOBE_ALIGN] = min(1.0, sn / pw)
        elif pw > 0.0:
            out[nd, LOBE_DIR + 2] = 1.0
    return out


def node_lobes(tree, box_lo=None, box_hi=None, segments=None) -> np.ndarray:
    """(nodes, LOBE_COLS): each node's lobe record (see LOBE_COLS) from tree (Octree.arrays()). The box is that
    around the samples' own boxes [box_lo, box_hi] (indexed like the tree's samples) where given, else the tree's.
    segments: (centres (m, 3), lengths (m,), power (m, 3)) of the tree's samples, the power the tree was built
    with, for the spread (LOBE_SPREAD2, left 0 without them; a point sample has length 0).
    A node without power gets a zero direction and alignment."""
    if box_lo is None:
        lo, hi = tree[1], tree[2]
        ext2 = 0.25 * np.sum((hi - lo) ** 2, axis=1) if len(lo) else np.zeros(0)
    else:
        ext2, lo, hi = _node_extents(tree, np.ascontiguousarray(box_lo, np.float64),
                                     np.ascontiguousarray(box_hi, np.float64))
    if segments is None:
        points, length, weight = np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))
    else:
        points, length, weight = (np.ascontiguousarray(a, np.float64) for a in segments)
    return _node_lobes(tree, np.ascontiguousarray(ext2, np.float64), np.ascontiguousarray(lo, np.float64),
                       np.ascontiguousarray(hi, np.float64), points, length, weight)
