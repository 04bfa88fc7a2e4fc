"""The multiple term's image planes: 0.25 transport mean free paths out under curved boundaries of small bodies and
0.45 under flat faces, toward diffusion's 0.7104 on bodies many diffusion lengths thick."""

from pathlib import Path

import numpy as np
import pytest

from conftest import write_scene
from pbvol_cli import config as C
from pbvol_cli.geometry.scene_build import build_scene
from pbvol_cli.imageio import read_exr
from pbvol_cli.pipeline.render import RenderOptions, render_scene
from pbvol_cli.pointbased.image_planes import (FLAT_SCALE, MILNE_EXTRAPOLATION, curved_extrapolation,
                                               flat_extrapolation, medium_extrapolation)
from pbvol_cli.pointbased.volume_samples import (CURVED_EXTRAPOLATION, DEFAULT_IMAGE_K, FLAT_FACE_EXTRAPOLATION,
                                                 IMAGE_CURVED, IMAGE_FLAT)

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def grey(thickness, albedo, reflects):
    """k of a grey isotropic body `thickness` reduced mean free paths thick (sigma'_t = 1)."""
    return curved_extrapolation(np.full(3, 1.0 - albedo), np.full(3, albedo), 1.0, thickness, reflects)


def test_the_examples_pbl_was_measured_on_keep_the_small_bodies_values():
    """Every example thinner than the gate keeps exactly 0.25 where its boundary curves and 0.45 on its flat faces
    (their images, and what docs/pbl.md measured on them, are unchanged); the marble bunny, 53-73 reduced mean free
    paths thick, grows toward the Milne value."""
    grown = {}
    for path in sorted(CONFIGS.glob("*.toml")):
        b = build_scene(C.load_scene(path), path, (8, 8))
        for m in range(len(b.medium_info)):
            if b.medium_info[m].material.density is not None:
                continue
            k = medium_extrapolation(b, m)
            assert k.shape == (2, 3)
            if path.stem != "marble_bunny":
                assert np.all(k == DEFAULT_IMAGE_K), (path.stem, k)
            grown[path.stem] = k
    k = grown["marble_bunny"][IMAGE_CURVED]
    assert np.all((k > 0.3) & (k < 0.55)) and k[0] < k[1] < k[2], k  # red diffuses farthest: least grown
    flat = grown["marble_bunny"][IMAGE_FLAT]
    assert np.all((flat > FLAT_FACE_EXTRAPOLATION) & (flat < MILNE_EXTRAPOLATION)) and flat[0] < flat[1] < flat[2]


def test_a_non_absorbing_body_keeps_the_small_bodies_value_at_any_size():
    """Without absorption light spreads over the whole body, whose boundary then always curves away within that
    distance (the furnaces of docs/pbl.md section 11 were measured at 0.25)."""
    for thickness in (5.0, 50.0, 5000.0):
        assert np.all(grey(thickness, 1.0, True) == CURVED_EXTRAPOLATION)


@pytest.mark.parametrize("reflects", [True, False])
def test_the_extrapolation_grows_with_the_body_toward_the_milne_value(reflects):
    ks = [grey(t, 0.999, reflects)[0] for t in (7.0, 15.0, 30.0, 60.0, 120.0, 240.0, 5000.0)]
    assert ks[0] == CURVED_EXTRAPOLATION
    assert all(a < b for a, b in zip(ks[1:], ks[2:])), ks
    assert ks[-1] == pytest.approx(MILNE_EXTRAPOLATION, abs=1e-6)
    # absorption shortens the diffusion length: the same thickness is more diffusion lengths across
    assert grey(30.0, 0.99, reflects)[0] > grey(30.0, 0.999, reflects)[0]


def test_a_reflecting_boundary_grows_first():
    """Behind a reflecting boundary the bounced light's sources lie shallow, and the grey spheres read low from a
    smaller size than index-matched ones (docs/pbl.md section 7)."""
    for thickness in (15.0, 30.0, 60.0, 120.0):
        assert grey(thickness, 0.999, True)[0] > grey(thickness, 0.999, False)[0]


def flat_k(thickness, albedo):
    """k under the flat faces of a grey isotropic body `thickness` reduced mean free paths thick."""
    return flat_extrapolation(np.full(3, 1.0 - albedo), np.full(3, albedo), 1.0, thickness)[0]


def test_flat_faces_reach_the_milne_value_within_a_diffusion_length_of_half_thickness():
    """Under a flat face the images start at the slab's 0.45 (a body thinner than the gate, or one that does not
    absorb, keeps it at any size) and go 1 - 1/e of the way to the Milne value at a half-thickness of FLAT_SCALE
    diffusion lengths: grey boxes of albedo 0.999, 15-60 reduced mean free paths thick, read 0.95, 0.92, 0.88
    index-matched and 0.94, 0.88, 0.85 behind eta 1.5 at the slab's value, 1.15, 1.11, 1.04 and 1.14, 1.08, 1.07 at
    the Milne value (docs/pbl.md section 7)."""
    assert flat_k(5.0, 0.999) == FLAT_FACE_EXTRAPOLATION and flat_k(5000.0, 1.0) == FLAT_FACE_EXTRAPOLATION
    ks = [flat_k(t, 0.999) for t in (15.0, 30.0, 60.0, 240.0, 5000.0)]
    assert all(a < b for a, b in zip(ks, ks[1:])), ks
    assert ks[-1] == pytest.approx(MILNE_EXTRAPOLATION, abs=1e-6)
    x = 1.0 / (np.sqrt(3.0 * 0.001) * 0.5)  # the thickness whose half is one diffusion length (albedo 0.999)
    share = (flat_k(FLAT_SCALE * x, 0.999) - FLAT_FACE_EXTRAPOLATION) / (MILNE_EXTRAPOLATION - FLAT_FACE_EXTRAPOLATION)
    assert share == pytest.approx(1.0 - np.exp(-1.0), abs=1e-12)


@pytest.mark.parametrize("reflects", [True, False])
def test_flat_faces_go_farther_toward_the_milne_value_than_curved_parts(reflects):
    """A flat face does not fall away from its plane: at every thickness past the gate its images have gone a larger
    share of the way than the curved parts' (the same body, either boundary)."""
    for thickness, albedo in ((15.0, 0.999), (30.0, 0.999), (240.0, 0.999), (60.0, 0.99)):
        args = (np.full(3, 1.0 - albedo), np.full(3, albedo), 1.0, thickness)
        curved = (curved_extrapolation(*args, reflects)[0] - CURVED_EXTRAPOLATION) / (
            MILNE_EXTRAPOLATION - CURVED_EXTRAPOLATION)
        flat_share = (flat_extrapolation(*args)[0] - FLAT_FACE_EXTRAPOLATION) / (
            MILNE_EXTRAPOLATION - FLAT_FACE_EXTRAPOLATION)
        assert flat_share > curved, (thickness, albedo, flat_share, curved)


def _grey_box(thickness: float, interface: str) -> dict:
    """benchmarks/scenes/thick_box.toml's box (30 x 10 x 30 under a sphere light) of a grey medium of albedo 0.999,
    `thickness` reduced mean free paths along its short side, at 16 x 16 pixels (a table of 20 000 particles: the
    test's time)."""
    return {"camera": {"position": [0.0, 30.0, 22.0], "look_at": [0.0, 5.0, 0.0], "fov": 40.0,
                       "resolution": [16, 16]},
            "render": {"spp": 8, "seed": 1, "lut": {"particles": 20000}},
            "lights": [{"type": "sphere", "center": [-8.0, 25.0, 6.0], "radius": 2.0, "radiance": 10.0},
                       {"type": "environment", "radiance": 0.05}],
            "shapes": [{"type": "box", "center": [0.0, 5.0, 0.0], "size": [30.0, 10.0, 30.0], "interface": interface,
                        "eta": 1.5, "medium": {"albedo": 0.999, "mean_free_path": 10.0 / thickness, "g": 0.0}}]}


@pytest.mark.parametrize("interface", ["dielectric", pytest.param("null", marks=pytest.mark.slow)])
def test_a_flat_faced_box_30_thick_reads_volpaths_scattered_light(tmp_path, interface):
    """Under the flat faces' images a box 30 reduced mean free paths thick (half of it 0.82 diffusion lengths) read
    0.88 of volpath's scattered light behind eta 1.5 and 0.92 index-matched; with the images reaching the Milne value
    within a diffusion length (FLAT_SCALE) 1.00 and 1.02 (benchmarks/pbl_thickness.py --boxes 30, docs/pbl.md
    section 7). Here at 16 x 16 pixels, 8 passes, a table of 20 000 particles, against 512 volpath samples, whose
    own noise is a few per cent: 0.991 and 1.017, 0.908 and 0.915 with the curved parts' law on the flat faces."""
    path = write_scene(tmp_path, _grey_box(30.0, interface))
    images = {}
    for name, opts in (("pbl", RenderOptions(method="pbl", cache_dir=tmp_path, quiet=True)),
                       ("volpath", RenderOptions(spp=512, quiet=True)),
                       ("surfaces", RenderOptions(spp=64, orders="0", quiet=True))):
        render_scene(path, tmp_path / f"{name}.exr", opts)
        images[name] = read_exr(tmp_path / f"{name}.exr")[0].astype(float)
    scattered = images["volpath"] - images["surfaces"]
    mask = scattered.mean(axis=2) > 0.05 * scattered.mean(axis=2).max()
    ratio = (images["pbl"] - images["surfaces"])[mask].mean() / scattered[mask].mean()
    print(f"grey box 30 thick, {interface}: pbl / volpath scattered light {ratio:.3f}")
    assert 0.95 < ratio < 1.07, ratio
