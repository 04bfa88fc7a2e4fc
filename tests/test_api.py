"""The Python API (pbvol/): scenes from files and dicts, renders as numpy arrays equal to the command line's
images, layers summing to the image, results saved as the CLI's EXR, errors as PbvolError."""

import numpy as np
import pytest

import pbvol
from conftest import camera, write_scene
from pbvol_cli.imageio import read_exr, read_layers
from pbvol_cli.pipeline.render import RenderOptions, render_scene

SCENE = {"camera": camera((12, 10)), "render": {"spp": 2, "seed": 4},
         "lights": [{"type": "sphere", "center": [2.0, 2.0, 2.0], "radius": 0.5, "radiance": 10.0},
                    {"type": "environment", "radiance": 0.2}],
         "shapes": [{"type": "sphere", "radius": 1.0, "interface": "null",
                     "medium": {"albedo": 0.8, "mean_free_path": 0.7}},
                    {"type": "quad", "center": [0.0, -1.2, 0.0], "size": [6.0, 6.0], "interface": "diffuse",
                     "albedo": 0.5}]}


def test_render_from_a_dict_equals_the_command_line(tmp_path):
    """The same scene as a dict and as a file: the API's image (float64) rounds to the EXR the command line writes,
    bit for bit; its metadata is the EXR's."""
    path = write_scene(tmp_path, SCENE)
    render_scene(path, tmp_path / "cli.exr", RenderOptions(quiet=True, timings=False))
    cli, meta = read_exr(tmp_path / "cli.exr")
    result = pbvol.render(pbvol.load_scene(SCENE, base_dir=tmp_path))
    assert result.image.shape == (10, 12, 3) and result.problem is None
    assert np.array_equal(result.image.astype(np.float32), cli)
    assert result.metadata["spp"] == 2 and result.metadata["seed"] == 4 and meta["seed"] == 4
    assert result.metadata["scene_hash"] == meta["scene_hash"]
    again = pbvol.render(path, spp=1, seed=9, resolution=(6, 5))
    assert again.image.shape == (5, 6, 3) and again.metadata["seed"] == 9


@pytest.mark.parametrize("method", ["raymarch", "vpl"])
def test_layers_sum_to_the_image_and_save_writes_the_exr(tmp_path, method):
    result = pbvol.render(SCENE, method=method, spp=1, cache_dir=tmp_path)
    assert set(result.layers) >= {"volume", "surface"}
    np.testing.assert_allclose(sum(result.layers.values()), result.image, rtol=1e-12, atol=1e-12)
    out = result.save(tmp_path / "api.exr")
    img, meta = read_exr(out)
    assert np.array_equal(img, result.image.astype(np.float32)) and meta["method"] == method
    assert set(read_layers(out)) == set(result.layers)


def test_errors(tmp_path):
    with pytest.raises(pbvol.ConfigError, match="shapes"):
        pbvol.load_scene(dict(SCENE, shapes=[{"type": "sphere", "radius": -1.0}]))
    with pytest.raises(pbvol.PbvolError, match="method"):
        pbvol.render(SCENE, method="nope")
    with pytest.raises(pbvol.PbvolError):
        pbvol.load_scene(tmp_path / "missing.toml")
