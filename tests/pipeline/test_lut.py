"""The precompute-lut stage: cache hits, misses, damaged entries, and the command line."""

from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from conftest import camera, write_scene
from pbvol_cli import config as C
from pbvol_cli.geometry.scene_build import MED_G, build_scene
from pbvol_cli.main import app
from pbvol_cli.multiple_scattering.extent import DEFAULT_EXTENT
from pbvol_cli.multiple_scattering.layout import Layout
from pbvol_cli.multiple_scattering.table import TableSettings
from pbvol_cli.pipeline.lut import channel_tables, get_table, table_groups
from pbvol_cli.pipeline.render import pbl_media

CONFIGS = Path(__file__).resolve().parents[2] / "configs"

SET = TableSettings(particles=3000, layout=Layout(extent=6.0, n_rho=8, n_z=16, n_theta=6, n_phi=6,
                                                  kill_radius=12.0), sh_order=4)


def test_hit_miss_and_damaged_entry(tmp_path):
    first = get_table(0.8, 0.3, 1, SET, tmp_path)
    assert not first.reused and first.path.exists()
    again = get_table(0.8, 0.3, 1, SET, tmp_path)
    assert again.reused and again.path == first.path
    assert np.array_equal(again.table.intensity, first.table.intensity)
    # anything that determines the table changes the key
    assert get_table(0.8, 0.3, 1, TableSettings(**{**SET.__dict__, "seed": 9}), tmp_path).path != first.path
    assert get_table(0.81, 0.3, 1, SET, tmp_path).path != first.path
    # a truncated file is rebuilt, not trusted
    first.path.write_bytes(first.path.read_bytes()[:200])
    rebuilt = get_table(0.8, 0.3, 1, SET, tmp_path)
    assert not rebuilt.reused
    assert np.array_equal(rebuilt.table.intensity, first.table.intensity)
    # so is a readable file whose arrays do not fit together
    d = dict(np.load(first.path))
    d["leaf"] = d["leaf"] + 10**6
    np.savez(first.path, **d)
    assert not get_table(0.8, 0.3, 1, SET, tmp_path).reused
    assert get_table(0.8, 0.3, 1, SET, tmp_path).reused
    # --force rebuilds
    assert not get_table(0.8, 0.3, 1, SET, tmp_path, force=True).reused


def test_channels_sharing_an_albedo_share_a_table():
    sa = np.array([0.1, 0.1, 0.3])
    ss = np.array([0.9, 0.9, 0.7])
    assert channel_tables(sa, ss) == [(0.7, [2]), (0.9, [0, 1])]


runner = CliRunner()


def test_cli_material_then_reuse(tmp_path):
    mat = tmp_path / "grey.toml"
    mat.write_text('name = "grey"\nalbedo = 0.8\nmean_free_path = 1.0\ng = 0.5\n')
    args = ["precompute-lut", str(mat), "--particles", "2000", "--cache-dir", str(tmp_path / "c"), "-q"]
    r = runner.invoke(app, args)
    assert r.exit_code == 0, r.output
    assert "grey RGB (albedo 0.8, g 0.5, hg): built" in r.stdout and "MB" in r.stdout
    r2 = runner.invoke(app, args)
    assert "reused cached table" in r2.stdout
    r3 = runner.invoke(app, args + ["--force"])
    assert "built" in r3.stdout


def test_cli_scene_lists_every_medium_and_bad_input_is_one_line(tmp_path):
    scene = {"camera": camera(), "render": {"lut": {"extent": 5.0, "sh_order": 4}},
             "lights": [{"type": "environment", "radiance": 1.0}],
             "shapes": [{"type": "sphere", "medium": {"name": "a", "albedo": [0.5, 0.5, 0.6], "mean_free_path": 1}},
                        {"type": "sphere", "center": [3, 0, 0], "medium": {"name": "b", "albedo": 0.7,
                                                                            "mean_free_path": 1}}]}
    path = write_scene(tmp_path, scene)
    r = runner.invoke(app, ["precompute-lut", str(path), "--particles", "1000", "--cache-dir", str(tmp_path / "c"),
                            "-q"])
    assert r.exit_code == 0, r.output
    assert r.stdout.count("built") == 3  # a: RG and B, b: RGB
    bad = tmp_path / "bad.toml"
    bad.write_text("albedo = 2\nmean_free_path = 1\n")
    r = runner.invoke(app, ["precompute-lut", str(bad), "--cache-dir", str(tmp_path / "c")])
    assert r.exit_code == 1 and r.stderr.strip().count("\n") == 0 and "albedo" in r.stderr


def test_every_example_keeps_the_default_table():
    """The examples' bodies spread their light over less than 40 mean free paths: their tables (and the images
    docs/pbl.md measured) are those of the fixed default."""
    for path in sorted(CONFIGS.glob("*.toml")):
        scene = C.load_scene(path)
        b = pbl_media(build_scene(scene, path, (8, 8)), scene.render.pbl, "pbl")
        for m in range(len(b.medium_info)):
            if b.medium_info[m].material.density is not None:
                continue
            for _, _, settings in table_groups(*b.medium_sigmas(m), float(b.media[m, MED_G]), b.medium_side(m),
                                               scene.render.lut):
                assert settings.layout.extent == DEFAULT_EXTENT, (path.stem, settings.layout.extent)


def test_precompute_builds_the_wider_table_a_thick_forward_scattering_body_renders_with(tmp_path):
    """A sphere of g 0.8, 150 mean free paths across: precompute-lut builds a table of 160 mean free paths in half
    (extent "auto"), and the pbl render reads that table and no other."""
    scene = {"unit": "cm", "camera": camera((2, 2)),
             "render": {"spp": 1, "lut": {"particles": 2000},
                        "pbl": {"surface_samples": 64, "segments_per_beam": 2}},
             "lights": [{"type": "environment", "radiance": 1.0}],
             "shapes": [{"type": "sphere", "radius": 3.0, "interface": "dielectric",
                         "medium": {"albedo": 0.9998, "g": 0.8, "mean_free_path": 0.04}}]}
    path = write_scene(tmp_path, scene)
    cache = ["--cache-dir", str(tmp_path / "c")]
    r = runner.invoke(app, ["precompute-lut", str(path), *cache])
    assert r.exit_code == 0, r.output
    assert "160 mean free paths in half" in r.stdout, r.stdout
    staged = sorted(p.name for p in (tmp_path / "c" / "lut").glob("*.npz"))
    assert len(staged) == 1
    r = runner.invoke(app, ["render", str(path), "--method", "pbl", "-o", str(tmp_path / "o.exr"), "-q",
                            "--components", "multiple", *cache])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (tmp_path / "c" / "lut").glob("*.npz")) == staged
