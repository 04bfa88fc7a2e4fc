"""The point-based method's stages from the command line: cached light samples, component layers."""

import numpy as np
from typer.testing import CliRunner

from conftest import medium_sphere_scene, write_scene
from pbvol_cli.imageio import read_exr, read_layers
from pbvol_cli.main import app

runner = CliRunner()


def test_place_samples_caches_and_render_writes_component_layers(tmp_path):
    path = write_scene(tmp_path, medium_sphere_scene(surface_samples=2000, segments_per_beam=4))
    args = ["place-samples", str(path), "--cache-dir", str(tmp_path / "c")]
    r = runner.invoke(app, args)
    assert r.exit_code == 0, r.output
    assert "placed in" in r.stdout and "volume samples" in r.stdout
    assert "reused cached samples" in runner.invoke(app, args).stdout
    out = tmp_path / "o.exr"
    r = runner.invoke(app, ["render", str(path), "--method", "pbl", "-o", str(out), "--cache-dir",
                            str(tmp_path / "c"), "--components", "single,double", "--spp", "1", "-q"])
    assert r.exit_code == 0, r.output
    img, meta = read_exr(out)
    layers = read_layers(out)
    assert set(layers) == {"single", "double", "multiple", "bounced", "surface"}
    assert np.allclose(img, sum(layers.values()), rtol=1e-5, atol=1e-7)
    assert layers["single"].sum() > 0 and layers["double"].sum() > 0
    assert layers["multiple"].sum() == 0 and layers["bounced"].sum() == 0
    assert meta["method"] == "pbl" and meta["stage_samples_reused"] == 1.0 and "stage_render_s" in meta
    assert meta["surface_paths"] == 8
    assert "stages: light samples" in r.stdout and "camera pass" in r.stdout  # each stage's time and memory
    bad = runner.invoke(app, ["render", str(path), "--method", "pbl", "-o", str(out), "--components", "triple",
                              "--cache-dir", str(tmp_path / "c")])
    assert bad.exit_code == 1 and "--components" in bad.stderr and "\n" not in bad.stderr.strip()
