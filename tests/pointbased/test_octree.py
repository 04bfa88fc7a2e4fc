"""The octree's node records: boxes, and the light cut's lobes."""

import numpy as np

from pbvol_cli.pointbased.octree import (LOBE_ALIGN, LOBE_CENTRE, LOBE_EXT2, LOBE_HI, LOBE_LO, LOBE_POWER,
                                         LOBE_SPREAD2, build_octree, node_lobes)


def test_node_lobes_take_the_extent_of_the_boxes_given():
    """Each node's box (its corners and squared half-diagonal) is the box around its samples' boxes: the octree's
    own (single scattering's kernel boxes) by default, the samples' boxes passed to node_lobes otherwise (their own
    extent, narrower); the other columns do not depend on them."""
    rng = np.random.default_rng(3)
    n = 200
    centre = rng.uniform(-1.0, 1.0, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    power = rng.uniform(0.5, 1.0, (n, 3))
    own = rng.uniform(0.01, 0.05, (n, 1))
    tree = build_octree(centre, centre - 10 * own, centre + 10 * own, d, power)
    wide, narrow = node_lobes(tree.arrays()), node_lobes(tree.arrays(), centre - own, centre + own)
    for nd in range(len(tree.start)):
        members = tree.order[tree.start[nd]:tree.end[nd]]
        for lobes, half in ((wide, 10 * own), (narrow, own)):
            lo, hi = (centre[members] - half[members]).min(0), (centre[members] + half[members]).max(0)
            assert np.isclose(lobes[nd, LOBE_EXT2], 0.25 * np.sum((hi - lo) ** 2), rtol=1e-12)
            np.testing.assert_array_equal(lobes[nd, LOBE_LO:LOBE_LO + 3], lo)
            np.testing.assert_array_equal(lobes[nd, LOBE_HI:LOBE_HI + 3], hi)
    assert np.all(narrow[:, LOBE_EXT2] < wide[:, LOBE_EXT2])
    cols = [c for c in range(wide.shape[1]) if c != LOBE_EXT2 and not LOBE_LO <= c < LOBE_HI + 3]
    np.testing.assert_array_equal(wide[:, cols], narrow[:, cols])
    assert np.isclose(narrow[0, LOBE_POWER], power.sum())
    assert np.all((narrow[:, LOBE_ALIGN] >= 0) & (narrow[:, LOBE_ALIGN] <= 1))


def test_node_spread_is_the_power_weighted_mean_square_distance_along_the_segments():
    """A node's spread (LOBE_SPREAD2) is the power-weighted mean, over the points along its samples' segments, of
    the squared distance from its centroid: |c - centroid|^2 + length^2 / 12 per segment (a uniform point along a
    segment of that length), summed about the centroid directly. Left 0 without the segments."""
    rng = np.random.default_rng(8)
    n = 300
    centre = 100.0 + rng.uniform(-1.0, 1.0, (n, 3))  # far from the origin: a one-pass E[x^2] - E[x]^2 would cancel
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    power = rng.uniform(0.1, 1.0, (n, 3))
    length = rng.uniform(0.0, 2.0, n)
    tree = build_octree(centre, centre - 0.01, centre + 0.01, d, power)
    lobes = node_lobes(tree.arrays(), segments=(centre, length, power))
    w = power.sum(1)
    leaves = 0
    for nd in range(len(tree.start)):
        members = tree.order[tree.start[nd]:tree.end[nd]]
        c = lobes[nd, LOBE_CENTRE:LOBE_CENTRE + 3]
        expect = np.sum(w[members] * (np.sum((centre[members] - c) ** 2, 1) + length[members] ** 2 / 12))
        assert np.isclose(lobes[nd, LOBE_SPREAD2], expect / w[members].sum(), rtol=1e-9)
        leaves += tree.first_child[nd] < 0
    assert leaves > 8 and lobes[0, LOBE_SPREAD2] > 0.5  # a tree of several levels, and a spread of about 1
    assert np.all(node_lobes(tree.arrays())[:, LOBE_SPREAD2] == 0.0)
