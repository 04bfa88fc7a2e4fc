"""Heterogeneous and emissive media in the path tracer against closed forms (render/media.py): transmittance
through a density grid and an exponential density, emission, a constant grid against the homogeneous medium, a
furnace, the scattering orders adding up; and the file errors of a grid."""

import math

import numpy as np
import pytest

from conftest import build, camera, camera_ray, volpath, write_scene
from pbvol_cli.errors import ConfigError, PbvolError
from pbvol_cli.pipeline.render import RenderOptions, render_scene

# a box [-1, 1]^3 seen end-on from far away: every pixel's rays cross it along z
BOX_CAMERA = camera((8, 8), position=(0.0, 0.0, 20.0), fov=4.0)
Z_PROFILE = np.array([0.0, 0.5, 1.0, 2.0, 3.0, 1.0, 0.2, 0.0])  # a grid's voxels along z
HEAT = np.array([0.0, 0.0, 1.0, 4.0, 2.0, 1.0, 0.0, 0.0])  # an emission grid's


def box_scene(medium, sky=1.0):
    return {"camera": BOX_CAMERA, "render": {"spp": 1}, "lights": [{"type": "environment", "radiance": sky}],
            "shapes": [{"type": "box", "size": [2.0, 2.0, 2.0], "interface": "null", "medium": medium}]}


def box_segment(o, d):
    """Entry and exit distances of the ray o + s d (d unit) through [-1, 1]^3."""
    t0 = (-1 - o) / d
    t1 = (1 - o) / d
    return np.max(np.minimum(t0, t1)), np.min(np.maximum(t0, t1))


def per_pixel(built, radiance_along, k=4):
    """Each pixel's mean of radiance_along(o, d) over k x k rays spread over it (the renderer jitters within the
    pixel)."""
    W, H = built.resolution
    out = np.zeros((H, W, 3))
    for py in range(H):
        for px in range(W):
            acc = np.zeros(3)
            for sy in range(k):
                for sx in range(k):
                    x = 2 * (px + (sx + 0.5) / k) / W - 1
                    y = 1 - 2 * (py + (sy + 0.5) / k) / H
                    o, d = camera_ray(built.camera, x, y)
                    acc += radiance_along(o, d / np.linalg.norm(d))
            out[py, px] = acc / k / k
    return out


def assert_rows_match(img, ref):
    """Each image row's mean against the closed form's within 4 standard errors (plus 0.5 % for the quadrature):
    the scenes vary along rows only, so a row's 8 pixels are 8 independent estimates of nearly one value and their
    spread measures the noise (the tracking estimators' variance depends on how tight the majorants are)."""
    rows, ref_rows = img.mean(1), ref.mean(1)
    se = img.std(1, ddof=1) / np.sqrt(img.shape[1]) + np.abs(ref - ref_rows[:, None, :]).max(1)
    assert np.all(np.abs(rows - ref_rows) <= 4 * se + 0.005 * ref_rows), (rows, ref_rows, se)
    se_image = np.sqrt((se ** 2).sum(0)) / len(rows)
    assert np.all(np.abs(rows.mean(0) - ref_rows.mean(0)) <= 4 * se_image + 0.005 * ref_rows.mean(0))


def march(o, d, density, emission=lambda p: 0.0, sky=1.0, n=4000):
    """Radiance through the box of an absorbing medium (sigma_a = density(p)) that emits density(p) emission(p),
    by the midpoint rule: sky e^(-tau) + int e^(-tau(s)) sigma_a L_e ds. density and emission take (n, 3)
    points."""
    a, b = box_segment(o, d)
    s = a + (np.arange(n) + 0.5) / n * (b - a)
    p = o[None, :] + s[:, None] * d[None, :]
    sig = density(p)
    src = sig * emission(p)
    ds = (b - a) / n
    tau = np.cumsum(sig) * ds - 0.5 * sig * ds  # optical depth to each midpoint
    return np.full(3, sky * math.exp(-sig.sum() * ds) + float(np.sum(np.exp(-tau) * src) * ds))


def z_grid(z, values):
    """A (1, 1, n) grid over [-1, 1] at z: linear between voxel centres, clamped to the end voxels."""
    n = len(values)
    centres = -1 + (np.arange(n) + 0.5) * 2 / n
    return np.interp(z, centres, values)


def test_grid_transmittance_and_emission(tmp_path):
    """An absorbing grid (sigma_a = the grid, 1 per unit) with an emission grid, against marching the same
    trilinear field."""
    np.savez(tmp_path / "g.npz", density=Z_PROFILE.reshape(1, 1, -1), heat=HEAT.reshape(1, 1, -1))
    medium = {"albedo": 0.0, "mean_free_path": 1.0, "emission": [0.5, 1.0, 2.0],
              "density": {"type": "grid", "file": "g.npz", "bounds": [[-1, -1, -1], [1, 1, 1]],
                          "emission_key": "heat"}}
    bs = build(tmp_path, box_scene(medium))
    img = volpath(bs, spp=1024, seed=1)
    ref_t = per_pixel(bs, lambda o, d: march(o, d, lambda p: z_grid(p[:, 2], Z_PROFILE)))
    ref_e = per_pixel(bs, lambda o, d: march(o, d, lambda p: z_grid(p[:, 2], Z_PROFILE),
                                             lambda p: z_grid(p[:, 2], HEAT), sky=0.0))
    ref = ref_t + ref_e[..., :1] * np.array([0.5, 1.0, 2.0])
    assert 0.05 < ref_t.mean() < 0.5  # the grid is neither transparent nor opaque
    assert_rows_match(img, ref)


def test_exponential_transmittance(tmp_path):
    """a e^(-b h), h along y from y = -1: rows of the image see different optical depths (0.2 to 4)."""
    medium = {"albedo": 0.0, "mean_free_path": 1.0,
              "density": {"type": "exponential", "a": 2.0, "b": 1.5, "up": [0.0, 2.0, 0.0], "origin": [0, -1, 0]}}
    bs = build(tmp_path, box_scene(medium))
    img = volpath(bs, spp=1024, seed=1)
    ref = per_pixel(bs, lambda o, d: march(o, d, lambda p: 2.0 * np.exp(-1.5 * (p[:, 1] + 1))))
    assert ref[:, :, 0].max() / ref[:, :, 0].min() > 5
    assert_rows_match(img, ref)


def test_emissive_homogeneous_medium(tmp_path):
    """L_e (1 - e^(-sigma_a l)) + sky e^(-sigma_a l) through a homogeneous, non-scattering, emissive box."""
    medium = {"albedo": 0.0, "mean_free_path": 0.7, "emission": [2.0, 1.0, 0.5]}
    bs = build(tmp_path, box_scene(medium, sky=0.3))
    img = volpath(bs, spp=1024, seed=1)

    def exact(o, d):
        a, b = box_segment(o, d)
        t = math.exp(-(b - a) / 0.7)
        return np.array([2.0, 1.0, 0.5]) * (1 - t) + 0.3 * t

    assert_rows_match(img, per_pixel(bs, exact))


def sphere_scene(medium, sky_only=False):
    lights = [{"type": "environment", "radiance": 1.0}]
    if not sky_only:
        lights.insert(0, {"type": "sphere", "center": [2.0, 2.0, 2.0], "radius": 0.5, "radiance": 10.0})
    return {"camera": camera((12, 12), position=(0, 0, 4.0), fov=40), "render": {"spp": 1}, "lights": lights,
            "shapes": [{"type": "sphere", "radius": 1.0, "interface": "null", "medium": medium}]}


def test_constant_grid_equals_the_homogeneous_medium(tmp_path):
    """Delta tracking through a grid of ones against the homogeneous medium's analytic free flights (RGB
    coefficients, anisotropic phase, a light seen through the medium): image means within 1 % (noise 0.3 %)."""
    np.savez(tmp_path / "ones.npz", density=np.ones((3, 4, 5)))
    med = {"albedo": [0.8, 0.6, 0.4], "mean_free_path": [0.5, 0.3, 0.8], "g": 0.3}
    grid = dict(med, density={"type": "grid", "file": "ones.npz", "bounds": [[-1, -1, -1], [1, 1, 1]]})
    a = volpath(build(tmp_path, sphere_scene(med)), spp=512, seed=1)
    b = volpath(build(tmp_path, sphere_scene(grid)), spp=512, seed=2)
    np.testing.assert_allclose(b.mean((0, 1)), a.mean((0, 1)), rtol=0.01)


def test_furnace_grid_albedo_one(tmp_path):
    """A non-absorbing medium of varying density under a white sky: every pixel 1 (the image's mean within 1 %,
    its noise about 0.3 %; single pixels carry about 5 % at 128 spp)."""
    rng = np.random.default_rng(4)
    np.savez(tmp_path / "cloud.npz", density=rng.random((6, 6, 6)) * 3)
    med = {"albedo": 1.0, "mean_free_path": 0.3, "g": 0.5,
           "density": {"type": "grid", "file": "cloud.npz", "bounds": [[-1, -1, -1], [1, 1, 1]]}}
    img = volpath(build(tmp_path, sphere_scene(med, sky_only=True)), spp=128, seed=1)
    assert abs(img.mean() - 1) < 0.01 and abs(np.median(img) - 1) < 0.03, (img.mean(), np.median(img))


def test_orders_add_up_in_a_heterogeneous_medium(tmp_path):
    """Renders restricted to 0, 1, 2 and 3+ scattering events add up to the whole render exactly (the random
    numbers a path draws do not depend on the filter), emission included."""
    med = {"albedo": 0.7, "mean_free_path": 0.4, "emission": [0.2, 0.1, 0.0],
           "density": {"type": "exponential", "a": 1.5, "b": 1.0}}
    bs = build(tmp_path, sphere_scene(med))
    whole = volpath(bs, spp=8, seed=3)
    parts = sum(volpath(bs, spp=8, seed=3, orders=o) for o in ("0", "1", "2", "3+"))
    np.testing.assert_allclose(parts, whole, rtol=1e-9, atol=1e-12)


def test_pbl_and_dipole_refuse_heterogeneous_media(tmp_path):
    med = {"albedo": 0.7, "mean_free_path": 0.4, "density": {"type": "exponential", "a": 1.5, "b": 1.0}}
    path = write_scene(tmp_path, sphere_scene(med))
    for method in ("pbl", "dipole"):
        with pytest.raises(PbvolError, match="volpath"):
            render_scene(path, tmp_path / "o.exr", RenderOptions(method=method, cache_dir=tmp_path, quiet=True))


@pytest.mark.parametrize("content,needle", [
    ({"nope": np.ones((2, 2, 2))}, "no array 'density'"),
    ({"density": np.ones((2, 2))}, "3D numeric"),
    ({"density": -np.ones((2, 2, 2))}, "negative or non-finite"),
    ({"density": np.full((2, 2, 2), np.nan)}, "negative or non-finite"),
])
def test_bad_grid_files(tmp_path, content, needle):
    np.savez(tmp_path / "g.npz", **content)
    med = {"albedo": 0.5, "mean_free_path": 1.0,
           "density": {"type": "grid", "file": "g.npz", "bounds": [[-1, -1, -1], [1, 1, 1]]}}
    with pytest.raises(ConfigError, match=needle) as e:
        build(tmp_path, box_scene(med))
    assert "scene.toml" in str(e.value) and "density" in str(e.value)


def test_vdb_and_missing_files(tmp_path):
    for name, needle in (("smoke.vdb", "OpenVDB"), ("missing.npz", "file not found")):
        med = {"albedo": 0.5, "mean_free_path": 1.0,
               "density": {"type": "grid", "file": name, "bounds": [[-1, -1, -1], [1, 1, 1]]}}
        with pytest.raises(ConfigError, match=needle):
            build(tmp_path, box_scene(med))


def test_majorant_cells_bound_the_field(tmp_path):
    """At random points, the majorant cell holding each (majorant_flight with a vanishing optical depth) is at
    least sigma_t there, for a grid holding a blob of smoke and for an exponential; the cells are tighter than one
    global bound over most of the volume (the blob's empty surroundings, the fog's upper part)."""
    from pbvol_cli.geometry.scene_build import MED_MAJORANT
    from pbvol_cli.render.media import density_at, majorant_flight

    rng = np.random.default_rng(5)
    c = [(np.arange(k) + 0.5) / k for k in (20, 9, 13)]
    x, y, z = np.meshgrid(*c, indexing="ij")
    blob = np.exp(-((x - 0.3) ** 2 + (y - 0.6) ** 2 + (z - 0.5) ** 2) / 0.02) * (1 + 0.2 * rng.random(x.shape))
    np.savez(tmp_path / "r.npz", density=blob)
    for density in ({"type": "grid", "file": "r.npz", "bounds": [[-1, -1, -1], [1, 1, 1]]},
                    {"type": "exponential", "a": 3.0, "b": 2.5, "up": [0.3, 1.0, 0.2]}):
        med = {"albedo": [0.5, 0.7, 0.9], "mean_free_path": [0.2, 0.3, 0.5], "density": density}
        bs = build(tmp_path, box_scene(med))
        st = float(np.max(bs.media[0, 0:3] + bs.media[0, 3:6]))
        cells = []
        for p in rng.uniform(-0.999, 0.999, (2000, 3)):
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            t, mu = majorant_flight(bs.media, bs.density_data, 0, *p, *d, 1e-12)
            sigma = density_at(bs.media, bs.density_data, 0, *p)[0] * st
            if t < 1e-6:  # the cell holding p: at least sigma_t
                assert mu >= sigma * (1 - 1e-12)
            else:  # its cell's majorant is under 1e-6 (the walk went on): so is sigma_t
                assert sigma < 1e-6
                mu = 0.0
            cells.append(mu)
        assert np.median(cells) < 0.5 * bs.media[0, MED_MAJORANT]
