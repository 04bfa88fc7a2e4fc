"""The built scene's questions about a medium's region."""

from conftest import build, camera


def _scene(*shapes):
    return {"camera": camera((8, 8)), "lights": [{"type": "environment", "radiance": 1.0}], "shapes": list(shapes)}


MEDIUM = {"albedo": 0.9, "mean_free_path": 0.1, "g": 0.0}


def test_a_sphere_a_box_and_a_cylinder_of_medium_are_convex(tmp_path):
    for shape in ({"type": "sphere", "radius": 1.0}, {"type": "box", "size": [2.0, 1.0, 3.0]},
                  {"type": "cylinder", "radius": 0.5, "height": 1.0}):
        bs = build(tmp_path, _scene({**shape, "interface": "dielectric", "medium": MEDIUM}))
        assert bs.medium_is_convex(0), shape


def test_a_bumpy_sphere_and_a_cup_are_not(tmp_path):
    for shape in ({"type": "bumpy_sphere", "radius": 1.0, "amplitude": 0.1},
                  {"type": "cup", "radius": 0.5, "height": 1.0, "wall": 0.1, "segments": 32}):
        bs = build(tmp_path, _scene({**shape, "interface": "dielectric", "medium": MEDIUM}))
        assert not bs.medium_is_convex(0), shape


def test_a_medium_around_an_object_is_not_convex(tmp_path):
    """Wax in a box with a glass sphere in it: rays from the wax meet the sphere first."""
    bs = build(tmp_path, _scene({"type": "box", "size": [4.0, 4.0, 4.0], "interface": "null", "medium": "wax"},
                                {"type": "sphere", "radius": 0.5, "interface": "dielectric", "eta": 1.5,
                                 "exterior_medium": "wax", "exterior_eta": 1.44}))
    assert bs.surfaces_bounding(0).sum() == 2  # the box and the sphere
    assert not bs.medium_is_convex(0)
