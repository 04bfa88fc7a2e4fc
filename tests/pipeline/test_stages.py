"""The point-based method's stages from the command line: cached light samples, component layers."""

import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import medium_sphere_scene, write_scene
from pbvol_cli.imageio import read_exr, read_layers
from pbvol_cli.main import app
from pbvol_cli.pipeline.cache import save_npz_atomic

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


@pytest.mark.parametrize("similarity,said", [("delta-eddington", ["(delta-Eddington)", "g 0.333333, hg)"]),
                                             ("truncated", ["(truncated peak)", "g 0.5, hg_truncated)"])])
def test_stages_cache_what_a_transformed_render_reads(tmp_path, similarity, said):
    """With [render.pbl] similarity set, precompute-lut builds the transformed medium's tables (delta-Eddington: of
    g / (1 + g), g = 0.5; truncated: of the capped lobe) and place-samples places the transformed medium's samples:
    the render then reuses both."""
    path = write_scene(tmp_path, medium_sphere_scene(surface_samples=2000, segments_per_beam=4,
                                                     similarity=similarity))
    cache = ["--cache-dir", str(tmp_path / "c")]
    r = runner.invoke(app, ["precompute-lut", str(path), *cache])
    assert r.exit_code == 0, r.output
    assert all(s in r.stdout for s in said), r.stdout
    assert runner.invoke(app, ["place-samples", str(path), *cache]).exit_code == 0
    staged = sorted(p.name for p in (tmp_path / "c").rglob("*.npz"))
    out = tmp_path / "o.exr"
    r = runner.invoke(app, ["render", str(path), "--method", "pbl", "-o", str(out), "--spp", "1", "-q", *cache])
    assert r.exit_code == 0, r.output
    assert read_exr(out)[1]["stage_samples_reused"] == 1.0
    tables = [n for n in staged if n.startswith("ms_")]
    assert len(tables) == 3 and sorted(p.name for p in (tmp_path / "c" / "lut").glob("*.npz")) == tables


def _reflecting_sphere(resolution: int) -> dict:
    """A small medium sphere behind eta 1.3 whose boundary reflects scattered light (bounced samples), cheap."""
    return {"camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "fov": 40, "resolution": [resolution] * 2},
            "render": {"spp": 1, "lut": {"particles": 2000},
                       "pbl": {"surface_samples": 300, "segments_per_beam": 4, "bounce_samples": 64}},
            "lights": [{"type": "directional", "direction": [0, -1, -0.5], "irradiance": 2.0}],
            "shapes": [{"type": "sphere", "radius": 1.0, "interface": "dielectric", "eta": 1.3,
                        "medium": {"albedo": 0.95, "mean_free_path": 0.2, "g": 0.3}}]}


def test_pass_zeros_bounced_samples_are_cached_and_give_the_same_image(tmp_path):
    """A pbl render stores pass 0's reflected bounced samples; the next render reuses them (the same pixels, bit
    for bit); a setting they depend on makes a new entry."""
    scene = _reflecting_sphere(10)
    cache = tmp_path / "cache"
    images = []
    for name, bounce_samples in (("a", 64), ("b", 64), ("c", 48)):
        scene["render"]["pbl"]["bounce_samples"] = bounce_samples
        path = write_scene(tmp_path, scene)
        r = runner.invoke(app, ["render", str(path), "-o", str(tmp_path / f"{name}.exr"), "--method", "pbl", "-q",
                                "--threads", "2", "--cache-dir", str(cache), "--components", "bounced"])
        assert r.exit_code == 0, r.output
        images.append(read_exr(tmp_path / f"{name}.exr")[0])
        entries = sorted(p.name for p in (cache / "samples").glob("bounced_*.npz"))
        assert len(entries) == (1 if name != "c" else 2), entries
    assert images[0].max() > 0 and np.array_equal(images[0], images[1])
    assert not np.array_equal(images[0], images[2])
    # the image comes from the entry: its power doubled (stored with a valid stamp), the bounced light grows
    entry = min((cache / "samples").glob("bounced_*.npz"), key=lambda p: p.stat().st_mtime_ns)
    with np.load(entry) as z:
        data = {k: z[k] for k in z.files if not k.startswith("entry_")}
    data["v_power"] = 2.0 * data["v_power"]
    save_npz_atomic(entry, **data)
    scene["render"]["pbl"]["bounce_samples"] = 64
    r = runner.invoke(app, ["render", str(write_scene(tmp_path, scene)), "-o", str(tmp_path / "d.exr"), "--method",
                            "pbl", "-q", "--threads", "2", "--cache-dir", str(cache), "--components", "bounced"])
    assert r.exit_code == 0, r.output
    assert read_exr(tmp_path / "d.exr")[0].mean() > 1.2 * images[0].mean()


def test_a_change_to_the_package_builds_pass_zeros_bounced_samples_again(tmp_path, monkeypatch):
    """The bounced samples go through every estimator: an entry made by other sources of the package (an edit, a
    pull, an upgrade) is not reused, however the settings match."""
    import pbvol_cli.pipeline.samples as samples

    path, cache = write_scene(tmp_path, _reflecting_sphere(6)), tmp_path / "cache"
    for stamp in ("sources-a", "sources-a", "sources-b"):
        monkeypatch.setattr(samples, "package_stamp", lambda stamp=stamp: stamp)
        r = runner.invoke(app, ["render", str(path), "-o", str(tmp_path / "o.exr"), "--method", "pbl", "-q",
                                "--threads", "2", "--cache-dir", str(cache), "--components", "bounced"])
        assert r.exit_code == 0, r.output
    assert len(list((cache / "samples").glob("bounced_*.npz"))) == 2
