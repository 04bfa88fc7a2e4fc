"""Single scattering (beam x point) against closed forms and an independent quadrature; the sample-by-sample
evaluation against the point-by-point walk."""

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from conftest import (SPHERE_G, SPHERE_LIGHT_DIR, SPHERE_SIGMA_A, SPHERE_SIGMA_S, build, camera, medium_sphere_scene,
                      random_volume_samples, single_scattering_reference, write_scene)
from pbvol_cli.imageio import read_layers
from pbvol_cli.multiple_scattering.table import empty_table
from pbvol_cli.physics.phase import phase_eval
from pbvol_cli.pipeline.render import RenderOptions, render_scene
from pbvol_cli.pointbased.octree import build_octree, node_lobes
import pbvol_cli.pointbased.single_scattering as single_module
from pbvol_cli.pointbased.single_scattering import single_scattering, single_scattering_by_samples
from pbvol_cli.pointbased.volume_samples import NO_PLANE, Medium, Query, VolumeSamples


def test_single_scattering_matches_quadrature(tmp_path):
    """pbl's single layer against the independent quadrature of the volpath tests (index-matched sphere)."""
    scene = medium_sphere_scene(surface_samples=20000, kmax=16)
    path = write_scene(tmp_path, scene)
    render_scene(path, tmp_path / "o.exr", RenderOptions(method="pbl", components="single", cache_dir=tmp_path,
                                                         quiet=True))
    single = read_layers(tmp_path / "o.exr")["single"]
    ref, covered = single_scattering_reference(build(tmp_path, scene), SPHERE_SIGMA_S, SPHERE_SIGMA_S + SPHERE_SIGMA_A,
                                               SPHERE_G, SPHERE_LIGHT_DIR, 2.0, 1.0)
    # the image mean is unbiased up to the beams' box kernel: measured within 0.1-2.1% for 5k-80k surface samples
    ratio = single[covered].mean(0) / ref[covered].mean(0)
    assert np.all(np.abs(ratio - 1) < 0.03), ratio
    # per pixel, camera-side sampling (k_max stratified points, 4 spp) leaves 8-12% relative RMS at this size
    rel_rms = np.sqrt(((single - ref) ** 2)[covered].mean(0) / (ref ** 2)[covered].mean(0))
    assert np.all(rel_rms < 0.15), rel_rms


def test_single_scattering_of_coarse_oblique_beams_under_a_flat_boundary_is_unbiased():
    """Parallel beams at 60 degrees into the half-space y < 0 (a jittered grid of entry points, kernel discs about
    one mean free path wide): the beam estimate at points at depth z averages to sigma_s p E / cos(theta)
    e^(-sigma_t z / cos(theta)), the beams' fluence there. With the attenuation along each beam's own axis the
    disc's average of the exponentials read 2 I_1(x) / x high (x = sigma_t r tan(theta) = 1.39: 1.26; measured
    1.2-1.3); over P's own path from the entry plane it is exact."""
    rng = np.random.default_rng(8)
    th, sig_t, alb, E = math.radians(60.0), 1.0, 0.8, 1.0
    d = np.array([math.sin(th), -math.cos(th), 0.0])
    s = 2.0  # entry spacing: beams of surface area s^2, cross-section s^2 cos(theta), radius 0.8
    gx, gz = np.meshgrid(np.arange(-12, 12) * s, np.arange(-12, 12) * s)
    start = np.stack([gx.ravel(), np.zeros(gx.size), gz.ravel()], axis=1)
    start[:, [0, 2]] += rng.random((len(start), 2)) * s
    n = len(start)
    length = np.full(n, 30.0)
    area = np.full(n, s * s * math.cos(th))
    power = np.full((n, 3), E * s * s)
    ends = np.ones(n, np.int64)  # every segment starts on the boundary
    plane = np.tile([0.0, 1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 30.0], (n, 1))  # entry plane y = 0, normal +y
    rb = np.sqrt(area / math.pi)
    lo = np.minimum(start - 3 * rb[:, None] * d, start + length[:, None] * d) - rb[:, None]
    hi = np.maximum(start - 3 * rb[:, None] * d, start + length[:, None] * d) + rb[:, None]
    centre = start + 0.5 * length[:, None] * d
    tree = build_octree(centre, lo, hi, np.tile(d, (n, 1)), power).arrays()
    vs = VolumeSamples(tree, start, np.tile(d, (n, 1)), length, power, area, centre, power, rb, ends, plane,
                       (empty_table().render_args(),) * 3, 0.0, node_lobes(tree))
    med = Medium(np.full(3, sig_t * (1 - alb)), np.full(3, sig_t * alb), 1, 0.0)
    w = np.array([0.0, 1.0, 0.0])
    for z in (0.5, 1.5):
        got = []
        for _ in range(3000):
            P = np.array([rng.uniform(-4, 4), -z, rng.uniform(-4, 4)])
            out = np.zeros(3)
            single_scattering(vs, med, Query(*P, *w, NO_PLANE), out)
            got.append(out[0])
        exact = med.sigma_s[0] * phase_eval(1, 0.0, d @ w) * E / math.cos(th) * math.exp(-sig_t * z / math.cos(th))
        mean, se = np.mean(got), np.std(got) / math.sqrt(len(got))
        print("depth", z, "mean / exact", mean / exact, "se", se / exact)
        assert abs(mean / exact - 1.0) < max(4 * se / exact, 0.03), (z, mean / exact)


@pytest.mark.parametrize("grazing", [True, False])
def test_no_beam_carries_more_than_the_power_it_entered_with(grazing):
    """A leg that starts on the boundary, with P in its backward continuation (grazing: the attenuation is taken
    along the axis, t < 0) or above its entry plane (a curved boundary's tangent plane, P beyond it): the estimate
    is the entry power's, sigma_s p Phi / A, never amplified by e^(sigma_t |t|). Amplified, bounced beams leaving the
    boundary at grazing angles in a dense medium (marble, 270 mean free paths across) made each generation of
    bounced light 10^8 times the last."""
    sig_t, alb, r = 10.0, 0.9, 0.5
    cos_in = 0.05 if grazing else 0.6  # cosine between the leg and the inward normal -y
    d = np.array([math.sqrt(1 - cos_in ** 2), -cos_in, 0.0])
    start, area, power = np.zeros((1, 3)), np.full(1, math.pi * r * r), np.ones((1, 3))
    plane = np.array([[0.0, 1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 30.0]])  # entry plane y = 0, normal +y (outward)
    tree = build_octree(start + 5 * d, start - 10.0, start + 10.0, d[None], power).arrays()
    vs = VolumeSamples(tree, start, d[None], np.full(1, 10.0), power, area, start + 5 * d, power, np.full(1, r),
                       np.ones(1, np.int64), plane, (empty_table().render_args(),) * 3, 0.0,
                       node_lobes(tree))
    med = Medium(np.full(3, sig_t * (1 - alb)), np.full(3, sig_t * alb), 0, 0.0)
    # grazing: 1.2 beam radii behind the start on the axis (in the continuation, t < 0); steep: on the disc, at
    # t = 0, 0.9 radii above the entry plane's side
    P = -1.2 * r * d if grazing else 0.9 * r * np.array([-d[1], d[0], 0.0]) * np.sign(d[0])
    assert grazing or P[1] > 0
    out = np.zeros(3)
    single_scattering(vs, med, Query(*P, 0.0, 0.0, 1.0, NO_PLANE), out)
    entry = med.sigma_s[0] * phase_eval(0, 0.0, 0.0) * power[0, 0] / area[0]
    assert out[0] > 0 and out[0] <= entry * (1 + 1e-12), (out[0], entry)


@pytest.mark.parametrize("max_cells", [1 << 21, 64])
def test_sample_by_sample_sums_equal_the_walk(monkeypatch, max_cells):
    """single_scattering_by_samples against single_scattering point by point: 3000 segments of every direction,
    length, width and boundary continuation, 2000 points (some in clumps, so that cells hold several): the same
    sums to rounding, and bit-identical on one thread and on three (the grid cut in slabs). max_cells 64: a grid
    coarsened far beyond its cell size finds the same beams."""
    monkeypatch.setattr(single_module, "GRID_MAX_CELLS", max_cells)
    rng = np.random.default_rng(5)
    vs = random_volume_samples(rng, 3000)
    med = Medium(np.array([0.2, 0.5, 1.0]), np.array([1.0, 0.8, 0.5]), 1, 0.7)
    pts = np.concatenate([rng.uniform(-2.5, 2.5, (1500, 3)), rng.normal(0.3, 0.05, (500, 3))])
    w = rng.normal(size=(len(pts), 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    walk = np.zeros((len(pts), 3))
    for j in range(len(pts)):
        single_scattering(vs, med, Query(*pts[j], *w[j], NO_PLANE), walk[j])
    assert (walk[:, 0] > 0).mean() > 0.5  # most points lie in some kernel
    one = single_scattering_by_samples(None, 1, vs, med, pts, w)
    np.testing.assert_allclose(one, walk, rtol=1e-12, atol=0.0)
    with ThreadPoolExecutor(3) as pool:
        three = single_scattering_by_samples(pool, 3, vs, med, pts, w)
    assert np.array_equal(one, three)
    # a point at infinity (a segment without an end) is in no kernel, and leaves the others' sums as they were
    far = single_scattering_by_samples(None, 1, vs, med, np.vstack([pts[:10], [[np.inf, 0.0, 0.0]]]), w[:11])
    np.testing.assert_allclose(far[:10], walk[:10], rtol=1e-12, atol=0.0)
    assert np.all(far[10] == 0.0)
    np.testing.assert_allclose(single_scattering_by_samples(None, 1, vs, med, pts[3:4], w[3:4]), walk[3:4],
                               rtol=1e-12, atol=0.0)  # a grid of one point


def test_each_sample_as_a_leg_gives_the_walks_sums():
    """_splat_legs with every volume sample a leg of its own (its span the kernel cylinder's, axial_extent) against
    the walk, at points spread over the samples and at points in one small clump, whose grid most legs reach only
    beyond its ends (a column's range of cells then lies outside the grid, and must be skipped, not wrapped)."""
    from pbvol_cli.pointbased.volume_samples import END_EXTENSION

    rng = np.random.default_rng(8)
    vs = random_volume_samples(rng, 3000)
    ext = END_EXTENSION * vs.rb
    span = np.column_stack([np.where(vs.ends & 1, -ext, 0.0), vs.len + np.where(vs.ends & 2, ext, 0.0)])
    legs = vs._replace(leg_first=np.arange(len(vs.len), dtype=np.int64), leg_span=span)
    med = Medium(np.array([0.2, 0.5, 1.0]), np.array([1.0, 0.8, 0.5]), 1, 0.7)
    for pts in (rng.uniform(-2.5, 2.5, (1000, 3)), rng.normal(0.3, 0.05, (300, 3))):
        w = rng.normal(size=(len(pts), 3))
        w /= np.linalg.norm(w, axis=1)[:, None]
        walk = np.zeros((len(pts), 3))
        for j in range(len(pts)):
            single_scattering(vs, med, Query(*pts[j], *w[j], NO_PLANE), walk[j])
        assert (walk[:, 0] > 0).mean() > 0.5
        np.testing.assert_allclose(single_scattering_by_samples(None, 1, legs, med, pts, w), walk, rtol=1e-12,
                                   atol=0.0)


def test_legs_give_the_segments_sums(tmp_path):
    """Light samples placed in a refracting sphere (legs of 6 segments through internal reflections): single
    scattering taken leg by leg (volume_samples.leg_table, _splat_legs) against segment by segment and against
    the walk, at points in and around the sphere: the same sums to rounding; bit-identical on one thread and
    three."""
    from pbvol_cli.pointbased.light_samples import place_light_samples
    from pbvol_cli.pointbased.volume_samples import NO_LEGS, SampleSet, medium_params

    scene = {"camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "fov": 40, "resolution": [8, 8]},
             "lights": [{"type": "directional", "direction": [0.3, -1, 0.2], "irradiance": 2.0}],
             "shapes": [{"type": "sphere", "radius": 1.0, "interface": "dielectric", "eta": 1.5,
                         "medium": {"sigma_a": 0.3, "sigma_s": [0.5, 1.0, 2.0], "g": 0.6}}]}
    bs = build(tmp_path, scene)
    tables = tuple(empty_table().render_args() for _ in range(3))
    vs = SampleSet(place_light_samples(bs, 3000, 6, 4, 8, 1, in_space_order=True), 0, bs.media, tables, 2.0).kernel
    assert 0 < len(vs.leg_first) < len(vs.len) / 3  # mostly whole legs of 6
    med = medium_params(bs.media, 0)
    rng = np.random.default_rng(3)
    pts = np.concatenate([rng.uniform(-1.1, 1.1, (3000, 3)), rng.normal(0.2, 0.03, (300, 3))])
    w = rng.normal(size=(len(pts), 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    legs = single_scattering_by_samples(None, 1, vs, med, pts, w)
    segments = single_scattering_by_samples(None, 1, vs._replace(leg_first=NO_LEGS[0], leg_span=NO_LEGS[1]), med,
                                            pts, w)
    assert (legs[:, 0] > 0).mean() > 0.5
    np.testing.assert_allclose(legs, segments, rtol=1e-12, atol=1e-15 * segments.max())
    walk = np.zeros((len(pts), 3))
    for j in range(0, len(pts), 7):
        single_scattering(vs, med, Query(*pts[j], *w[j], NO_PLANE), walk[j])
    np.testing.assert_allclose(legs[::7], walk[::7], rtol=1e-12, atol=1e-15 * segments.max())
    with ThreadPoolExecutor(3) as pool:
        assert np.array_equal(single_scattering_by_samples(pool, 3, vs, med, pts, w), legs)


def test_a_dense_slab_under_vertical_light_reads_the_closed_form_at_every_depth(tmp_path):
    """A box whose mean free path is 10 ray offsets (eps), lit straight down through an index-matched top: S_1 just
    below it is sigma_s / (4 pi) e^(-sigma_t z) exactly (isotropic phase, unit irradiance). The beams start eps
    inside the boundary; their first samples start on it again, with the power that crossed it. Before, they
    started at eps with that power and every depth read e^(sigma_t eps) = 1.105 too much (measured 1.10)."""
    from pbvol_cli.pointbased.light_samples import place_light_samples
    from pbvol_cli.pointbased.volume_samples import SampleSet, medium_params

    probe = build(tmp_path, {"camera": camera((4, 4), position=(0, 6, 0.5), fov=30),
                             "lights": [{"type": "directional", "direction": [0, -1, 0], "irradiance": 1.0}],
                             "shapes": [{"type": "box", "size": [6.0, 1.0, 6.0], "interface": "null",
                                         "medium": {"albedo": 0.9, "mean_free_path": 1.0}}]})
    mfp = 10.0 * probe.eps
    scene = {"camera": camera((4, 4), position=(0, 6, 0.5), fov=30),
             "lights": [{"type": "directional", "direction": [0, -1, 0], "irradiance": 1.0}],
             "shapes": [{"type": "box", "size": [6.0, 1.0, 6.0], "interface": "null",
                         "medium": {"albedo": 0.9, "mean_free_path": mfp}}]}
    bs = build(tmp_path, scene)
    assert bs.eps == probe.eps
    tables = tuple(empty_table().render_args() for _ in range(3))
    vs = SampleSet(place_light_samples(bs, 4000, 8, 2, 8, 1), 0, bs.media, tables, 2.0).kernel
    med = medium_params(bs.media, 0)
    sigma_t = float(med.sigma_a[1] + med.sigma_s[1])
    rng = np.random.default_rng(5)
    for depth in (0.2, 1.0, 2.0):  # mean free paths below the top face (y = 0.5)
        pts = np.column_stack([rng.uniform(-2, 2, 3000), np.full(3000, 0.5 - depth / sigma_t),
                               rng.uniform(-2, 2, 3000)])
        s1 = single_scattering_by_samples(None, 1, vs, med, pts, np.tile([0.0, 1.0, 0.0], (3000, 1)))[:, 1]
        exact = med.sigma_s[1] / (4 * math.pi) * math.exp(-depth)
        assert abs(s1.mean() / exact - 1) < 0.02, (depth, s1.mean() / exact)
