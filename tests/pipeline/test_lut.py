"""The precompute-lut stage: cache hits, misses, damaged entries, and the command line."""

import numpy as np
from typer.testing import CliRunner

from conftest import camera, write_scene
from pbvol_cli.main import app
from pbvol_cli.multiple_scattering.layout import Layout
from pbvol_cli.multiple_scattering.table import TableSettings
from pbvol_cli.pipeline.lut import channel_tables, get_table

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
