"""`render --method dipole` against the reference path tracer where diffusion holds: a thick slab under a sky and a
large sphere under a sphere light, both of albedo 0.99 behind eta 1.5 (20 mean free paths deep or more)."""

import numpy as np
import pytest

from conftest import build, camera, volpath, write_scene
from pbvol_cli.errors import PbvolError
from pbvol_cli.imageio import read_layers
from pbvol_cli.pipeline.render import RenderOptions, render_scene

MEDIUM = {"albedo": 0.99, "mean_free_path": 0.05, "g": 0.0}


def slab():
    shape = {"type": "box", "size": [4.0, 1.0, 4.0], "interface": "dielectric", "eta": 1.5, "medium": MEDIUM}
    return {"camera": camera((16, 16), position=(0.0, 3.0, 0.3), fov=8), "render": {"spp": 4},
            "lights": [{"type": "environment", "radiance": 1.0}], "shapes": [shape]}


def sphere():
    shape = {"type": "sphere", "radius": 1.0, "interface": "dielectric", "eta": 1.5, "medium": MEDIUM}
    return {"camera": camera((24, 24), position=(0.0, 0.0, 4.0), fov=35), "render": {"spp": 2},
            "lights": [{"type": "sphere", "center": [3.0, 3.0, 3.0], "radius": 1.0, "radiance": 2.0},
                       {"type": "environment", "radiance": 0.1}], "shapes": [shape]}


def dipole_layers(tmp_path, scene):
    path = write_scene(tmp_path, scene)
    render_scene(path, tmp_path / "d.exr", RenderOptions(method="dipole", cache_dir=tmp_path, quiet=True))
    return read_layers(tmp_path / "d.exr")


@pytest.mark.parametrize("make,diffusion_ratio", [(slab, 1.036), (sphere, 0.956)])
def test_against_volpath(tmp_path, make, diffusion_ratio):
    """Where the medium shows (volpath's orders 2, 3+ over 0.02): the diffusion layer over volpath's orders 2 and 3+
    (the dipole's model error: measured 1.036 on the slab, 0.956 on the sphere; both renders' noise is under 1 %
    of these means, so 0.03 around the measured value catches a change of the estimator), the single layer over
    order 1 (pbl's estimator, unbiased up to its kernel: within 0.06) and the surfaces over order 0."""
    scene = make()
    layers = dipole_layers(tmp_path, scene)
    assert set(layers) == {"single", "diffusion", "surface"}
    bs = build(tmp_path, scene)
    ref = {o: volpath(bs, spp=512, seed=1, orders=o) for o in ("0", "1", "2,3+")}
    seen = ref["2,3+"].mean(-1) > 0.02
    assert seen.sum() > 100
    ratio = layers["diffusion"][seen].mean() / ref["2,3+"][seen].mean()
    assert abs(ratio - diffusion_ratio) < 0.03, ratio
    assert abs(layers["single"][seen].mean() / ref["1"][seen].mean() - 1) < 0.06
    assert abs(layers["surface"].mean() / ref["0"].mean() - 1) < 0.05


def test_components_refused(tmp_path):
    path = write_scene(tmp_path, slab())
    with pytest.raises(PbvolError, match="--components"):
        render_scene(path, tmp_path / "d.exr", RenderOptions(method="dipole", components="single", cache_dir=tmp_path,
                                                             quiet=True))


def test_no_medium_renders_surfaces(tmp_path):
    """A scene without a medium: the dipole is the camera paths' surfaces alone, as pbl's."""
    scene = {"camera": camera((8, 8)), "render": {"spp": 1}, "lights": [{"type": "environment", "radiance": 1.0}],
             "shapes": [{"type": "sphere", "radius": 1.0, "interface": "diffuse", "albedo": 0.5}]}
    layers = dipole_layers(tmp_path, scene)
    assert np.all(layers["diffusion"] == 0) and layers["surface"].mean() > 0
