#!/usr/bin/env python3
"""What single scattering's octree walk visits and scans at a camera point, and what the walk and the scan cost.

    .venv/bin/python benchmarks/pbl_single_scan.py [--scene oil_sphere] [--points 5000] [--radius 5.0]
        [--node-sizes 8,16,32,64]

Points uniform in the sphere of radius --radius about the origin (the example spheres), the scene's cached light
samples (as benchmarks/pbl_point_cost.py). A copy of `single_scattering`'s walk and scan with counters: per point
the nodes visited, the samples scanned, those within the segment's extent and those whose kernel cylinder holds
the point; then, on one thread, the walk alone and walk + scan in microseconds a point, for nodes of up to each
--node-sizes samples taken as leaves (8: the octree's own leaves), and walk + scan with the points sorted in space.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from pbvol_cli.pointbased.octree import LEAF_WALK_STACK  # noqa: E402
from pbvol_cli.pointbased.volume_samples import END_EXTENSION  # noqa: E402


@njit(cache=True)
def _next_node(tree, stack, sp, px, py, pz, max_count):
    """octree.next_leaf, stopping at nodes of at most max_count samples."""
    lo, hi, first_child, n_children, start, end = tree[1], tree[2], tree[6], tree[7], tree[8], tree[9]
    while sp[0] > 0:
        sp[0] -= 1
        nd = stack[sp[0]]
        if px < lo[nd, 0] or px > hi[nd, 0] or py < lo[nd, 1] or py > hi[nd, 1] or pz < lo[nd, 2] or pz > hi[nd, 2]:
            continue
        if first_child[nd] < 0 or end[nd] - start[nd] <= max_count:
            return nd
        for ch in range(first_child[nd], first_child[nd] + n_children[nd]):
            stack[sp[0]] = ch
            sp[0] += 1
    return -1


@njit(cache=True)
def _scan(vs, pts, max_count, scan):
    """Per point: (nodes visited, samples scanned, within the extent, kernel hits); scan=False walks only."""
    tree, v_start, v_dir, v_len, v_area, v_ends = vs.tree, vs.start, vs.dir, vs.len, vs.area, vs.ends
    start, end = tree[8], tree[9]
    out = np.zeros((pts.shape[0], 4), np.int64)
    stack = np.empty(LEAF_WALK_STACK, np.int64)
    sp = np.ones(1, np.int64)
    for p in range(pts.shape[0]):
        px, py, pz = pts[p, 0], pts[p, 1], pts[p, 2]
        sp[0] = 1
        stack[0] = 0
        while True:
            nd = _next_node(tree, stack, sp, px, py, pz, max_count)
            if nd < 0:
                break
            out[p, 0] += 1
            if not scan:
                continue
            for i in range(start[nd], end[nd]):  # (samples are stored in the tree's order)
                out[p, 1] += 1
                qx, qy, qz = px - v_start[i, 0], py - v_start[i, 1], pz - v_start[i, 2]
                t = qx * v_dir[i, 0] + qy * v_dir[i, 1] + qz * v_dir[i, 2]
                ext = END_EXTENSION * math.sqrt(v_area[i] / math.pi)
                if t < (-ext if v_ends[i] & 1 else 0.0) or t >= v_len[i] + (ext if v_ends[i] & 2 else 0.0):
                    continue
                out[p, 2] += 1
                rx, ry, rz = qx - t * v_dir[i, 0], qy - t * v_dir[i, 1], qz - t * v_dir[i, 2]
                if (rx * rx + ry * ry + rz * rz) * math.pi <= v_area[i]:
                    out[p, 3] += 1
    return out


def _timed(vs, pts, max_count, scan):
    _scan(vs, pts[:8], max_count, scan)
    best = math.inf
    for _ in range(3):
        t = time.perf_counter()
        out = _scan(vs, pts, max_count, scan)
        best = min(best, time.perf_counter() - t)
    return out, 1e6 * best / len(pts)


def main():
    from pbl_point_cost import point_args, points_in_sphere, scene_samples

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    point_args(ap, 5000)
    ap.add_argument("--node-sizes", default="8,16,32,64")
    args = ap.parse_args()
    path, _, _, sample_set = scene_samples(args.scene, args.cache)
    vs = sample_set.kernel
    pts, _ = points_in_sphere(args.points, args.radius, np.random.default_rng(3))
    leaves = int((vs.tree[6] < 0).sum())
    print(f"{path.stem}: {len(vs.len)} volume samples in {leaves} leaves, {args.points} points, one thread")
    for size in (int(s) for s in args.node_sizes.split(",")):
        _, walk_us = _timed(vs, pts, size, False)
        out, scan_us = _timed(vs, pts, size, True)
        nodes, scanned, extent, hits = out.mean(axis=0)
        print(f"  nodes of <= {size:3d}: {nodes:6.1f} visited, {scanned:7.1f} scanned, {extent:7.1f} within the "
              f"extent, {hits:5.1f} hits; walk {walk_us:5.1f} µs, walk + scan {scan_us:5.1f} µs a point")
    cell = np.floor(pts / 0.3)
    order = np.lexsort((cell[:, 2], cell[:, 1], cell[:, 0]))
    _, sorted_us = _timed(vs, np.ascontiguousarray(pts[order]), 8, True)
    print(f"  points sorted in 0.3-unit cells: walk + scan {sorted_us:5.1f} µs a point")


if __name__ == "__main__":
    main()
