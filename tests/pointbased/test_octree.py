"""The octree's node records: boxes, and the light cut's lobes."""

import numpy as np

from pbvol_cli.pointbased.octree import (LOBE_ALIGN, LOBE_EXT2, LOBE_HI, LOBE_LO, LOBE_POWER, build_octree,
                                         node_lobes)


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
