"""The smooth terms shared within bins (pointbased/radiance_cache.py): bins as specified, fewer evaluations, and
the image the per-point evaluation gives, within its noise."""

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from conftest import SPHERE_SIGMA_A, SPHERE_SIGMA_S, build, camera, medium_sphere_scene, smooth_layers
from pbvol_cli.config import PblSettings
from pbvol_cli.geometry.raycast import TriangleCaster
from pbvol_cli.multiple_scattering.table import empty_table
from pbvol_cli.pointbased.bounced import BOUNCED_KERNEL, bounced_samples
from pbvol_cli.physics.sampling import MFP_PER_POINT, points_on_segment
from pbvol_cli.pointbased.gather import GatherSettings, eval_segments, segment_planes
from pbvol_cli.pointbased.light_samples import place_light_samples
from pbvol_cli.pointbased.radiance_cache import (TERM_SHARE_MIN, CacheSettings, TermShares, bin_groups, bin_keys,
                                                 cache_settings, extra_evaluations, lateral_width, representatives,
                                                 scattered_points, shared_terms, thread_parts)
from pbvol_cli.pointbased.volume_samples import Medium, SampleSet


def test_bin_keys_split_space_into_cells_and_directions_into_cube_map_bins():
    rng = np.random.default_rng(1)
    pos = rng.random((4000, 3)) * 10.0
    d = rng.normal(size=(4000, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    depth = rng.random(4000) * 5.0
    keys = bin_keys(pos, d, depth, 1.0, 1.0, 4, np.random.default_rng(7))
    # a cell is one unit wide: points in one bin lie within a unit cube, and there are about 10^3 cells
    for key in np.unique(keys[:, :3], axis=0)[:50]:
        members = pos[(keys[:, :3] == key).all(axis=1)]
        assert np.all(members.max(0) - members.min(0) < 1.0)
    assert 700 < len(np.unique(keys[:, :3], axis=0)) <= 1331
    # 6 faces x 4 x 4 direction bins, each a compact cone (cube-map bins of a turned cube)
    assert len(np.unique(keys[:, 4])) == 96
    for b in range(96):
        members = d[keys[:, 4] == b]
        mean = members.mean(0) / np.linalg.norm(members.mean(0))
        assert np.min(members @ mean) > math.cos(math.radians(40))
    # cubes as wide as deep are not sliced by depth; wider ones are, in slices of one cell
    assert np.all(keys[:, 3] == 0)
    sliced = bin_keys(pos, d, depth, 4.0, 1.0, 4, np.random.default_rng(7))
    for key in np.unique(sliced[:, :4], axis=0)[:50]:
        members = depth[(sliced[:, :4] == key).all(axis=1)]
        assert members.max() - members.min() < 1.0
    # the grid's shift and turn come from the generator: the same seed, the same bins
    assert np.array_equal(keys, bin_keys(pos, d, depth, 1.0, 1.0, 4, np.random.default_rng(7)))
    assert not np.array_equal(keys, bin_keys(pos, d, depth, 1.0, 1.0, 4, np.random.default_rng(8)))


def test_bin_groups_number_the_bins_as_unique_rows_do():
    rng = np.random.default_rng(3)
    keys = np.column_stack([rng.integers(-5, 30, 5000), rng.integers(0, 3, 5000), rng.integers(-3, 4, 5000),
                            rng.integers(0, 40, 5000), rng.integers(0, 384, 5000)]).astype(np.int64)
    keys[::7, 3] = 10 ** 9  # a point without a boundary plane: its depth slab far away
    expected = np.unique(keys, axis=0, return_inverse=True)[1].ravel()
    assert np.array_equal(bin_groups(keys), expected)
    wide = keys.copy()
    wide[::5, 0] = 2 ** 40  # ranges too wide for one 62-bit integer: the rows themselves
    assert np.array_equal(bin_groups(wide), np.unique(wide, axis=0, return_inverse=True)[1].ravel())
    assert len(bin_groups(keys[:0])) == 0


def test_points_on_a_segment_follow_its_optical_length_up_to_kmax():
    """A point per MFP_PER_POINT mean free paths of the least dense channel, at least one, at most kmax (an
    unbounded segment and a medium without extinction included)."""
    s = 2.0 / MFP_PER_POINT
    counts = [points_on_segment(4, s, d) for d in (0.0, 0.1, 0.5, 0.5001, 1.0, 1.2, 1.9, 2.1, 50.0, math.inf)]
    assert counts == [1, 1, 1, 2, 2, 3, 4, 4, 4, 4]
    assert points_on_segment(4, 0.0, 10.0) == 1 and points_on_segment(1, s, 50.0) == 1
    assert points_on_segment(8, s, 1.9) == 4


def test_points_per_mean_free_path_keep_each_segments_transmittance_integral():
    """Segments of 0.3 to 12 mean free paths take 1 to 4 points (per_mfp) or always 4; either way each segment's
    points are owned by it and their weights (throughput x transmittance / (pdf x points)) sum, over the random
    offset of the stratification, to the integral of the transmittance along it, per channel (the channels'
    extinctions differ from the one the depths are drawn with)."""
    med = Medium(np.array([0.1, 0.3, 0.05]), np.array([0.9, 1.2, 0.6]), 0, 0.0)  # least dense channel 0.65
    s = 0.65
    tseg = np.array([0.3, 2.0, 4.0, 12.0]) / s
    n, draws = len(tseg), 4000
    pos, dirs = np.zeros((n, 3)), np.tile([0.0, 0.0, 1.0], (n, 1))
    beta = np.array([[1.0, 0.5, 2.0]] * n)
    planes = segment_planes(pos, dirs, tseg, None, None)
    st = med.sigma_a + med.sigma_s
    exact = beta * (-np.expm1(-np.outer(tseg, st))) / st
    for per_mfp, expected in ((True, [1, 2, 4, 4]), (False, [4, 4, 4, 4])):
        total = np.zeros((n, 3))
        rng = np.arange(1, n + 1, dtype=np.uint64) * np.uint64(7919)
        for _ in range(draws):
            pts = scattered_points(np.arange(n), pos, dirs, beta, tseg, rng, med, 4, planes, per_mfp=per_mfp)
            assert np.bincount(pts.owner, minlength=n).tolist() == expected
            assert np.all((pts.pos[:, 2] >= 0.0) & (pts.pos[:, 2] <= tseg[pts.owner] + 1e-12))
            for c in range(3):
                total[:, c] += np.bincount(pts.owner, weights=pts.weight[:, c], minlength=n)
        np.testing.assert_allclose(total / draws, exact, rtol=0.01)


def test_representatives_are_drawn_in_proportion_to_the_weights():
    group = np.array([0, 0, 0, 1, 1, 2])
    weight = np.array([1.0, 3.0, 0.0, 0.0, 0.0, 2.0])
    picks = np.array([representatives(group, weight, np.random.default_rng(s)) for s in range(4000)])
    assert np.all(picks[:, 1] == 3) and np.all(picks[:, 2] == 5)  # a bin of zero weight: its first point
    share = (picks[:, 0] == 1).mean()
    assert abs(share - 0.75) < 4 * math.sqrt(0.75 * 0.25 / 4000) and not np.any(picks[:, 0] == 2)


def test_representatives_of_repeated_bins_are_drawn_by_weight_within_each():
    group = np.array([0, 0, 0, 1, 1, 2])
    weight = np.array([1.0, 3.0, 0.0, 0.0, 0.0, 2.0])
    bins = np.array([0, 0, 2, 0])
    picks = np.array([representatives(group, weight, np.random.default_rng(s), bins) for s in range(4000)])
    assert np.all(picks[:, 2] == 5) and np.all(np.isin(picks[:, [0, 1, 3]], [0, 1]))
    for j in (0, 1, 3):  # each draw its own, in proportion to the weights
        assert abs((picks[:, j] == 1).mean() - 0.75) < 4 * math.sqrt(0.75 * 0.25 / 4000)
    assert 0.1 < (picks[:, 0] != picks[:, 1]).mean() < 0.9


def test_extra_evaluations_follow_the_square_root_of_each_bins_share_of_the_image():
    """Bin b's share S_b sums over pixels its points' weight in the pixel, squared, times the pixel's factor: two
    points of one bin in one pixel count together. The extra evaluations, splits x the bins in all, go as
    sqrt(S_b), fractions rounded at random (their mean exact); none with splits 0."""
    group = np.array([0, 0, 1, 1, 2, 3])
    pixel = np.array([0, 0, 1, 2, 3, 3])
    weight = np.array([1.0, 1.0, 2.0, 2.0, 0.5, 0.0])
    factor = np.array([1.0, 1.0, 0.5, 4.0])
    s = np.array([4.0, 4.0 * 1.0 + 4.0 * 0.5, 0.25 * 4.0, 0.0])  # (1 + 1)^2 x 1; 2^2 x 1 + 2^2 x 0.5; ...
    expected = 2.0 * 4 * np.sqrt(s) / np.sqrt(s).sum()
    draws = np.array([extra_evaluations(group, pixel, weight, factor, 2.0, np.random.default_rng(k))
                      for k in range(4000)])
    assert np.all(draws >= np.floor(expected)) and np.all(draws <= np.ceil(expected))
    np.testing.assert_allclose(draws.mean(0), expected, atol=0.03)
    assert np.all(extra_evaluations(group, pixel, weight, factor, 0.0, np.random.default_rng(1)) == 0)


def test_extra_evaluations_keep_every_smooth_layers_mean_in_a_render(tmp_path, monkeypatch):
    """The test sphere behind a dielectric boundary with its bins evaluated once each and with two extra
    evaluations a bin (bin_splits 2, where the pixels' weights ask), six seeds each: the double, multiple and
    bounced layers' means agree within 4 standard errors, and bins were evaluated more than once."""
    import pbvol_cli.pointbased.radiance_cache as radiance_cache

    scene = medium_sphere_scene(surface_samples=800, segments_per_beam=4, bounce_samples=64)
    scene["camera"] = camera((16, 16), position=(0, 0, 3.5), fov=40)
    scene["shapes"][0].update(interface="dielectric", eta=1.33)
    extras = []
    extra = radiance_cache.extra_evaluations
    monkeypatch.setattr(radiance_cache, "extra_evaluations",
                        lambda *a: extras.append(extra(*a)) or extras[-1])
    runs = {}
    for splits in (0.0, 2.0):
        scene["render"]["pbl"]["bin_splits"] = splits
        runs[splits] = smooth_layers(tmp_path, scene, range(6))
    assert extras and all(e.sum() > 0 for e in extras) and max(e.max() for e in extras) > 2
    for j, name in enumerate(("double", "multiple", "bounced")):
        ma, mb = runs[0.0][:, j].mean((1, 2, 3)), runs[2.0][:, j].mean((1, 2, 3))
        se = math.hypot(ma.std(ddof=1), mb.std(ddof=1)) / math.sqrt(len(ma))
        print(name, ma.mean(), mb.mean(), se)
        assert ma.mean() > 0 and abs(ma.mean() - mb.mean()) < 4 * se, (name, ma.mean(), mb.mean(), se)


def test_thread_parts_share_the_work_when_every_segment_index_is_odd():
    # the camera's rays in a medium are often transmitted children, every second slot: odd indices only
    owner = np.array([7, 3, 3, 11, 5, 9, 7, 1, 13, 15, 3, 17])
    parts = thread_parts(owner, 2)
    assert sorted(np.concatenate(parts).tolist()) == list(range(len(owner)))  # each representative once
    for p in parts:
        assert np.all(np.diff(p) > 0)  # in the representatives' order
    owners = [set(owner[p].tolist()) for p in parts]
    assert not owners[0] & owners[1]  # a segment's representatives (its random state) on one thread
    assert [len(o) for o in owners] == [5, 4]  # nine segments dealt alternately
    assert len(thread_parts(owner, 1)[0]) == len(owner)


def _double_along_chords(sample_set, cell, lateral, runs, pool, toward=1.0):
    """Double scattering toward toward x z (+1 or -1) along 1184 chords of the test sphere (parallel rays, as a
    camera's), the mean of `runs` independent estimates per chord and their variance: the terms shared in bins of
    `cell` mean free paths deep and `lateral` wide (0: each point its own). Returns (mean, variance of the mean,
    evaluations per run)."""
    cache = CacheSettings(cell, lateral, 8, False) if cell > 0 else None
    return _terms_along_chords(sample_set, cache, runs, pool, toward,
                               GatherSettings(1, 8, 0.02, False, True, False, 1, 1, 8))


def _terms_along_chords(sample_set, cache, runs, pool, toward, settings):
    """The terms of settings (GatherSettings), summed, toward toward x z along 1184 chords of the test sphere, as
    _double_along_chords: shared in the bins of cache (CacheSettings; None: each point its own)."""
    g = np.linspace(-0.85, 0.85, 40)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    inside = x * x + y * y < 0.85**2
    x, y = x[inside], y[inside]
    z = np.sqrt(1.0 - x * x - y * y)
    pos = np.column_stack([x, y, -toward * z])  # from the far side of the sphere toward a camera at toward x z
    dirs = np.tile([0.0, 0.0, toward], (len(x), 1))
    t = 2.0 * z
    planes = segment_planes(pos, dirs, t, pos, pos + t[:, None] * dirs)
    n = len(x)
    est, evaluations = [], []
    salt = 0 if cache is None else int(cache.cell * 1e9)
    for r in range(runs):
        # random states of their own per run and per bin size: the two means' noise independent
        rng = np.arange(n, dtype=np.uint64) * np.uint64(7919) + np.uint64(1000003 * (r + 1) + salt)
        out = np.zeros((n, 3, 3))
        if cache is not None:
            evaluations.append(shared_terms(pool, 2, np.arange(n), pos, dirs, np.ones((n, 3)), t, rng,
                                            sample_set.medium, sample_set.kernel, settings, cache, out, planes,
                                            np.random.default_rng([5, r])))
        else:
            evaluations.append(n)
            eval_segments(pool, 2, np.arange(n), pos, dirs, np.ones((n, 3)), t, rng, sample_set.medium,
                          sample_set.kernel, settings, out, np.zeros(n, np.int64), planes)
        est.append(out.sum(axis=1))
    est = np.array(est)
    return est.mean(0), est.var(0, ddof=1) / runs, float(np.mean(evaluations))


def test_the_blur_of_shared_bins_stays_below_the_noise_and_a_coarse_bin_is_caught(tmp_path):
    """The error control: double scattering along 1600 parallel chords of the test sphere (under its directional
    light), 48 runs each, per point and shared. At the default 0.5 mean free paths the per-chord difference from the
    per-point mean is what the two means' noise predicts (measured 1.03; bound 1.5) with under a third of the
    evaluations; bins of 4 mean free paths (nearly the whole sphere) blur the light's gradient and the same measure
    catches it (measured 5.3; bound 3; 1 and 2 mean free paths read 1.33 and 2.32)."""
    bs = build(tmp_path, medium_sphere_scene())
    tabs = [empty_table().render_args()] * 3
    sample_set = SampleSet(place_light_samples(bs, 4000, 8, 4, 8, 1), 0, bs.media, tabs, 2.0)
    with ThreadPoolExecutor(2) as pool:
        base, base_var, _ = _double_along_chords(sample_set, 0.0, 0.0, 48, pool)
        ratios = {}
        for cell, lateral in ((0.5, 0.5), (4.0, 4.0)):
            mean, var, evaluations = _double_along_chords(sample_set, cell, lateral, 48, pool)
            lit = base > 0.05 * base.max()
            ratios[cell, lateral] = float(((mean - base) ** 2)[lit].mean() / (var + base_var)[lit].mean())
            print(cell, lateral, "evaluations", evaluations, "of", len(base), "difference^2 / noise",
                  ratios[cell, lateral])
            if cell == 0.5:
                assert evaluations < len(base) / 3
    assert ratios[0.5, 0.5] < 1.5 and ratios[4.0, 4.0] > 3.0, ratios


@pytest.mark.slow  # (a long validation: the default run keeps a faster sibling)
def test_bins_two_mean_free_paths_wide_on_a_body_sixteen_across_stay_below_the_noise(tmp_path):
    """The default width along the boundary, 2 mean free paths, is bounded by an eighth of the medium's size
    (lateral_width): on the test sphere (4 mean free paths across) it stays about a cell, on the same sphere with a
    medium 4x denser (17 across) it is 2 mean free paths, and there the double scattering along 1184 chords seen
    from the lit side, 48 runs each, shared against per point, differs by what the noise predicts (bound 1.5, as
    above) with fewer evaluations than bins of half a mean free path."""
    scene = medium_sphere_scene()
    medium = scene["shapes"][0]["medium"]
    small = build(tmp_path, scene)
    medium.update(sigma_a=(4 * SPHERE_SIGMA_A).tolist(), sigma_s=(4 * SPHERE_SIGMA_S).tolist())
    bs = build(tmp_path, scene)
    tabs = [empty_table().render_args()] * 3
    mfp = 1.0 / float(np.max(4 * (SPHERE_SIGMA_A + SPHERE_SIGMA_S)))
    wide = CacheSettings(0.5, 2.0, 8, False)
    small_set = SampleSet(place_light_samples(small, 500, 8, 4, 8, 1), 0, small.media, tabs, 2.0)
    assert lateral_width(wide, 4 * mfp, small_set.kernel) < 0.55 * 4 * mfp  # an eighth of 2: about a cell
    sample_set = SampleSet(place_light_samples(bs, 4000, 8, 4, 8, 1), 0, bs.media, tabs, 2.0)
    assert lateral_width(wide, mfp, sample_set.kernel) == 2.0 * mfp
    with ThreadPoolExecutor(2) as pool:
        base, base_var, _ = _double_along_chords(sample_set, 0.0, 0.0, 48, pool, toward=-1.0)
        mean, var, evaluations = _double_along_chords(sample_set, 0.5, 2.0, 48, pool, toward=-1.0)
        _, _, narrow = _double_along_chords(sample_set, 0.5, 0.5, 2, pool, toward=-1.0)
    lit = base > 0.05 * base.max()
    ratio = float(((mean - base) ** 2)[lit].mean() / (var + base_var)[lit].mean())
    print("evaluations", evaluations, "(half a mean free path wide:", narrow, ") of", len(base),
          "difference^2 / noise", ratio)
    assert ratio < 1.5 and evaluations < narrow


@pytest.mark.slow  # (a long validation: the default run keeps a faster sibling)
def test_the_bounced_lights_coarser_bins_blur_it_by_a_bounded_share(tmp_path):
    """bounced_bins (the bounced light's bins that many times the lights' in depth, width and direction:
    cache_settings(..., single=True)) on the test sphere made 4x denser (17 mean free paths across) behind eta 1.5:
    the bounced light's three terms along 1184 chords seen from the lit side, 32 runs each, shared against per
    point. The blur's mean square over the light's ((mean - per point)^2 less the two means' noise, over the
    per-point mean^2) reads 0.026 +- 0.007 at 2 with 0.71 of the lights' bins' evaluations (0.008 +- 0.004 at 1,
    the lights' bins) and 0.051 +- 0.006 at 8 (a few bins over the whole sphere), which the bound catches: a blur
    worth taking only where the bounced light is a small share of the image (the oil sphere's config)."""
    scene = medium_sphere_scene()
    shape = scene["shapes"][0]
    shape.update(interface="dielectric", eta=1.5)
    shape["medium"].update(sigma_a=(4 * SPHERE_SIGMA_A).tolist(), sigma_s=(4 * SPHERE_SIGMA_S).tolist())
    bs = build(tmp_path, scene)
    tabs = [empty_table().render_args()] * 3
    lit = SampleSet(place_light_samples(bs, 2000, 8, 4, 8, 1), 0, bs.media, tabs, 2.0)
    gather = GatherSettings(1, 8, 0.02, True, True, True, 1, 1, 8)
    caster = TriangleCaster(bs.vertices, bs.faces, 2)
    with ThreadPoolExecutor(2) as pool:
        try:
            back = bounced_samples(bs, caster, pool, 2, 0, lit, lambda smp: SampleSet(smp, 0, bs.media, tabs, 2.0),
                                   1000, 2, 2, 8, gather, 1)
        finally:
            caster.close()
        bounced = SampleSet(back, 0, bs.media, tabs, BOUNCED_KERNEL)
        base, base_var, _ = _terms_along_chords(bounced, None, 32, pool, -1.0, gather)
        lit_chords = base > 0.05 * base.max()
        blur, evaluations = {}, {}
        for f in (2, 8):
            cache = cache_settings(PblSettings(bounced_bins=f), single=True)
            mean, var, evaluations[f] = _terms_along_chords(bounced, cache, 32, pool, -1.0, gather)
            blur[f] = float(((mean - base) ** 2 - var - base_var)[lit_chords].mean() / (base**2)[lit_chords].mean())
    print("evaluations", evaluations, "of", len(base), "blur^2 / light^2", blur)
    assert blur[2] < 0.038 < blur[8] and evaluations[2] < 0.5 * len(base), (blur, evaluations)


def test_shared_terms_keep_every_smooth_layers_mean_in_a_render(tmp_path):
    """End to end (the lights' and the bounced samples, through the camera pass): the test sphere behind a
    dielectric boundary rendered with the terms shared (the bounced light's bins twice as coarse: bounced_bins 2)
    and per point, six seeds each: the double, multiple and bounced layers' means agree within 4 standard errors of
    the seed-to-seed spread."""
    scene = medium_sphere_scene(surface_samples=800, segments_per_beam=4, bounce_samples=64)
    scene["camera"] = camera((16, 16), position=(0, 0, 3.5), fov=40)
    scene["shapes"][0].update(interface="dielectric", eta=1.33)  # a boundary that reflects: a bounced layer
    runs = {}
    for cell in (0.0, 0.5):
        scene["render"]["pbl"].update(cache_cell=cell, bounced_bins=2.0)
        runs[cell] = smooth_layers(tmp_path, scene, range(6))
    for j, name in enumerate(("double", "multiple", "bounced")):
        ma, mb = runs[0.0][:, j].mean((1, 2, 3)), runs[0.5][:, j].mean((1, 2, 3))
        se = math.hypot(ma.std(ddof=1), mb.std(ddof=1)) / math.sqrt(len(ma))
        print(name, ma.mean(), mb.mean(), se)
        assert ma.mean() > 0 and abs(ma.mean() - mb.mean()) < 4 * se, (name, ma.mean(), mb.mean(), se)


def test_term_shares_follow_the_square_root_of_the_second_moments():
    """The term of the larger second moment is always evaluated, the other at the square root of their ratio, at
    least TERM_SHARE_MIN; a bin kept at share q adds (Y / q)^2 q, whose expectation is Y^2."""
    ts = TermShares()
    assert not ts.measured() and ts.shares() == (1.0, 1.0)
    values, w = np.zeros((2, 3, 3)), np.ones((2, 3))
    values[0, 1] = [2.0, 0.0, 0.0]  # double: Y = 2, then 0
    values[:, 2] = [[0.5, 0.5, 0.0], [0.0, 0.0, 0.0]]  # multiple: Y = 1, then 0
    ts.add(values, w)
    assert ts.measured() and ts.shares() == (1.0, 0.5)
    ts.add(values * np.array([1.0, 1.0, 1.0 / 0.5])[None, :, None], w, (1.0, 0.5))  # the same bins kept at q_m = 1/2
    assert np.allclose(ts.second_moment, [8.0, 3.0]) and ts.shares() == (1.0, math.sqrt(3.0 / 8.0))
    ts.second_moment[:] = [1.0, 1e-4]
    assert ts.shares() == (1.0, TERM_SHARE_MIN)


def test_term_shares_keep_every_smooth_layers_mean_in_a_render(tmp_path, monkeypatch):
    """The test sphere on a diffuse floor, its bins and the points after a bounce off the floor evaluating the
    lesser term at a share (term_shares) against every bin and point both, six seeds each: the double, multiple
    and bounced layers' means agree within 4 standard errors, and the shares did fall below 1 on both."""
    import pbvol_cli.pointbased.gather as gather

    scene = medium_sphere_scene(surface_samples=800, segments_per_beam=4, bounce_samples=64)
    scene["camera"] = {**camera((16, 16), position=(0, 2.0, 3.0), fov=50), "look_at": [0.0, -0.4, 0.0]}
    scene["shapes"][0].update(interface="dielectric", eta=1.33)
    scene["shapes"].append({"type": "quad", "center": [0.0, -1.0, 0.0], "size": [6.0, 6.0], "interface": "diffuse",
                            "albedo": 0.8})
    seen, bounced_off = [], []
    shares = TermShares.shares
    monkeypatch.setattr(TermShares, "shares", lambda self: seen.append(shares(self)) or seen[-1])
    after = gather._after_diffuse

    def record(pool, threads, idx, *rest):  # (rest[-3]: the TermShares)
        if rest[-3] is not None and len(idx) and min(shares(rest[-3])) < 1.0:
            bounced_off.append(len(idx))
        return after(pool, threads, idx, *rest)

    monkeypatch.setattr(gather, "_after_diffuse", record)
    runs = {}
    for on in (False, True):
        scene["render"]["pbl"]["term_shares"] = on
        runs[on] = smooth_layers(tmp_path, scene, range(6))
    assert seen and min(min(q) for q in seen) < 0.9, seen
    assert sum(bounced_off) > 0  # points after the floor's bounce took the shares
    for j, name in enumerate(("double", "multiple", "bounced")):
        ma, mb = runs[False][:, j].mean((1, 2, 3)), runs[True][:, j].mean((1, 2, 3))
        se = math.hypot(ma.std(ddof=1), mb.std(ddof=1)) / math.sqrt(len(ma))
        print(name, ma.mean(), mb.mean(), se)
        assert ma.mean() > 0 and abs(ma.mean() - mb.mean()) < 4 * se, (name, ma.mean(), mb.mean(), se)


def test_points_of_a_segment_of_no_length_weigh_nothing():
    """scattered_points of a segment of no length (a ray meeting a surface where it starts) beside one of length 2:
    the first's points weigh zero, the second's as they do alone."""
    from pbvol_cli.pointbased.gather import segment_planes
    from pbvol_cli.pointbased.radiance_cache import scattered_points
    from pbvol_cli.pointbased.volume_samples import Medium

    med = Medium(np.array([0.5, 0.5, 0.5]), np.array([1.0, 1.1, 1.2]), 1, 0.0)
    pos, dirs = np.zeros((2, 3)), np.tile([0.0, 0.0, 1.0], (2, 1))
    beta, tseg = np.ones((2, 3)), np.array([0.0, 2.0])
    planes = segment_planes(pos, dirs, tseg, np.full((2, 3), np.nan), np.full((2, 3), np.nan))
    both = scattered_points(np.arange(2), pos, dirs, beta, tseg, np.array([1, 2], np.uint64), med, 3, planes)
    alone = scattered_points(np.array([1]), pos, dirs, beta, tseg, np.array([1, 2], np.uint64), med, 3, planes)
    assert np.all(both.weight[both.owner == 0] == 0.0)
    np.testing.assert_array_equal(both.weight[both.owner == 1], alone.weight)
    assert np.all(alone.weight > 0)
