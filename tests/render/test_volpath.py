"""The reference path tracer against closed forms, energy conservation and itself."""

import math

import numpy as np
import pytest

from conftest import build, camera, camera_ray, single_scattering_reference, volpath

WHITE_ENV = [{"type": "environment", "radiance": 1.0}]


def _std_error(img):
    """Standard error of the image mean, from the spread of the pixels (pixels are independent)."""
    return img.std(axis=(0, 1)) / math.sqrt(img.shape[0] * img.shape[1])


@pytest.mark.parametrize("eta", [1.0, 1.5])
@pytest.mark.parametrize("g", [-0.5, 0.0, 0.9])
def test_furnace_non_absorbing_sphere(tmp_path, eta, g):
    """alpha = 1 inside a sphere under a uniform white environment: every pixel sees radiance 1."""
    scene = {"camera": camera((16, 16)), "lights": WHITE_ENV,
             "shapes": [{"type": "sphere", "radius": 1.0, "interface": "dielectric", "eta": eta,
                         "medium": {"albedo": 1.0, "mean_free_path": 0.3, "g": g}}]}
    img = volpath(build(tmp_path, scene), spp=32)
    se = np.maximum(_std_error(img), 1e-12)
    assert np.all(np.abs(img.mean(axis=(0, 1)) - 1.0) < 4 * se + 1e-12), (img.mean(axis=(0, 1)), se)
    # no region is biased either: 4x4 blocks agree with 1 within their own noise
    blocks = img.reshape(4, 4, 4, 4, 3).mean(axis=(1, 3))
    block_se = img.reshape(4, 4, 4, 4, 3).std(axis=(1, 3)) / 4
    assert np.all(np.abs(blocks - 1.0) <= 5 * block_se + 1e-12)


def test_furnace_chromatic_medium_is_unbiased(tmp_path):
    """Different sigma_t per channel (spectral MIS) with alpha = 1: still radiance 1 in every channel."""
    scene = {"camera": camera((16, 16)), "lights": WHITE_ENV,
             "shapes": [{"type": "sphere", "radius": 1.0, "interface": "null",
                         "medium": {"sigma_a": 0.0, "sigma_s": [0.5, 3.0, 12.0], "g": 0.5}}]}
    img = volpath(build(tmp_path, scene), spp=32)
    assert np.all(np.abs(img.mean(axis=(0, 1)) - 1.0) < 4 * _std_error(img))


def test_diffuse_sphere_under_white_environment(tmp_path):
    """A convex Lambertian object under a uniform environment reflects albedo x radiance everywhere."""
    alb = [0.2, 0.5, 0.8]
    scene = {"camera": camera((16, 16), position=(0, 0, 2.5)), "lights": WHITE_ENV,
             "shapes": [{"type": "sphere", "radius": 1.0, "interface": "diffuse", "albedo": alb}]}
    img = volpath(build(tmp_path, scene), spp=16)
    inside = img[4:12, 4:12].reshape(-1, 3)
    se = inside.std(0) / math.sqrt(len(inside))
    assert np.all(np.abs(inside.mean(0) - alb) < 4 * se + 1e-12)


def test_diffuse_plane_under_sphere_light_matches_closed_form(tmp_path):
    """Irradiance from a sphere light of radiance L, radius r, centre at distance D, angle theta to the
    normal (fully above the horizon): E = pi L (r/D)^2 cos(theta). Exercises light sampling and MIS."""
    L, r, h, a = 50.0, 0.3, 1.0, 0.6
    # the camera sits between the light and the plane, looking down: the light is behind it
    scene = {"camera": {"position": [0, 0.6, 0.0], "look_at": [0, 0, 0], "up": [0, 0, -1], "fov": 60,
                        "resolution": [16, 16]},
             "lights": [{"type": "sphere", "center": [0, h, 0], "radius": r, "radiance": L}],
             "shapes": [{"type": "quad", "size": [10.0, 10.0], "interface": "diffuse", "albedo": a}]}
    built = build(tmp_path, scene)
    img = volpath(built, spp=64)
    # expected radiance at each pixel: average over a sub-pixel grid of the camera's rays
    cam = built.camera
    W = H = 16
    k = 8
    expected = np.zeros((H, W))
    for py in range(H):
        for px in range(W):
            acc = 0.0
            for sy in range(k):
                for sx in range(k):
                    x = 2 * (px + (sx + 0.5) / k) / W - 1
                    y = 1 - 2 * (py + (sy + 0.5) / k) / H
                    o, d = camera_ray(cam, x, y)
                    p = o - d * o[1] / d[1]  # hit on the plane y = 0
                    to_c = np.array([0, h, 0]) - p
                    D = np.linalg.norm(to_c)
                    acc += a / math.pi * math.pi * L * (r / D) ** 2 * (to_c[1] / D)
            expected[py, px] = acc / (k * k)
    got, exp = img[..., 0].ravel(), expected.ravel()
    assert np.abs(got.mean() - exp.mean()) < 4 * got.std() / math.sqrt(got.size)
    assert np.mean(((got - exp) / exp) ** 2) < 0.01


def test_single_scattering_matches_quadrature(tmp_path):
    """--orders 1 of an index-matched sphere under a directional light against a numerical integral."""
    sigma_s, sigma_a, g = np.array([0.6, 1.0, 2.0]), np.array([0.2, 0.5, 0.1]), 0.5
    light_dir = [-1.0, -0.5, -0.7]
    scene = {"camera": camera((12, 12), position=(0, 0, 3.5), fov=40),
             "lights": [{"type": "directional", "direction": light_dir, "irradiance": 2.0}],
             "shapes": [{"type": "sphere", "radius": 1.0, "interface": "null",
                         "medium": {"sigma_a": sigma_a.tolist(), "sigma_s": sigma_s.tolist(), "g": g}}]}
    built = build(tmp_path, scene)
    a = volpath(built, spp=128, seed=1, orders="1")
    b = volpath(built, spp=128, seed=2, orders="1")
    ref, covered = single_scattering_reference(built, sigma_s, sigma_s + sigma_a, g, light_dir, 2.0, 1.0)
    img = 0.5 * (a + b)
    # per-pixel noise of the average of the two renders, estimated from their difference
    noise_var = ((a - b) ** 2 / 4)[covered].mean(0)
    err = ((img - ref) ** 2)[covered].mean(0)
    # mean squared error = noise variance + bias^2: with no bias it is ~noise_var (chi-square, 2 sigma)
    n = covered.sum()
    assert np.all(err < noise_var * (1 + 2 * math.sqrt(2 / n)) + 1e-3 * ref[covered].mean(0) ** 2), (err, noise_var)
    assert np.all(np.abs(img[covered].mean(0) / ref[covered].mean(0) - 1) < 0.02)


def test_orders_partition_the_full_image(tmp_path):
    """Orders 0, 1, 2 and 3+ rendered separately with the same seed add up to the full render."""
    scene = {"camera": camera((12, 12)), "lights": WHITE_ENV + [{"type": "sphere", "center": [2, 2, 2],
                                                                  "radius": 0.3, "radiance": 20.0}],
             "shapes": [{"type": "sphere", "radius": 1.0, "interface": "null",
                         "medium": {"albedo": [0.9, 0.7, 0.5], "mean_free_path": 0.5, "g": 0.3}}]}
    built = build(tmp_path, scene)
    full = volpath(built, spp=8, seed=3)
    parts = [volpath(built, spp=8, seed=3, orders=o) for o in ("0", "1", "2", "3+")]
    assert np.allclose(sum(parts), full, rtol=1e-9, atol=1e-12)
    assert np.allclose(volpath(built, spp=8, seed=3, orders="1,2"), parts[1] + parts[2], rtol=1e-9, atol=1e-12)
    assert all(p.sum() > 0 for p in parts)


def test_same_seed_same_image_bit_for_bit(tmp_path):
    scene = {"camera": camera((12, 12)), "lights": WHITE_ENV,
             "shapes": [{"type": "sphere", "radius": 1.0, "interface": "dielectric", "eta": 1.3,
                         "medium": {"albedo": [0.9, 0.7, 0.5], "mean_free_path": 0.5, "g": 0.3}},
                        {"type": "quad", "center": [0, -1, 0], "size": [6, 6]}]}
    built = build(tmp_path, scene)
    a = volpath(built, spp=4, seed=11)
    b = volpath(built, spp=4, seed=11)
    c = volpath(built, spp=4, seed=12)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    # the batch size does not change the image
    assert np.array_equal(a, volpath(built, spp=4, seed=11, batch=1024))


def test_splitting_at_smooth_boundaries_is_unbiased_and_quiets_a_lights_images(tmp_path):
    """A glass sphere of an absorbing, scattering medium under a small sphere light and a dim sky, the light's
    mirror image on the glass in view. Following both branches at the first smooth interfaces (split_depth 3),
    everywhere ("all") or only where the reflection points at the light ("lights"), against choosing one (0): the
    image means agree within their standard errors over independent seeds (an analytic sphere and a mesh box). On
    the sphere the noise of the light's images (a chosen reflection carried 1 / F times its share) falls by more
    than 4x either way: on this small sphere the mirror image, which both follow, is most of it ("all" also
    follows the glints inside)."""
    def scene(shape):
        return {"camera": camera((24, 24), position=(0.0, 0.0, 4.0), fov=35),
                "lights": [{"type": "sphere", "center": [2.0, 2.0, 3.0], "radius": 0.15, "radiance": 200.0},
                           {"type": "environment", "radiance": 0.05}],
                "shapes": [{**shape, "interface": "dielectric", "eta": 1.5,
                            "medium": {"albedo": [0.9, 0.6, 0.3], "mean_free_path": 0.8, "g": 0.5}}]}

    modes = {"none": (0, "all"), "all": (3, "all"), "lights": (3, "lights")}
    for shape in ({"type": "sphere", "radius": 1.0}, {"type": "box", "size": [1.4, 1.4, 1.4],
                                                      "transform": {"rotate": [20, 30, 0]}}):
        built = build(tmp_path, scene(shape))
        runs = {m: np.array([volpath(built, spp=64, seed=s, split_depth=d, split_rule=r) for s in range(1, 7)])
                for m, (d, r) in modes.items()}
        for m in ("all", "lights"):
            diff = runs[m].mean(axis=(0, 1, 2)) - runs["none"].mean(axis=(0, 1, 2))
            # standard errors from each pixel's spread over the seeds (pixels are independent; a light met by
            # chance makes the spread of six image means alone an unreliable measure)
            se = np.sqrt(sum(np.var(runs[k], axis=0, ddof=1).sum(axis=(0, 1)) / 6 for k in (m, "none"))) / 576
            assert np.all(np.abs(diff) < 4 * se), (shape["type"], m, diff, se)
        if shape["type"] != "sphere":  # (the box shows no image of the light from here)
            continue
        # the pixels of the light's images on and through the glass: where the unscattered light is bright (an
        # independent render), not where a few scattered paths met the light by chance
        direct = volpath(built, spp=64, seed=99, orders="0").sum(axis=2)
        hot = direct > 0.1 * direct.max()
        spread = {m: np.var(runs[m], axis=0, ddof=1).sum(axis=2)[hot].sum() for m in runs}
        assert 0 < spread["all"] < 0.25 * spread["none"], (shape["type"], spread)
        assert 0 < spread["lights"] < 0.25 * spread["none"], (shape["type"], spread)


def test_mesh_occluder_blocks_light_in_a_scene_without_media(tmp_path):
    """A box between a diffuse floor and the light casts a shadow (no ray may skip a triangle cast)."""
    scene = {"camera": {"position": [0, 0.5, 0.0], "look_at": [0, 0, 0], "up": [0, 0, -1], "fov": 1.0,
                        "resolution": [2, 2]},
             "lights": [{"type": "sphere", "center": [0, 3, 0], "radius": 0.2, "radiance": 50.0}],
             "shapes": [{"type": "quad", "size": [10.0, 10.0], "interface": "diffuse"},
                        {"type": "box", "center": [0, 1.5, 0], "size": [1.0, 0.2, 1.0]}]}
    # direct light only (max_depth 1): the floor under the box sees no light at all
    assert volpath(build(tmp_path, scene), spp=64, max_depth=1).max() == 0.0
    # and with the box moved aside it does
    scene["shapes"][1]["center"] = [3, 1.5, 0]
    assert volpath(build(tmp_path, scene), spp=64, max_depth=1).min() > 0.0


@pytest.mark.parametrize("eta", [1.0, 1.5])
def test_furnace_medium_inside_a_mesh(tmp_path, eta):
    """The same furnace through a triangle mesh (box): exercises the distance grid and mesh medium tracking."""
    scene = {"camera": camera((16, 16), position=(1.0, 1.5, 4.0)), "lights": WHITE_ENV,
             "shapes": [{"type": "box", "size": [1.6, 1.2, 1.4], "interface": "dielectric", "eta": eta,
                         "transform": {"rotate": [10, 25, 0]},
                         "medium": {"albedo": 1.0, "mean_free_path": 0.2, "g": 0.5}}]}
    img = volpath(build(tmp_path, scene), spp=16)
    if eta == 1.5:
        assert np.allclose(img, 1.0, rtol=1e-9)  # no NEE through a refracting boundary: every path returns 1
    else:
        assert np.all(np.abs(img.mean(axis=(0, 1)) - 1.0) < 4 * _std_error(img))


def test_furnace_nested_glass_of_non_absorbing_liquid(tmp_path):
    """A cup (glass eta 1.5) holding a non-absorbing liquid (eta 1.33) under a white environment: the three
    interfaces must track media consistently, so every pixel is exactly 1."""
    scene = {"camera": camera((16, 16), position=(0.0, 2.0, 6.0)), "lights": WHITE_ENV,
             "shapes": [{"type": "cup", "radius": 1.0, "height": 2.0, "wall": 0.1, "bottom": 0.2,
                         "interface": "dielectric", "eta": 1.5, "fill": 0.6, "segments": 64,
                         "liquid": {"albedo": 1.0, "mean_free_path": 0.3, "g": 0.7, "eta": 1.33}}]}
    img = volpath(build(tmp_path, scene), spp=8)
    assert np.allclose(img, 1.0, rtol=1e-9)


def test_time_limit_stops_after_whole_passes(tmp_path):
    from pbvol_cli.render.volpath import render_volpath

    scene = {"camera": camera((16, 16)), "lights": WHITE_ENV,
             "shapes": [{"type": "sphere", "radius": 1.0, "interface": "dielectric", "eta": 1.5,
                         "medium": {"albedo": 0.99, "mean_free_path": 0.05}}]}
    built = build(tmp_path, scene)
    img, spp, stats = render_volpath(built, 100000, 1, 100000, 8, None, 256, 2, time_limit=0.2)
    assert 1 <= spp < 100000
    assert stats["paths"] == spp * 256
    assert np.all(np.isfinite(img))


def test_black_surface_ends_paths_instead_of_dividing_by_zero(tmp_path):
    """A black diffuse floor (albedo 0) under a medium: paths leaving it carry nothing and once reached the
    medium's spectral-MIS weights with a zero sum (ZeroDivisionError, a traceback). They end; the image is the
    same as with the floor's light simply absent: finite, the medium lit, the floor's own pixels black."""
    scene = {"camera": camera((12, 12), position=(0.0, 2.0, 4.0)), "render": {"spp": 8},
             "lights": [{"type": "environment", "radiance": 1.0}],
             "shapes": [{"type": "quad", "center": [0, -1.0, 0], "size": [20.0, 20.0], "interface": "diffuse",
                         "albedo": 0.0},
                        {"type": "sphere", "radius": 0.8, "interface": "null",
                         "medium": {"albedo": 0.9, "mean_free_path": 0.5}}]}
    img = volpath(build(tmp_path, scene), spp=8, rr_depth=1000)
    assert np.all(np.isfinite(img))
    assert img[6, 6].mean() > 0.05  # the medium, lit by the sky
    assert img[11, 0].max() == 0.0  # the floor, seen beside the sphere: black
