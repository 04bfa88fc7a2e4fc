"""The gather along ray segments in a medium: the segments' boundary planes, the order rays are evaluated in, single
scattering deferred to a batch's end."""

import numpy as np
import pytest

import pbvol_cli.pointbased.single_scattering as single_module
from conftest import random_volume_samples
from pbvol_cli.physics.sampling import rand
from pbvol_cli.pointbased.gather import (LAYER_DOUBLE, LAYER_SINGLE, DeferredSingle, GatherSettings, eval_segments,
                                         morton_order, segment_planes, spatial_order)
from pbvol_cli.pointbased.volume_samples import Medium


def test_segment_planes_face_out_of_the_segment_on_either_side():
    """A camera segment's end planes, from the surfaces' normals whichever way they point: the start plane's
    normal faces back along the ray and the end plane's forward, both through the segment's end points; a ray
    from the camera (NaN normal) or one that leaves the scene (t = inf) has no plane there (q = inf)."""
    pos = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 0.5], [0.0, 0.0, 0.0]])
    d = np.array([[0.0, 0.0, -1.0], [0.6, 0.0, 0.8], [1.0, 0.0, 0.0]])
    t = np.array([2.0, 1.0, np.inf])
    n_start = np.array([[0.0, 0.0, 1.0], [-0.6, 0.0, -0.8], [np.nan, np.nan, np.nan]])
    n_end = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    pl = segment_planes(pos, d, t, n_start, n_end)
    assert pl[0].tolist() == [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0, 2.0]  # out of the slab -2 < z < 0 both ways
    assert pl[1, :3].tolist() == [-0.6, 0.0, -0.8] and pl[1, 3] == pytest.approx(-0.6 - 0.4)
    assert pl[1, 4:7].tolist() == [0.0, 0.0, 1.0] and pl[1, 7] == pytest.approx(0.5 + 0.8)
    for row, p0, p1 in ((0, pos[0], pos[0] + 2 * d[0]), (1, pos[1], pos[1] + d[1])):  # inside: n . x <= q
        assert pl[row, :3] @ (p0 + 0.5 * (p1 - p0)) < pl[row, 3] and pl[row, 4:7] @ (p0 + 0.5 * (p1 - p0)) < pl[row, 7]
    assert pl[2, 3] == np.inf and pl[2, 7] == np.inf


def test_spatial_order_is_a_permutation_that_keeps_neighbours_together():
    """Rays are evaluated along a Morton curve through their segments' midpoints: every ray once, and the midpoints
    of consecutive rays much closer than in the given (random) order; an infinite segment (a ray that leaves) counts
    from its start."""
    rng = np.random.default_rng(5)
    n = 4000
    pos, dirs = rng.uniform(-5.0, 5.0, (n, 3)), rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    t = rng.uniform(0.0, 2.0, n)
    t[::50] = np.inf
    idx = rng.permutation(n)[: n // 2]
    out = spatial_order(idx, pos, dirs, t)
    assert sorted(out.tolist()) == sorted(idx.tolist())
    mid = pos + np.where(np.isfinite(t), t, 0.0)[:, None] * dirs * 0.5

    def mean_step(order):
        return np.linalg.norm(np.diff(mid[order], axis=0), axis=1).mean()

    assert mean_step(out) < 0.25 * mean_step(idx)
    assert spatial_order(idx[:1], pos, dirs, t).tolist() == idx[:1].tolist()


@pytest.mark.parametrize("grid_from", [0.0, np.inf])
def test_deferred_single_scattering_adds_what_the_segments_would(monkeypatch, grid_from):
    """Single scattering drawn segment by segment in two path depths (DeferredSingle.add; kmax_diffuse points
    after a diffuse bounce) and evaluated at the batch's end, sample by sample (grid_from 0) or point by point
    (inf), against each segment's own evaluation (gather._segment): the same points (each segment's random number
    drawn as there) and sums per pixel, two segments sharing a pixel."""
    monkeypatch.setattr(single_module, "POINTS_PER_SAMPLE_FOR_GRID", grid_from)
    rng = np.random.default_rng(9)
    vs = random_volume_samples(rng, 2000)
    med = Medium(np.array([0.2, 0.5, 1.0]), np.array([1.0, 0.8, 0.5]), 1, 0.7)
    n = 600
    pos, dirs = rng.uniform(-2.0, 2.0, (n, 3)), rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    tseg, beta = rng.uniform(0.2, 3.0, n), rng.uniform(0.1, 1.0, (n, 3))
    planes = segment_planes(pos, dirs, tseg, None, None)
    streams = rng.integers(1, 2 ** 62, n).astype(np.uint64)
    # single with double scattering: every segment point by point (_segment), its single scattering at the kmax
    # points of the segment's first random number, kmax_diffuse after a diffuse bounce (every third segment)
    settings = GatherSettings(2, 8, 0.02, True, True, False, 1, 3, 8)
    each = np.zeros((n, 4, 3))
    diffuse = (np.arange(n) % 3 == 0).astype(np.int64)
    eval_segments(None, 1, np.arange(n), pos, dirs, beta, tseg, streams.copy(), med, vs, settings, each, diffuse,
                  planes)
    pixel = np.arange(n) // 2
    deferred, layer, rng_d = DeferredSingle(), np.zeros((n // 2, 3)), streams.copy()
    for depth in (np.arange(0, n, 2), np.arange(1, n, 2)):
        after = diffuse[depth] > 0
        deferred.add(0, vs, med, depth[after], pos, dirs, beta, tseg, rng_d, settings.kmax_diffuse, planes, pixel)
        deferred.add(0, vs, med, depth[~after], pos, dirs, beta, tseg, rng_d, settings.kmax, planes, pixel)
    deferred.flush(None, 1, layer, n // 2)
    expected = np.zeros((n // 2, 3))
    np.add.at(expected, pixel, each[:, LAYER_SINGLE])
    assert (expected[:, 0] > 0).mean() > 0.5
    np.testing.assert_allclose(layer, expected, rtol=1e-12, atol=0.0)
    once = streams.copy()
    for i in range(n):
        rand(once, i)
    assert np.array_equal(rng_d, once)  # one random number a segment, as _segment draws


def test_morton_order_puts_points_at_infinity_in_its_first_cell_without_warnings():
    """A point at infinity or NaN (an unbounded segment's) does not spoil the others' order, nor warn."""
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(200, 3))
    others = np.delete(np.arange(200), [3, 50])
    with np.errstate(all="raise"):
        plain = others[morton_order(pts[others])]
        bad = pts.copy()
        bad[[3, 50]] = [np.inf, 0.0, 0.0], [np.nan, 1.0, 1.0]
        order = morton_order(bad)
    assert set(order[:2].tolist()) == {3, 50}
    assert order[2:].tolist() == plain.tolist()


def test_a_coarser_light_cut_after_a_diffuse_bounce_keeps_the_mean_and_only_there():
    """cut_size_diffuse sets the light cut's refinements at the points after a diffuse bounce: with none (the
    octree's root alone) and with 8, eight segments evaluated 600 times each (their own random streams) read the same
    mean double scattering within 4 standard errors, the coarser cut noisier; a segment that did not bounce off a
    diffuse surface reads the same bit for bit whatever cut_size_diffuse."""
    rng = np.random.default_rng(4)
    vs = random_volume_samples(rng, 2000)
    med = Medium(np.array([0.2, 0.5, 1.0]), np.array([1.0, 0.8, 0.5]), 1, 0.7)
    segments, copies = 8, 600
    pos, dirs = rng.uniform(-1.5, 1.5, (segments, 3)), rng.normal(size=(segments, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    pos, dirs = np.repeat(pos, copies, 0), np.repeat(dirs, copies, 0)
    n = segments * copies
    tseg, beta = np.full(n, 1.5), np.ones((n, 3))
    planes = segment_planes(pos, dirs, tseg, None, None)
    streams = rng.integers(1, 2 ** 62, n).astype(np.uint64)

    def double(cut, diffuse):
        out = np.zeros((n, 4, 3))
        settings = GatherSettings(2, 8, 0.02, False, True, False, 1, 1, cut)
        eval_segments(None, 1, np.arange(n), pos, dirs, beta, tseg, streams.copy(), med, vs, settings, out,
                      np.full(n, diffuse, np.int64), planes)
        return out[:, LAYER_DOUBLE].reshape(segments, copies, 3)

    coarse, fine = double(0, 1), double(8, 1)
    se = np.hypot(coarse.std(1, ddof=1), fine.std(1, ddof=1)) / np.sqrt(copies)
    assert np.all(fine.mean(1) > 0) and np.all(se > 0)
    assert np.all(np.abs(coarse.mean(1) - fine.mean(1)) < 4 * se), (coarse.mean(1), fine.mean(1), se)
    assert coarse.std(1).mean() > 1.2 * fine.std(1).mean()
    assert np.array_equal(double(0, 0), double(8, 0))
