"""The multiple term's image planes on curved boundaries: 0.25 transport mean free paths out on small bodies, toward
diffusion's 0.7104 on bodies many diffusion lengths thick."""

from pathlib import Path

import numpy as np
import pytest

from pbvol_cli import config as C
from pbvol_cli.geometry.scene_build import build_scene
from pbvol_cli.pointbased.image_planes import (MILNE_EXTRAPOLATION, curved_extrapolation, flat_extrapolation,
                                               medium_extrapolation)
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


@pytest.mark.parametrize("reflects", [True, False])
def test_flat_faces_grow_from_their_own_value_by_the_same_law(reflects):
    """A thick body is flat on the scale its light spreads over whatever its faces' shape: under a flat face the
    images start at the slab's 0.45 and go the same share of the way to the Milne value as the curved parts'."""
    for thickness, albedo in ((5.0, 0.999), (30.0, 0.999), (240.0, 0.999), (5000.0, 0.99), (100.0, 1.0)):
        args = (np.full(3, 1.0 - albedo), np.full(3, albedo), 1.0, thickness, reflects)
        curved, flat = curved_extrapolation(*args)[0], flat_extrapolation(*args)[0]
        share = (curved - CURVED_EXTRAPOLATION) / (MILNE_EXTRAPOLATION - CURVED_EXTRAPOLATION)
        assert flat == pytest.approx(FLAT_FACE_EXTRAPOLATION + share * (MILNE_EXTRAPOLATION
                                                                        - FLAT_FACE_EXTRAPOLATION), abs=1e-12)
        assert FLAT_FACE_EXTRAPOLATION <= flat <= MILNE_EXTRAPOLATION and flat >= curved
    assert flat_extrapolation(np.full(3, 0.01), np.full(3, 0.99), 1.0, 5000.0, reflects)[0] == pytest.approx(
        MILNE_EXTRAPOLATION, abs=1e-6)
