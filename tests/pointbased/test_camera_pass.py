"""The point-based camera paths: surfaces against volpath, the camera paths per pixel and pass."""

import math

import numpy as np
import pytest

from conftest import camera, medium_sphere_scene, smooth_layers, write_scene
from pbvol_cli.imageio import read_exr, read_layers
from pbvol_cli.pipeline.render import RenderOptions, render_scene
from pbvol_cli.pointbased.camera_pass import (AUTO_FIRST_PATHS, AUTO_MAX_PATHS, DIFFUSE_COST, DIFFUSE_SHARE_MIN,
                                              PASS_COST_RATIO, DiffuseShare, PixelStatistics, add_rows,
                                              auto_surface_paths, diffuse_share, neighbourhood_sums, pass_paths,
                                              pilot_surface_paths)


@pytest.mark.parametrize("light", ["quad", "sphere"])
def test_surfaces_match_volpath_with_indirect_light_caustics_and_lights_that_hide_the_sky(tmp_path, light):
    """pbl's surface shading (no medium): a diffuse plane and sphere (indirect light, 3 bounces), a glass sphere
    (its caustic reaches the plane only through the specular chain), a quad light in front of the environment
    (lights are opaque to shadow rays: counting the sky behind the light made pbl 2% bright), or a sphere light
    seen directly, in the glass and through it (pbl once judged its side at the surface behind it: it vanished).
    Image means within 4 standard errors of the two methods' seed-to-seed spread (measured: within 0.25%)."""
    emitter = ({"type": "quad", "corner": [-1.0, 4.0, -1.0], "edge1": [2.0, 0, 0], "edge2": [0, 0, 2.0],
                "radiance": 5.0} if light == "quad" else
               {"type": "sphere", "center": [0.3, 1.9, -0.5], "radius": 0.25, "radiance": 30.0})
    scene = {"camera": camera((10, 10), position=(0, 3.0, 4.0), fov=50), "render": {"spp": 16},
             "lights": [emitter, {"type": "environment", "radiance": 0.2}],
             "shapes": [{"type": "quad", "center": [0, 0, 0], "size": [6.0, 6.0], "interface": "diffuse", "albedo": 0.7},
                        {"type": "sphere", "center": [-0.8, 0.6, 0], "radius": 0.6, "interface": "diffuse",
                         "albedo": [0.8, 0.5, 0.3]},
                        {"type": "sphere", "center": [0.8, 0.7, 0.2], "radius": 0.6, "interface": "dielectric",
                         "eta": 1.5}]}
    path = write_scene(tmp_path, scene)
    stats = {}
    for method, spp in (("pbl", 32), ("volpath", 128)):
        means = []
        for seed in range(4):
            render_scene(path, tmp_path / "o.exr", RenderOptions(method=method, spp=spp, seed=seed, cache_dir=tmp_path,
                                                                 quiet=True))
            means.append(read_exr(tmp_path / "o.exr")[0].mean((0, 1)))
        means = np.array(means, float)
        stats[method] = (means.mean(0), means.std(0, ddof=1) / 2)
    (mp, sp), (mv, sv) = stats["pbl"], stats["volpath"]
    assert np.all(sp > 0) and np.all(sv > 0)
    assert np.all(np.abs(mp - mv) < 4 * np.hypot(sp, sv)), (mp, mv, sp, sv)


def _floor_scene():
    """_scene's medium sphere seen from above a diffuse floor (light samples kept few: fast)."""
    scene = medium_sphere_scene(surface_samples=800, segments_per_beam=4, bounce_samples=64)
    scene["camera"] = camera((12, 12), position=(0, 1.5, 3.5), fov=50)
    scene["shapes"].append({"type": "quad", "center": [0, -1.0, 0], "size": [8.0, 8.0], "interface": "diffuse",
                            "albedo": 0.6})
    return scene


def _seed_renders(tmp_path, scene, spp, seeds=range(4)):
    """Renders scene with pbl once per seed into tmp_path / "o.exr", yielding that path after each."""
    path = write_scene(tmp_path, scene)
    for seed in seeds:
        render_scene(path, tmp_path / "o.exr", RenderOptions(method="pbl", spp=spp, seed=seed, cache_dir=tmp_path,
                                                             quiet=True))
        yield tmp_path / "o.exr"


def test_surface_paths_keep_the_image_and_cut_the_surfaces_noise(tmp_path):
    """surface_paths = k traces k camera paths per pixel and pass, one of them (chosen at random) evaluating the
    medium with weight k: every layer's mean stays that of k = 1 (within 4 standard errors of the seed-to-seed
    spread), and the surface layer's per-pixel variance falls about k times (bound: half)."""
    scene = _floor_scene()
    scene["lights"].append({"type": "environment", "radiance": 0.3})
    stats = {}
    for k in (1, 4):
        scene["render"]["pbl"]["surface_paths"] = k
        runs = []
        for out in _seed_renders(tmp_path, scene, spp=2):
            L = read_layers(out)
            medium = sum(L[c].astype(float) for c in ("single", "double", "multiple", "bounced"))
            runs.append((L["surface"].astype(float), medium))
        stats[k] = [np.array([r[j] for r in runs]) for j in range(2)]  # (seed, H, W, 3) per part
    for j, part in enumerate(("surface", "medium")):
        a, b = stats[1][j], stats[4][j]
        ma, mb = a.mean((1, 2, 3)), b.mean((1, 2, 3))
        se = math.hypot(ma.std(ddof=1), mb.std(ddof=1)) / 2
        print(part, ma.mean(), mb.mean(), se)
        assert ma.mean() > 0 and abs(ma.mean() - mb.mean()) < 4 * se + 1e-12, (part, ma, mb)
    var1 = stats[1][0].var(axis=0, ddof=1).mean()
    var4 = stats[4][0].var(axis=0, ddof=1).mean()
    print("surface variance k=1, k=4:", var1, var4)
    assert var4 < 0.5 * var1, (var1, var4)


def test_auto_surface_paths_minimises_the_error_at_equal_time():
    """auto_surface_paths returns the k of least (S1 / k + M) (k + R), brute-forced over every allowed k; no
    surface noise takes one path, no medium noise the most."""
    R = PASS_COST_RATIO
    ks = np.arange(1, AUTO_MAX_PATHS + 1)
    for s1, m in ((0.06, 0.003), (0.05, 0.03), (1e-4, 0.005), (0.1, 1e-5), (0.02, 0.02)):
        cost = (s1 / ks + m) * (ks + R)
        k = auto_surface_paths(s1, m)
        assert cost[k - 1] <= 1.01 * cost.min(), (s1, m, k, ks[cost.argmin()])
    assert auto_surface_paths(0.0, 0.01) == 1
    assert auto_surface_paths(0.01, 0.0) == AUTO_MAX_PATHS
    assert auto_surface_paths(0.06, 0.003) > 8 > auto_surface_paths(0.05, 0.03)


def test_auto_surface_paths_count_the_passes_already_in_the_image():
    """With passes already in the image (their variance sum A and cost C per pixel) and r passes to come, the count
    is the k of least (A + r (S1 / k + M)) (C + r (k + R)), brute-forced; two passes of 8 paths of a noisy surface
    over a quiet medium leave less to gain: 20 paths for the last two of four passes where a pass alone would take
    the cap. No passes before, or r None, give a pass's own optimum."""
    R = PASS_COST_RATIO
    ks = np.arange(1, 1025)
    for s1, m, first in ((0.06, 0.003, (8, 8)), (0.1, 1e-5, (8, 8)), (0.02, 0.02, (8, 8)), (0.5, 0.001, (8, 30))):
        A = sum(s1 / k + m for k in first)
        C = sum(k + R for k in first)
        for r in (1, 2, 6, 100):
            cost = (A + r * (s1 / ks + m)) * (C + r * (ks + R))
            k = auto_surface_paths(s1, m, 1024, (A, C), r)
            assert cost[k - 1] <= 1.01 * cost.min(), (s1, m, first, r, k, ks[cost.argmin()])
        assert auto_surface_paths(s1, m, 1024, (A, C), None) == auto_surface_paths(s1, m, 1024)
        assert auto_surface_paths(s1, m, 1024, (0.0, 0.0), 3) == auto_surface_paths(s1, m, 1024)
    s1, m = 0.1, 1e-5
    assert auto_surface_paths(s1, m, 1024) > 128
    assert auto_surface_paths(s1, m, 1024, (2 * (s1 / 8 + m), 2 * (8 + R)), 2) == 20


def test_pilot_paths_keep_the_mean_count_and_follow_the_square_root_of_the_noise():
    """pilot_surface_paths: the first passes' counts from a pilot's variances keep 8 paths a pixel on average, give a
    pixel of 100x the variance about 10x the paths of the rest beyond the one every pixel keeps, raise its
    neighbours (3 x 3) above the far pixels, never go below 1, and are 8 everywhere where the pilot saw no
    variance at all."""
    s1 = np.full(400, 0.01)
    s1[210] = 1.0  # pixel (10, 10) of a 20 x 20 image
    k = pilot_surface_paths(s1, 20)
    assert abs(k.mean() - AUTO_FIRST_PATHS) < 0.5 and k.min() >= 1
    far = k[0] - 1
    assert 8 * far <= k[210] - 1 <= 12 * far, (k[210], k[0])
    assert k[209] > k[0] and k[231] > k[0]  # its neighbours (10, 9) and (11, 11)
    assert np.array_equal(pilot_surface_paths(np.zeros(400), 20), np.full(400, AUTO_FIRST_PATHS))


def test_neighbourhood_sums_add_each_pixels_nine_neighbours_with_the_edges_repeated():
    """neighbourhood_sums (the pilot pools its paths over each pixel's 3 x 3 neighbourhood): inside the image the
    sum of the nine pixels around, at an edge or a corner the edge's pixels counted again in place of those beyond
    it, every channel on its own; a constant image sums to nine times itself."""
    rng = np.random.default_rng(5)
    h, w = 4, 6
    v = rng.random((h * w, 2))
    got = neighbourhood_sums(v, w).reshape(h, w, 2)
    img = v.reshape(h, w, 2)
    for y in range(h):
        for x in range(w):
            want = sum(img[min(max(y + dy, 0), h - 1), min(max(x + dx, 0), w - 1)] for dy in (-1, 0, 1)
                       for dx in (-1, 0, 1))
            assert np.allclose(got[y, x], want), (y, x)
    assert np.allclose(neighbourhood_sums(np.full((h * w, 3), 0.5), w), 4.5)


def test_pixel_statistics_measure_the_variances_and_give_noisy_pixels_more_paths():
    """PixelStatistics: each pixel's surface-path variance (from all its paths) and the medium's pass-to-pass
    variance, relative as compare's relMSE, from synthetic passes of known variances (Gaussian, 50 x 100 pixels);
    the next pass's counts are sqrt(R S1_p / M) per pixel: a block of pixels 16 times as noisy (a small light's
    mirror image) gets about 4 times the paths, a noiseless pixel one."""
    rng = np.random.default_rng(5)
    W, H, sd_s, sd_m, level = 100, 50, 0.3, 0.05, 1.0
    npix = W * H
    sd = np.full(npix, sd_s)
    noisy = (np.arange(npix) % W < 30) & (np.arange(npix) // W < 20)
    sd[noisy] *= 4.0
    sd[np.arange(npix) // W >= H - 10] = 0.0  # the bottom rows: no surface noise at all
    st = PixelStatistics(npix, W)
    image = np.full((npix, 3), level)
    assert st.next_paths(image) is None
    for k in (8, 8, 1, 3):
        paths = level + sd[None, :, None] * rng.normal(size=(k, npix, 3))
        st.add(np.full(npix, k), paths.sum(0), (paths ** 2).sum(0), 0.2 + sd_m * rng.normal(size=(npix, 3)))
    den = level ** 2 + 1e-2
    s1, m = st.variances(image)
    quiet = ~noisy & (sd > 0)
    assert s1[quiet].mean() == pytest.approx(sd_s ** 2 / den, rel=0.03)
    assert s1[noisy].mean() == pytest.approx(16 * sd_s ** 2 / den, rel=0.03)
    assert m == pytest.approx(sd_m ** 2 / den, rel=0.1)
    k = st.next_paths(image)
    optimum = math.sqrt(PASS_COST_RATIO) * sd_s / sd_m  # 26.8 with the true variances
    inner_quiet = quiet & (np.arange(npix) % W > 35) & (np.arange(npix) // W < H - 12)  # away from the other blocks
    assert abs(np.median(k[inner_quiet]) - optimum) <= 0.1 * optimum, np.median(k[inner_quiet])
    assert abs(np.median(k[noisy]) / np.median(k[inner_quiet]) - 4.0) < 0.4
    assert np.all(k[np.arange(npix) // W >= H - 8] == 1)
    # with one pass to come the first passes' noise stays in the image: fewer paths, in the same proportions
    k1 = st.next_paths(image, 1)
    before = (np.mean(s1 * (1 / 8 + 1 / 8 + 1 + 1 / 3)) + 4 * m, np.mean(st.count) + 4 * PASS_COST_RATIO)
    fewer = math.sqrt((before[1] + PASS_COST_RATIO) / (before[0] + m) * sd_s ** 2 / den)
    assert fewer < 0.5 * optimum and abs(np.median(k1[inner_quiet]) - fewer) <= 0.1 * fewer + 1
    assert abs(np.median(k1[noisy]) / np.median(k1[inner_quiet]) - 4.0) < 0.6


def test_diffuse_share_minimises_the_error_at_equal_time():
    """diffuse_share returns the p of least (a + b / p)(1 + DIFFUSE_COST p), a the variance that is not the
    rays' after a diffuse bounce (v measured at share p_before less b / p_before), brute-forced over a fine grid
    of shares; none of that light takes the least share, a pass whose variance is all of it every ray."""
    ps = np.linspace(DIFFUSE_SHARE_MIN, 1.0, 20001)
    for b, v, p_before in ((1e-5, 1e-3, 1.0), (1e-4, 1e-3, 0.5), (2e-4, 3e-4, 1.0), (3e-5, 2e-3, 0.125),
                           (1e-3, 5e-3, 1.0)):
        a = v - b / p_before
        cost = (a + b / ps) * (1.0 + DIFFUSE_COST * ps)
        p = diffuse_share(b, v, p_before)
        assert (a + b / p) * (1.0 + DIFFUSE_COST * p) <= 1.0001 * cost.min(), (b, v, p, ps[cost.argmin()])
    assert diffuse_share(0.0, 1e-3, 1.0) == DIFFUSE_SHARE_MIN
    assert diffuse_share(1e-3, 1e-3, 1.0) == 1.0
    assert diffuse_share(1e-6, 1e-2, 1.0) == DIFFUSE_SHARE_MIN < diffuse_share(1e-3, 4e-3, 1.0) == 1.0


def test_the_second_pass_takes_its_diffuse_share_from_the_first_pass_and_the_pilot():
    """With a pilot's surface variance, the second pass's share of the rays after a diffuse bounce is the
    splitting optimum of the first pass's measured second moment b against the pilot's variance over the pass's
    paths (the medium's pass-to-pass variance left out, so the share is no lower than with it); without a pilot, or
    with nothing measured, it stays 1 until the third pass."""
    npix, W = 40, 8
    k = np.full(npix, 4)
    for pilot in (None, np.full(npix, 0.8)):
        st = PixelStatistics(npix, W)
        st.pilot_surface = pilot
        assert st.next_diffuse_share(None, k) == 1.0  # the first pass
        level = np.ones((npix, 3))
        st.add(k, 4 * level, 4 * level, level)
        assert st.next_diffuse_share(level, k) == 1.0  # nothing measured after a diffuse bounce
        share = DiffuseShare(1.0, level ** 2 + 1e-2)
        share.add(np.arange(npix), k, np.full((npix, 3), 4 * 0.02))  # each ray's value / k = 0.02 in its pixel
        st.add_diffuse(share, npix)
        b = 0.02 ** 2 / 1.01
        expected = 1.0 if pilot is None else diffuse_share(b, 0.8 / 4 + b, 1.0)
        assert st.next_diffuse_share(level, k) == pytest.approx(expected)
    assert expected < 0.5  # (b small against the surfaces' noise: most rays skip the smooth terms)


def test_diffuse_share_measures_the_second_moment_of_what_the_rays_would_add_unweighted():
    """A ray kept at share p adds its value / p; p times that squared has the expectation of the value squared:
    the measure is per pixel relative (over the image so far squared + 0.01) and divides by the pixel's path
    count like the pixel's estimate. The first pass (no image yet) measures nothing but counts its rays."""
    den = np.array([[1.0, 1.0, 1.0], [4.0, 4.0, 4.0]])
    share = DiffuseShare(0.5, den)
    share.add(np.array([0, 1, 1]), np.array([2.0, 1.0, 1.0]), np.array([[2.0, 2.0, 2.0], [2.0, 0, 0], [0, 0, 0]]))
    assert share.rays == 3
    assert share.second_moment == pytest.approx(0.5 * (1.0 + (4.0 / 4.0) / 3.0))
    first = DiffuseShare(1.0, None)
    first.add(np.array([0]), np.array([1.0]), np.ones((1, 3)))
    assert first.rays == 1 and first.second_moment == 0.0


def _water_sphere_on_a_floor():
    """_scene's medium sphere behind an eta 1.33 boundary on a diffuse floor, seen from above: many camera rays
    enter it after a bounce off the floor."""
    scene = medium_sphere_scene(surface_samples=800, segments_per_beam=4, bounce_samples=64)
    scene["camera"] = {**camera((16, 16), position=(0, 2.0, 3.0), fov=50), "look_at": [0.0, -0.4, 0.0]}
    scene["shapes"][0].update(interface="dielectric", eta=1.33)
    scene["shapes"].append({"type": "quad", "center": [0.0, -1.0, 0.0], "size": [6.0, 6.0], "interface": "diffuse",
                            "albedo": 0.8})
    return scene


def test_diffuse_shares_keep_every_smooth_layers_mean_in_a_render(tmp_path, monkeypatch):
    """The test sphere on a diffuse floor, the rays after a bounce off the floor evaluating the smooth terms on
    half of them (weighted 2) against all of them, six seeds each: the double, multiple and bounced layers' means
    agree within 4 standard errors, and the rays did play (the share is forced: the rule's own wants 3 passes)."""
    import pbvol_cli.pointbased.gather as gather

    scene = _water_sphere_on_a_floor()
    played = []
    after = gather._after_diffuse

    def record(pool, threads, idx, *rest):  # (rest[-1]: the share)
        if rest[-1] < 1.0:
            played.append(len(idx))
        return after(pool, threads, idx, *rest)

    monkeypatch.setattr(gather, "_after_diffuse", record)
    runs = {}
    for share in (1.0, 0.5):
        monkeypatch.setattr(PixelStatistics, "next_diffuse_share", lambda self, image, k, q=share: q)
        runs[share] = smooth_layers(tmp_path, scene, range(6))
    assert sum(played) > 0
    for j, name in enumerate(("double", "multiple", "bounced")):
        ma, mb = runs[1.0][:, j].mean((1, 2, 3)), runs[0.5][:, j].mean((1, 2, 3))
        se = math.hypot(ma.std(ddof=1), mb.std(ddof=1)) / math.sqrt(len(ma))
        assert ma.mean() > 0 and abs(ma.mean() - mb.mean()) < 4 * se, (name, ma.mean(), mb.mean(), se)


def test_a_coarser_cut_after_a_diffuse_bounce_keeps_every_smooth_layers_mean_in_a_render(tmp_path):
    """[render.pbl] cut_size_diffuse reaches the points after a diffuse bounce: the test sphere on a diffuse floor,
    rendered with no refinement there and with 8, six seeds each, gives other images (the setting acts) whose
    double, multiple and bounced layers' means agree within 4 standard errors (the light cut is unbiased whatever
    its size)."""
    scene = _water_sphere_on_a_floor()
    runs = {}
    for cut in (0, 8):
        scene["render"]["pbl"]["cut_size_diffuse"] = cut
        runs[cut] = smooth_layers(tmp_path, scene, range(6))
    assert not np.array_equal(runs[0], runs[8])
    for j, name in enumerate(("double", "multiple", "bounced")):
        ma, mb = runs[0][:, j].mean((1, 2, 3)), runs[8][:, j].mean((1, 2, 3))
        se = math.hypot(ma.std(ddof=1), mb.std(ddof=1)) / math.sqrt(len(ma))
        print(name, "cut 0", ma.mean(), "cut 8", mb.mean(), "se", se)
        assert mb.mean() > 0 and abs(ma.mean() - mb.mean()) < 4 * se, (name, ma.mean(), mb.mean(), se)


def test_pass_paths_run_sample_by_sample_and_continue_each_pixels_count():
    k = np.array([3, 1, 2])
    pixels, samples, ranks = pass_paths(k, np.array([10, 0, 5]))
    assert pixels.tolist() == [0, 1, 2, 0, 2, 0]
    assert samples.tolist() == [10, 0, 5, 11, 6, 12] and ranks.tolist() == [0, 0, 0, 1, 1, 2]
    # any counts (zero and a pixel of many included): every (rank, pixel) pair once, ordered by rank, then pixel
    k = np.random.default_rng(4).integers(0, 9, 500)
    k[17] = 300
    pixels, samples, ranks = pass_paths(k, np.zeros(500, np.int64))
    expected = sorted((r, p) for p in range(500) for r in range(k[p]))
    assert list(zip(ranks.tolist(), pixels.tolist())) == expected and samples.tolist() == ranks.tolist()


def test_auto_surface_paths_follow_the_noise_and_keep_the_image(tmp_path):
    """surface_paths = 0 (auto): 8 paths a pixel on average for the first two passes (spread by a pilot's noise), then
    more where the surfaces' noise rules (a
    floor under a sky beside a thin medium) and one where there is no surface light at all (the medium under a
    directional light against black). The image's mean stays that of a fixed k (4 standard errors of the seeds'
    spread), with a pooled pilot too (pilot_pool), and the same seed gives the same image."""
    floor = _floor_scene()
    floor["lights"] = [{"type": "environment", "radiance": 0.5}]
    floor["shapes"][0]["medium"] = {"sigma_a": 0.05, "sigma_s": 0.05, "g": 0.0}
    means = {}
    for k in (8, 0):  # auto last: its seed-3 render is checked for reproducibility below
        floor["render"]["pbl"]["surface_paths"] = k
        runs = []
        for out in _seed_renders(tmp_path, floor, spp=4):
            img, meta = read_exr(out)
            runs.append(img.astype(float).mean())
            if k == 0:
                ks = [float(v) for v in meta["surface_paths_per_pass"].split(",")]
                assert ks[0] == ks[1] and abs(ks[0] - 8) < 0.5 and min(ks[2:]) > 8, ks
                assert meta["surface_paths"] == pytest.approx(np.mean(ks), rel=1e-3)  # ks: 4 digits each
                assert meta["surface_paths_setting"] == 0
        means[k] = np.array(runs)
    se = math.hypot(means[0].std(ddof=1), means[8].std(ddof=1)) / 2
    print("auto vs 8 paths:", means[0].mean(), means[8].mean(), se)
    assert abs(means[0].mean() - means[8].mean()) < 4 * se + 1e-12
    render_scene(tmp_path / "scene.toml", tmp_path / "p.exr", RenderOptions(method="pbl", spp=4, seed=3,
                                                                           cache_dir=tmp_path, quiet=True))
    assert np.array_equal(read_exr(tmp_path / "p.exr")[0], read_exr(tmp_path / "o.exr")[0])
    # a pilot of one path a pixel pooled over each pixel's neighbours (pilot_pool) places the paths otherwise,
    # and the image keeps its mean
    floor["render"]["pbl"].update(surface_paths=0, pilot_paths=1, pilot_pool=True)
    pooled = np.array([read_exr(out)[0].astype(float).mean() for out in _seed_renders(tmp_path, floor, spp=4)])
    se = math.hypot(pooled.std(ddof=1), means[8].std(ddof=1)) / 2
    assert abs(pooled.mean() - means[8].mean()) < 4 * se + 1e-12, (pooled.mean(), means[8].mean(), se)

    dark = medium_sphere_scene(surface_samples=500, segments_per_beam=2, bounce_samples=64)
    dark["camera"]["resolution"] = [8, 8]
    render_scene(write_scene(tmp_path, dark), tmp_path / "d.exr", RenderOptions(method="pbl", spp=3,
                                                                               cache_dir=tmp_path, quiet=True))
    assert read_exr(tmp_path / "d.exr")[1]["surface_paths_per_pass"] == "8,8,1"
    dark["render"]["pbl"]["first_paths"] = 3  # the first two passes' mean, where the medium's noise rules
    render_scene(write_scene(tmp_path, dark), tmp_path / "d.exr", RenderOptions(method="pbl", spp=3,
                                                                               cache_dir=tmp_path, quiet=True))
    assert read_exr(tmp_path / "d.exr")[1]["surface_paths_per_pass"] == "3,3,1"


@pytest.mark.parametrize("setting", ["roulette_single", "roulette", "surface_roulette"])
def test_roulette_on_weak_branches_keeps_every_layers_mean(tmp_path, setting):
    """roulette_single (single scattering), roulette (the smooth terms) and surface_roulette (whether a branch is
    followed at all) play Russian roulette on weak camera branches, each with a threshold of its own. Inside a
    dielectric sphere the internal reflections are such branches (weight about F = 0.04): at a threshold of 1 every
    branch below full weight plays, the internal legs survive 1 in 25 with 25x the weight, and the single, double
    and surface layers' means stay those of a threshold of 0 (no roulette) within 4 standard errors of the
    seed-to-seed spread."""
    scene = medium_sphere_scene(surface_samples=800, segments_per_beam=4, bounce_samples=64,
                                components=["single", "double"])
    scene["shapes"][0].update(interface="dielectric", eta=1.5)
    scene["lights"].append({"type": "environment", "radiance": 0.3})
    means = {}
    for threshold in (0.0, 1.0):
        scene["render"]["pbl"][setting] = threshold
        runs = [[read_layers(out)[c].astype(float).mean() for c in ("single", "double", "surface")]
                for out in _seed_renders(tmp_path, scene, spp=2, seeds=range(6))]
        means[threshold] = np.array(runs)  # (seed, layer)
    a, b = means[0.0], means[1.0]
    se = np.hypot(a.std(0, ddof=1), b.std(0, ddof=1)) / math.sqrt(len(a))
    print(setting, "single, double, surface: no roulette", a.mean(0), "roulette 1", b.mean(0), "se", se)
    assert np.all(a.mean(0) > 0) and np.all(se > 0)
    assert np.all(np.abs(a.mean(0) - b.mean(0)) < 4 * se), (a.mean(0), b.mean(0), se)


def test_single_scattering_deferred_over_batches_is_the_same_flushed_often(tmp_path, monkeypatch):
    """The lights' single scattering of a pass is evaluated for many camera batches at once (gather.DeferredSingle),
    flushed when it holds DEFERRED_POINTS points: with batches of 64 paths and a flush every 100 points the single
    layer is the one of a single flush (each point's sum is its own; without roulette nothing else depends on the
    batches)."""
    import pbvol_cli.pointbased.camera_pass as camera_pass
    import pbvol_cli.pointbased.gather as gather

    scene = medium_sphere_scene(surface_samples=800, segments_per_beam=4, components=["single"])
    scene["shapes"][0].update(interface="dielectric", eta=1.5)
    scene["render"]["pbl"]["roulette_single"] = 0.0
    flushes = []
    flush = gather.DeferredSingle.flush
    monkeypatch.setattr(gather.DeferredSingle, "flush", lambda self, *a: (flushes.append(self.count), flush(self, *a)))
    layers = []
    for chunk, points in ((camera_pass.CAMERA_CHUNK, gather.DEFERRED_POINTS), (64, 100)):
        monkeypatch.setattr(camera_pass, "CAMERA_CHUNK", chunk)
        monkeypatch.setattr(gather, "DEFERRED_POINTS", points)
        flushes.clear()
        out = next(_seed_renders(tmp_path, scene, spp=1, seeds=[3]))
        layers.append(read_layers(out)["single"].astype(float))
        print(chunk, points, "flushes", len(flushes), "points", sum(flushes))
        assert len(flushes) == 1 if chunk > 64 else len(flushes) >= 3 and min(flushes[:-1]) >= 100
    assert layers[0].sum() > 0
    np.testing.assert_allclose(layers[1], layers[0], rtol=1e-6, atol=0.0)


def test_smooth_terms_of_a_pass_are_binned_together_whatever_its_batches(tmp_path, monkeypatch):
    """The smooth terms of a pass's camera segments are binned and evaluated together (radiance_cache.DeferredBins),
    not batch by batch: with the medium's paths in batches of 50 the double, multiple and bounced layers are those
    of one batch bit for bit (without roulette nothing else depends on the batches), and the pass evaluates the
    bins once, however many batches and depths fed them."""
    import pbvol_cli.pointbased.camera_pass as camera_pass
    import pbvol_cli.pointbased.radiance_cache as radiance_cache

    scene = medium_sphere_scene(surface_samples=800, segments_per_beam=4, surface_paths=1)
    scene["shapes"][0].update(interface="dielectric", eta=1.5)
    scene["render"]["pbl"].update(roulette=0.0, roulette_single=0.0, surface_roulette=0.0)
    flushes = []
    flush = radiance_cache.DeferredBins.flush
    monkeypatch.setattr(radiance_cache.DeferredBins, "flush",
                        lambda self, *a: (flushes.append(self.count), flush(self, *a))[1])
    layers = []
    for chunk in (camera_pass.CAMERA_CHUNK, 50):  # (144 pixels: three batches of 50)
        monkeypatch.setattr(camera_pass, "CAMERA_CHUNK", chunk)
        flushes.clear()
        layers.append(read_layers(next(_seed_renders(tmp_path, scene, spp=1, seeds=[4]))))
        assert len(flushes) == 1 and flushes[0] > 144, flushes  # one evaluation of every depth's points
    for name in ("double", "multiple", "bounced"):
        assert layers[0][name].sum() > 0, name
        np.testing.assert_allclose(layers[1][name], layers[0][name], rtol=1e-6, atol=0.0, err_msg=name)


def test_add_rows_sums_repeated_rows_in_order_as_numpy_add_at():
    rng = np.random.default_rng(5)
    index = rng.integers(0, 7, 200)
    values = rng.normal(size=(200, 3)) * 10.0 ** rng.integers(-8, 8, (200, 1))
    expected, got = np.ones((7, 3)), np.ones((7, 3))
    np.add.at(expected, index, values)
    add_rows(got, index, values)
    assert np.array_equal(got, expected)  # the same additions in the same order
    add_rows(got, index[:0], values[:0])
    assert np.array_equal(got, expected)


def test_surface_only_batches_of_any_size_give_the_same_image(tmp_path, monkeypatch):
    """The surface-only camera paths are traced in batches of SURFACE_CHUNK (memory): batches of 64 give the
    image of one batch bit for bit (their light is their own; the medium's paths keep their batches of 100)."""
    import pbvol_cli.pointbased.camera_pass as camera_pass

    assert camera_pass.batch_bounds(10, 3, 4, 2) == [(0, 4), (4, 6), (6, 8), (8, 10)]
    assert camera_pass.batch_bounds(10, 0, 4, 3) == [(0, 3), (3, 6), (6, 9), (9, 10)]
    scene = medium_sphere_scene(surface_samples=800, segments_per_beam=4, surface_paths=8)
    scene["shapes"][0].update(interface="dielectric", eta=1.5)
    scene["lights"].append({"type": "environment", "radiance": 0.3})
    monkeypatch.setattr(camera_pass, "CAMERA_CHUNK", 100)  # (144 pixels: the medium's paths in two batches)
    images, batches = [], []
    trace = camera_pass._trace_batch
    monkeypatch.setattr(camera_pass, "_trace_batch", lambda *a, **k: (batches.append(len(a[7])), trace(*a, **k))[1])
    for size in (camera_pass.SURFACE_CHUNK, 64):
        monkeypatch.setattr(camera_pass, "SURFACE_CHUNK", size)
        images.append(read_exr(next(_seed_renders(tmp_path, scene, spp=2, seeds=[5])))[0])
    assert images[0].max() > 0 and np.array_equal(images[0], images[1])
    assert 64 in batches and max(batches) > 500  # the second render did cut the surface-only paths in 64s


def test_a_render_is_the_same_bit_for_bit_on_one_two_or_three_threads(tmp_path):
    """The README's promise for pbl: a sphere behind glass over a diffuse floor (single scattering by samples,
    the bins with term shares and extra evaluations, the terms after a diffuse bounce, the bounced light), two
    passes with auto path counts, rendered on 1, 2 and 3 threads: every layer the same bit for bit (the threads
    take the bins' representatives in parts as they come free, a segment's random state in one part)."""
    scene = _floor_scene()
    scene["shapes"][0].update(interface="dielectric", eta=1.5)
    scene["render"]["pbl"].update(bin_splits=0.5)
    path = write_scene(tmp_path, scene)
    layers = []
    for threads in (1, 2, 3):
        out = tmp_path / f"t{threads}.exr"
        render_scene(path, out, RenderOptions(method="pbl", spp=2, seed=5, threads=threads, cache_dir=tmp_path,
                                              quiet=True))
        layers.append(read_layers(out))
    for name in ("surface", "single", "double", "multiple", "bounced"):
        assert layers[0][name].sum() > 0, name
        for other in layers[1:]:
            assert np.array_equal(other[name], layers[0][name]), name
