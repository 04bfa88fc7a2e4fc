"""The flat faces of a medium's boundary, where the multiple term's images lie farther out."""

import numpy as np

from conftest import camera, write_scene
from pbvol_cli import config as C
from pbvol_cli.geometry.scene_build import build_scene
from pbvol_cli.pointbased.flat_faces import FLAT_MIN_RADIUS, flat_faces, medium_faces
from pbvol_cli.pointbased.sources import on_flat_face

MEDIUM = {"sigma_s": 2.0, "sigma_a": 0.0, "g": 0.5}  # transport mean free path 1


def _built(tmp_path, shapes):
    scene = {"camera": camera(), "lights": [{"type": "environment", "radiance": 1.0}], "shapes": shapes}
    path = write_scene(tmp_path, scene)
    return build_scene(C.load_scene(path), path)


def test_a_glass_of_liquid_has_its_free_surface_and_its_floor_as_flat_faces(tmp_path):
    bs = _built(tmp_path, [{"type": "cup", "center": [0.0, 0.0, 0.0], "radius": 3.0, "height": 6.0, "wall": 0.2,
                            "bottom": 0.5, "fill": 0.5, "liquid": MEDIUM, "interface": "dielectric"}])
    faces = medium_faces(bs, 0)
    assert faces.shape == (2, 5)
    np.testing.assert_allclose(np.abs(faces[:, 1]), 1.0)
    heights = sorted(faces[:, 3] * faces[:, 1])
    np.testing.assert_allclose(heights, [0.5, 0.5 + 0.5 * 5.5], atol=1e-5)
    # the curved wall is no face: its facets' corner normals follow the cylinder
    assert not on_flat_face(faces, 1.0, 0.0, 0.0, 2.8)


def test_a_box_has_six_faces_a_sphere_none_and_small_faces_do_not_count(tmp_path):
    box = _built(tmp_path, [{"type": "box", "size": [4.0, 4.0, 4.0], "medium": MEDIUM, "interface": "null"}])
    faces = medium_faces(box, 0)
    assert len(faces) == 6
    for axis in range(3):
        for side in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = side
            assert on_flat_face(faces, *n, 2.0)
    # a face's disc radius sqrt(16 / pi) = 2.26: flat at a transport mean free path of 2, not at 3
    assert len(flat_faces(box, 0, 2.26 / FLAT_MIN_RADIUS - 0.01)) == 6
    assert len(flat_faces(box, 0, 2.26 / FLAT_MIN_RADIUS + 0.01)) == 0
    sphere = _built(tmp_path, [{"type": "sphere", "radius": 3.0, "medium": MEDIUM, "interface": "null"}])
    assert len(medium_faces(sphere, 0)) == 0


def test_only_the_largest_faces_are_kept(tmp_path, monkeypatch):
    """At most MAX_FACES faces, the largest first: every look-up of the multiple term tests its planes against each."""
    import pbvol_cli.pointbased.flat_faces as flat

    box = _built(tmp_path, [{"type": "box", "size": [4.0, 1.0, 4.0], "medium": MEDIUM, "interface": "null"}])
    assert len(flat.flat_faces(box, 0, 0.5)) == 6
    monkeypatch.setattr(flat, "MAX_FACES", 2)
    faces = flat.flat_faces(box, 0, 0.5)
    assert len(faces) == 2
    np.testing.assert_allclose(np.abs(faces[:, 1]), 1.0)  # the 4 x 4 faces, normal along y
