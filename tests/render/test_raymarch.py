"""The ray-marching integrator (render/raymarch.py, `--method raymarch`): emission and absorption against closed
forms with the step error shrinking as the step's square, an emissive furnace, single scattering against volpath
restricted to one scattering event (homogeneous and heterogeneous), surfaces lit through a fog behind a null
boundary against volpath's unscattered light, reproducibility."""

import numpy as np
import pytest

from conftest import build, camera, render_layers, volpath, write_scene
from pbvol_cli.errors import PbvolError
from pbvol_cli.pipeline.render import RenderOptions, render_scene
from test_media import HEAT, Z_PROFILE, box_scene, march, per_pixel, sphere_scene, z_grid


def raymarch(tmp_path, scene, spp, seed=1, **settings):
    """The layers of a raymarch render ({"volume", "surface"}: (H, W, 3)) and their sum under "image"."""
    return render_layers(tmp_path, scene, "raymarch", spp, seed, **settings)


def test_emission_and_absorption_converge_with_the_step(tmp_path):
    """An absorbing grid with an emission grid, against marching the same trilinear field finely: the largest
    pixel error is below 1e-3 at step 0.02 and falls by more than 8x from step 0.1 to 0.02 (midpoint
    transmittance: the error goes as the step squared, 25x; the stratified emission is unbiased)."""
    np.savez(tmp_path / "g.npz", density=Z_PROFILE.reshape(1, 1, -1), heat=HEAT.reshape(1, 1, -1))
    medium = {"albedo": 0.0, "mean_free_path": 1.0, "emission": [0.5, 1.0, 2.0],
              "density": {"type": "grid", "file": "g.npz", "bounds": [[-1, -1, -1], [1, 1, 1]],
                          "emission_key": "heat"}}
    scene = box_scene(medium)
    bs = build(tmp_path, scene)
    ref_t = per_pixel(bs, lambda o, d: march(o, d, lambda p: z_grid(p[:, 2], Z_PROFILE)))
    ref_e = per_pixel(bs, lambda o, d: march(o, d, lambda p: z_grid(p[:, 2], Z_PROFILE),
                                             lambda p: z_grid(p[:, 2], HEAT), sky=0.0))
    ref = ref_t + ref_e[..., :1] * np.array([0.5, 1.0, 2.0])
    err = {step: np.abs(raymarch(tmp_path, scene, 16, step=step)["image"] / ref - 1).max() for step in (0.1, 0.02)}
    assert err[0.02] < 1e-3 and err[0.1] > 8 * err[0.02], err


def test_emissive_furnace(tmp_path):
    """A non-scattering medium emitting L_e under a sky of L_e: L_e (1 - T) + L_e T = L_e in every pixel, in
    expectation over the stratified offsets (the marched transmittance of a homogeneous medium is exact, the
    emission a Riemann sum at random offsets): the image mean within 4 standard errors of L_e, the standard error
    measured from the 64 pixels' spread (about 0.3 %)."""
    medium = {"albedo": 0.0, "mean_free_path": 0.5, "emission": [0.5, 0.5, 0.5]}
    img = raymarch(tmp_path, box_scene(medium, sky=0.5), 32, step=0.3)["image"][..., 0]
    se = img.std(ddof=1) / np.sqrt(img.size)
    assert abs(img.mean() - 0.5) < 4 * se and se < 0.005 * 0.5, (img.mean(), se)


@pytest.mark.parametrize("medium", [
    {"albedo": 0.8, "mean_free_path": 2.0, "g": 0.3},
    {"albedo": 0.9, "mean_free_path": 1.0, "g": 0.3, "density": {"type": "exponential", "a": 1.0, "b": 1.0}},
], ids=["homogeneous", "exponential"])
def test_single_scattering_matches_volpath_order_one(tmp_path, medium):
    """A thin medium in a null sphere under a sphere light and a sky: the volume layer (single scattering, default
    step) against `volpath --orders 1` (2048 samples: its mean's noise about 0.2 %). Four seeds of 64 passes give
    the ray marcher's noise; the means agree within 4 of its standard errors plus 1 % for the reference and the
    step."""
    scene = sphere_scene(medium)
    ref = volpath(build(tmp_path, scene), spp=2048, seed=1, orders="1").mean()
    means = np.array([raymarch(tmp_path, scene, 64, seed=s)["volume"].mean() for s in range(4)])
    se = means.std(ddof=1) / 2
    assert abs(means.mean() - ref) < 4 * se + 0.01 * ref, (means, ref, se)
    assert se < 0.01 * ref  # the check has teeth: the noise is small against the signal


def test_surfaces_lit_through_fog_behind_a_null_boundary(tmp_path):
    """A floor inside an exponential fog bounded by a null box, under a sphere light outside it: the surface
    layer (shadow rays through the null boundary, their transmittance marched) against `volpath --orders 0` (the
    light not scattered by the medium): means within 1.5 % (the noise of either is about 0.3 %), and a floor
    cut off from the light by an opaque boundary instead gets none."""
    fog = {"albedo": 0.9, "mean_free_path": 3.0, "g": 0.3,
           "density": {"type": "exponential", "a": 1.0, "b": 0.8, "origin": [0, -1, 0]}}
    scene = {"camera": camera((12, 12), position=(0, 1.0, 4.0), fov=50), "render": {"spp": 1},
             "materials": {"fog": fog},
             "lights": [{"type": "sphere", "center": [1.0, 4.0, 1.0], "radius": 0.5, "radiance": 20.0}],
             "shapes": [{"type": "box", "size": [4.0, 2.0, 4.0], "interface": "null", "medium": "fog"},
                        {"type": "quad", "center": [0, -0.99, 0], "size": [3.8, 3.8], "interface": "diffuse",
                         "albedo": 0.5, "exterior_medium": "fog"}]}
    ref = volpath(build(tmp_path, scene), spp=1024, seed=1, orders="0").mean()
    surface = raymarch(tmp_path, scene, 16)["surface"].mean()
    assert ref > 0.005 and abs(surface / ref - 1) < 0.015, (surface, ref)
    scene["lights"].append({"type": "environment", "radiance": 0.0})
    scene["shapes"].append({"type": "quad", "center": [0, 1.2, 0], "size": [8.0, 8.0], "interface": "diffuse",
                            "albedo": 0.0})  # a black ceiling between the light and the fog
    assert raymarch(tmp_path, scene, 4)["surface"].max() == 0.0


def test_reproducible_and_components_refused(tmp_path):
    medium = {"albedo": 0.9, "mean_free_path": 1.0, "emission": [0.1, 0.0, 0.0],
              "density": {"type": "exponential", "a": 1.0, "b": 1.0}}
    scene = sphere_scene(medium)
    a, b = raymarch(tmp_path, scene, 2, seed=3), raymarch(tmp_path, scene, 2, seed=3)
    assert np.array_equal(a["image"], b["image"]) and a["volume"].max() > 0
    path = write_scene(tmp_path, scene)
    with pytest.raises(PbvolError, match="--components"):
        render_scene(path, tmp_path / "x.exr", RenderOptions(method="raymarch", components="single", quiet=True))
