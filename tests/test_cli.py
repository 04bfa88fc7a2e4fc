"""The command line as a user meets it: bad input, compare, materials, check, render."""

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import camera, write_scene
from pbvol_cli.imageio import read_exr, write_exr
from pbvol_cli.main import app

runner = CliRunner()

GOOD = {"camera": camera((8, 8)), "render": {"spp": 2},
        "lights": [{"type": "environment", "radiance": 1.0}],
        "shapes": [{"type": "sphere", "radius": 1.0, "interface": "dielectric", "eta": 1.5, "medium": "wax"}]}


def _one_line_error(result, *fragments):
    assert result.exit_code != 0
    err = result.stderr.strip()
    assert err.startswith("error: ") and "\n" not in err, err
    assert "Traceback" not in result.output
    for f in fragments:
        assert f in err, (f, err)


def _with_shape(**fields):
    s = json.loads(json.dumps(GOOD))
    s["shapes"][0].update(fields)
    return s


@pytest.mark.parametrize("scene,fragments", [
    (_with_shape(medium={"albedo": 1.2, "mean_free_path": 1.0}), ["shapes[0].medium.albedo", "[0, 1]"]),
    (_with_shape(medium={"albedo": 0.5, "mean_free_path": -1.0}), ["shapes[0].medium.mean_free_path", "positive"]),
    (_with_shape(medium={"albedo": 0.5, "mean_free_path": 1.0, "g": 1.0}), ["shapes[0].medium.g", "|g| < 1"]),
    (_with_shape(eta=0.0), ["shapes[0].eta", "eta > 0"]),
    (_with_shape(medium="chocolate"), ["shapes[0].medium", "unknown material 'chocolate'", "wax"]),
    (_with_shape(colour=1), ["shapes[0].colour", "unknown field"]),
    (_with_shape(type="teapot"), ["shapes[0]", "unknown type 'teapot'"]),
    ({**GOOD, "shapes": [{"type": "mesh", "file": "missing.obj"}]}, ["shapes[0].file", "not found"]),
    ({**GOOD, "camera": {**GOOD["camera"], "fov": 200}}, ["camera.fov", "(0, 180)"]),
    ({**GOOD, "lights": []}, ["at least one light"]),
    # non-finite and overflowing numbers, negative light, a bool for a number
    ({**GOOD, "lights": [{"type": "environment", "radiance": float("nan")}]}, ["lights[0].radiance", "finite"]),
    ({**GOOD, "lights": [{"type": "sphere", "center": [0, 5, 0], "radius": 1e-200, "power": 1e300}]},
     ["lights[0]", "overflows"]),
    ({**GOOD, "lights": [{"type": "quad", "corner": [0, 5, 0], "edge1": [1, 0, float("inf")], "edge2": [0, 0, 1],
                          "radiance": 1.0}]}, ["lights[0].edge1", "finite"]),
    ({**GOOD, "lights": [{"type": "point", "position": [0, 5, 0], "intensity": -1.0}]},
     ["lights[0].intensity", "non-negative"]),
    ({**GOOD, "camera": {**GOOD["camera"], "look_at": [0, float("inf"), 0]}}, ["camera.look_at", "finite"]),
    ({**GOOD, "camera": {**GOOD["camera"], "fov": True}}, ["camera.fov", "expected a number"]),
    (_with_shape(radius=float("nan")), ["shapes[0].radius", "finite"]),
    (_with_shape(transform={"translate": [0, float("nan"), 0]}), ["shapes[0].transform.translate", "finite"]),
    (_with_shape(medium={"albedo": 0.5, "mean_free_path": 1e-320}), ["shapes[0].medium", "overflow"]),
    (_with_shape(medium={"albedo": 0.5, "mean_free_path": 1e-300, "scale": 1e300}), ["shapes[0].medium",
                                                                                     "overflow"]),
    # every error is listed, on one line
    ({**_with_shape(radius=-1.0), "camera": {**GOOD["camera"], "fov": 200}}, ["camera.fov", "shapes[0].radius"]),
])
def test_bad_scene_gives_one_line_error_naming_file_and_field(tmp_path, scene, fragments):
    path = write_scene(tmp_path, scene)
    for cmd in (["check", str(path)], ["render", str(path), "-o", str(tmp_path / "x.exr"), "-q"]):
        _one_line_error(runner.invoke(app, cmd), str(path), *fragments)
    assert not (tmp_path / "x.exr").exists()


def test_toml_syntax_error(tmp_path):
    p = tmp_path / "broken.toml"
    p.write_text("[camera\nposition = [0, 0, 1]\n")
    _one_line_error(runner.invoke(app, ["check", str(p)]), str(p), "TOML syntax error", "line 1")


def test_missing_scene_file(tmp_path):
    _one_line_error(runner.invoke(app, ["check", str(tmp_path / "none.toml")]), "none.toml", "file not found")


def test_bad_material_file_is_named(tmp_path):
    (tmp_path / "mine.toml").write_text("albedo = 0.5\nmean_free_path = 0\n")
    path = write_scene(tmp_path, _with_shape(medium="mine.toml"))
    _one_line_error(runner.invoke(app, ["check", str(path)]), "mine.toml", "mean_free_path")


def test_bad_orders_and_resolution(tmp_path):
    path = write_scene(tmp_path, GOOD)
    out = str(tmp_path / "x.exr")
    _one_line_error(runner.invoke(app, ["render", str(path), "-o", out, "--orders", "7"]), "--orders", "'7'")
    _one_line_error(runner.invoke(app, ["render", str(path), "-o", out, "--resolution", "big"]), "--resolution")
    _one_line_error(runner.invoke(app, ["render", str(path), "-o", str(tmp_path / "x.png")]), ".exr")


def test_command_line_numbers_are_bounded_like_the_scene_fields(tmp_path):
    path = write_scene(tmp_path, GOOD)
    out = str(tmp_path / "x.exr")
    _one_line_error(runner.invoke(app, ["render", str(path), "-o", out, "--resolution", "100000x100000"]),
                    "--resolution", "16384")
    for option, value in (("--spp", "99999999999999999999"), ("--seed", "-1"), ("--threads", "0")):
        _one_line_error(runner.invoke(app, ["render", str(path), "-o", out, option, value]), option)
    assert not (tmp_path / "x.exr").exists()


def test_one_exit_status_per_kind_of_outcome(tmp_path):
    """0 ok, 1 bad input (whether pbvol or the option parser finds it), 2 a comparison failed (README)."""
    path = write_scene(tmp_path, GOOD)
    for bad in (["render", str(path), "--no-such-option"], ["render", str(path)], ["check", str(tmp_path / "no")],
                ["frobnicate"]):
        r = runner.invoke(app, bad)
        assert r.exit_code == 1, (bad, r.output)
        _one_line_error(r)
    write_exr(tmp_path / "a.exr", np.zeros((2, 2, 3), np.float32))
    write_exr(tmp_path / "b.exr", np.ones((2, 2, 3), np.float32))
    assert runner.invoke(app, ["compare", str(tmp_path / "a.exr"), str(tmp_path / "a.exr")]).exit_code == 0
    assert runner.invoke(app, ["compare", str(tmp_path / "a.exr"), str(tmp_path / "b.exr"), "--fail-above",
                               "0.5"]).exit_code == 2


def test_inputs_that_cannot_work_are_refused_before_the_render(tmp_path):
    # a mesh with a hole cannot hold a medium: rays would leave it without meeting a boundary
    (tmp_path / "open.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\n")
    path = write_scene(tmp_path, {**GOOD, "shapes": [{"type": "mesh", "file": "open.obj", "medium": "wax",
                                                      "interface": "dielectric"}]})
    _one_line_error(runner.invoke(app, ["check", str(path)]), "shapes[0].file", "not closed")
    # an image given as a scene
    write_exr(tmp_path / "img.exr", np.zeros((2, 2, 3), np.float32))
    _one_line_error(runner.invoke(app, ["check", str(tmp_path / "img.exr")]), "img.exr", "not a TOML text file")
    # outputs that cannot be written, a reference that is not finite: before any work
    good = write_scene(tmp_path, GOOD)
    nan = np.zeros((8, 8, 3), np.float32)
    nan[1, 1] = np.nan
    write_exr(tmp_path / "nan.exr", nan)
    for extra, fragments in ((["-o", str(tmp_path / "no" / "x.exr")], ["no/x.exr", "does not exist"]),
                             (["-o", str(tmp_path / "x.exr"), "--preview", str(tmp_path / "no" / "p.png")],
                              ["--preview", "does not exist"]),
                             (["-o", str(tmp_path)], ["must be an .exr"]),
                             (["-o", str(tmp_path / "x.exr"), "--reference", str(tmp_path / "nan.exr")],
                              ["nan.exr", "non-finite"])):
        _one_line_error(runner.invoke(app, ["render", str(good), "-q", *extra]), *fragments)
    assert not (tmp_path / "x.exr").exists()
    # light samples no machine holds (terabytes)
    huge = write_scene(tmp_path, {**GOOD, "render": {"pbl": {"surface_samples": 10**8}}})
    for cmd in (["place-samples", str(huge)], ["render", str(huge), "-o", str(tmp_path / "x.exr"), "--method", "pbl"]):
        _one_line_error(runner.invoke(app, [*cmd, "-q"]), "render.pbl.surface_samples = 100000000", "GiB")


def test_an_unwritable_cache_is_refused_by_the_cache_builders_and_read_only_for_render(tmp_path):
    (tmp_path / "file").write_text("a file where the cache folder should be")
    cache = str(tmp_path / "file" / "cache")
    path = write_scene(tmp_path, {**GOOD, "render": {"spp": 1, "pbl": {"surface_samples": 200,
                                                                         "segments_per_beam": 2}}})
    for cmd in (["precompute-lut", "materials/wax.toml"], ["place-samples", str(path)]):
        _one_line_error(runner.invoke(app, [*cmd, "--cache-dir", cache, "-q"]), "cannot write to it", "--cache-dir")
    r = runner.invoke(app, ["render", str(path), "-o", str(tmp_path / "x.exr"), "--method", "pbl",
                            "--components", "single", "-q", "--cache-dir", cache])
    assert r.exit_code == 0, r.output
    assert "for this run only" in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert (tmp_path / "x.exr").exists()


def test_no_timings_gives_byte_identical_files(tmp_path):
    path = write_scene(tmp_path, {**GOOD, "render": {"spp": 1, "pbl": {"surface_samples": 200,
                                                                         "segments_per_beam": 2}}})
    for method in ("volpath", "pbl"):  # pbl: the first run places the light samples, the second reuses them
        files = [tmp_path / f"{method}{i}.exr" for i in range(2)]
        for f in files:
            r = runner.invoke(app, ["render", str(path), "-o", str(f), "--method", method, "-q", "--threads", "2",
                                    "--cache-dir", str(tmp_path / "cache"), "--no-timings",
                                    "--components", "single,double"])
            assert r.exit_code == 0, r.output
        assert files[0].read_bytes() == files[1].read_bytes(), method
        _, meta = read_exr(files[0])
        assert "time_s" not in meta and not any(k.startswith("stage_") for k in meta) and meta["seed"] == 0


def test_every_command_takes_quiet(tmp_path):
    from pbvol_cli.main import app as main_app

    path = write_scene(tmp_path, {**GOOD, "render": {"spp": 1, "pbl": {"surface_samples": 200,
                                                                         "segments_per_beam": 2}}})
    write_exr(tmp_path / "a.exr", np.zeros((2, 2, 3), np.float32))
    mat = tmp_path / "m.toml"
    mat.write_text('albedo = 0.9\nmean_free_path = 1.0\n')
    cache = ["--cache-dir", str(tmp_path / "cache")]
    for part in ("0:1", "1:2"):
        assert runner.invoke(app, ["render", str(path), "-o", str(tmp_path / f"{part[0]}.exr"), "--samples", part,
                                   "-q"]).exit_code == 0
    runs = {"render": ["render", str(path), "-o", str(tmp_path / "x.exr")],
            "merge": ["merge", str(tmp_path / "0.exr"), str(tmp_path / "1.exr"), "-o", str(tmp_path / "m.exr")],
            "compare": ["compare", str(tmp_path / "a.exr"), str(tmp_path / "a.exr")],
            "precompute-lut": ["precompute-lut", str(mat), "--particles", "2000", *cache],
            "place-samples": ["place-samples", str(path), *cache],
            "check": ["check", str(path)], "materials": ["materials"], "schema": ["schema"],
            "batch": ["batch", str(path), "-o", str(tmp_path)],
            "export-mitsuba": ["export-mitsuba", str(path), "-o", str(tmp_path / "scene.xml")]}
    assert set(runs) == {c.name or c.callback.__name__ for c in main_app.registered_commands}
    for name, args in runs.items():
        r = runner.invoke(app, [*args, "-q"])
        assert r.exit_code == 0, (name, r.output)
        assert "\r" not in r.stderr and r.stderr == "", (name, r.stderr)  # no progress
    assert runner.invoke(app, [*runs["compare"], "-q"]).stdout == ""
    assert runner.invoke(app, ["materials", "-q"]).stdout.split()[:2] == ["apple", "bumpy_sphere"]


def test_json_summaries_for_scripts(tmp_path):
    path = write_scene(tmp_path, GOOD)
    c = runner.invoke(app, ["check", str(path), "--json"])
    assert c.exit_code == 0, c.output
    d = json.loads(c.stdout)
    assert d["media"][0]["label"] == "wax" and d["lights"] == ["environment"] and d["resolution"] == [8, 8]
    r = runner.invoke(app, ["render", str(path), "-o", str(tmp_path / "x.exr"), "-q", "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["method"] == "volpath" and s["spp"] == 2 and s["output"] == str(tmp_path / "x.exr")


def test_check_notes_nothing_of_the_table_where_light_stays_near_its_entry(tmp_path):
    """A body 2000 mean free paths across of albedo 0.99 spreads its light over about 12 mean free paths (two
    diffusion lengths): the default table holds it and check notes nothing of the table."""
    thick = _with_shape(medium={"albedo": 0.99, "mean_free_path": 0.001}, radius=1.0)
    d = json.loads(runner.invoke(app, ["check", str(write_scene(tmp_path, thick)), "--json"]).stdout)
    assert d["media"][0]["mean_free_paths_across"][0] > 1000
    assert not any("table" in n for n in d["notes"]) and "table" not in d["media"][0]["pointbased_poor"]
    assert not json.loads(runner.invoke(app, ["check", str(write_scene(tmp_path, GOOD)), "--json"]).stdout)["notes"]


def test_check_names_the_lights_a_path_tracer_cannot_bring_into_a_sealed_medium(tmp_path):
    def notes(lights, **shape):
        d = json.loads(runner.invoke(app, ["check", str(write_scene(tmp_path, {**_with_shape(**shape),
                                                                               "lights": lights})), "--json"]).stdout)
        return d["notes"]

    point = {"type": "point", "position": [0, 5, 0], "intensity": 10.0}
    small = {"type": "sphere", "center": [0, 20, 0], "radius": 0.5, "radiance": 50.0}  # 0.002 sr
    large = {"type": "sphere", "center": [0, 4, 0], "radius": 1.5, "radiance": 5.0}  # 0.44 sr
    n = notes([point, small, large])
    assert len(n) == 2 and n[0].startswith("lights[0] (point) is a delta light") and "inside wax" in n[0]
    assert n[1].startswith("lights[1] (sphere) subtends 0.002 sr from wax")
    assert notes([point, small], interface="null") == []  # no refracting boundary: volpath's shadow rays reach them
    assert notes([large]) == []


def test_check_says_what_the_similarity_transform_does_to_each_medium(tmp_path):
    scene = {**GOOD, "render": {"spp": 2, "pbl": {"similarity": "delta-eddington"}}}
    d = json.loads(runner.invoke(app, ["check", str(write_scene(tmp_path, scene)), "--json"]).stdout)
    assert d["notes"] == ["wax: pbl renders it as its delta-Eddington equivalent ([render.pbl] similarity: g 0.8 -> "
                          "0.444, sigma_s x 0.36; docs/pbl.md, section 2)"]
    iso = {**_with_shape(medium={"albedo": 0.9, "mean_free_path": 0.1, "g": 0.0}), "render": scene["render"]}
    d = json.loads(runner.invoke(app, ["check", str(write_scene(tmp_path, iso)), "--json"]).stdout)
    assert len(d["notes"]) == 1 and "leaves it as given (hg, g 0)" in d["notes"][0]
    scene["render"]["pbl"]["similarity"] = "truncated"
    d = json.loads(runner.invoke(app, ["check", str(write_scene(tmp_path, scene)), "--json"]).stdout)
    assert d["notes"] == [("wax: pbl renders it with its lobe's forward peak (within 26 degrees) taken as unscattered "
                           "([render.pbl] similarity: sigma_s x 0.579, the phase function exact beyond; docs/pbl.md, "
                           "section 2)")]


def test_check_summarises_the_scene(tmp_path):
    path = write_scene(tmp_path, GOOD)
    r = runner.invoke(app, ["check", str(path)])
    assert r.exit_code == 0, r.output
    assert "shapes: 1" in r.stdout and "lights: 1" in r.stdout and "wax" in r.stdout
    assert "mean free paths" in r.stdout


def test_materials_lists_every_preset_with_its_source():
    r = runner.invoke(app, ["materials"])
    assert r.exit_code == 0
    for name in ("oil", "wine", "wax", "milk", "espresso", "bumpy_sphere", "marble", "ketchup", "skin1"):
        assert f"\n{name}\n" in "\n" + r.stdout
    assert r.stdout.count("source:") == 18


def test_compare_known_mse_json_and_gate(tmp_path):
    a = np.full((4, 6, 3), 0.5, np.float32)
    b = a.copy()
    b[..., 1] += 0.2  # MSE = 0.2^2 / 3 over all channels
    write_exr(tmp_path / "a.exr", a)
    write_exr(tmp_path / "b.exr", b)
    r = runner.invoke(app, ["compare", str(tmp_path / "a.exr"), str(tmp_path / "b.exr"), "--json",
                            "--diff", str(tmp_path / "d.png")])
    assert r.exit_code == 0, r.output
    m = json.loads(r.stdout)
    assert m["mse"] == pytest.approx(0.04 / 3, rel=1e-6)
    assert m["per_channel"]["G"]["mse"] == pytest.approx(0.04, rel=1e-6)
    assert m["per_channel"]["R"]["mse"] == 0.0
    assert (tmp_path / "d.png").exists()
    gate = runner.invoke(app, ["compare", str(tmp_path / "a.exr"), str(tmp_path / "b.exr"), "--fail-above", "0.01"])
    assert gate.exit_code == 2
    ok = runner.invoke(app, ["compare", str(tmp_path / "a.exr"), str(tmp_path / "b.exr"), "--fail-above", "0.1"])
    assert ok.exit_code == 0
    # the relative MSE of G: 0.04 / (0.7^2 + 0.01) = 0.08, over three channels 0.0267; the MSE is 0.0133
    assert m["rel_mse"] == pytest.approx(0.08 / 3, rel=1e-6)
    for metric, bound, status in (("rel-mse", "0.02", 2), ("rel-mse", "0.03", 0), ("mse", "0.02", 0)):
        r = runner.invoke(app, ["compare", str(tmp_path / "a.exr"), str(tmp_path / "b.exr"), "--fail-above", bound,
                                "--metric", metric])
        assert r.exit_code == status, (metric, bound, r.output)
        assert (f"FAIL: {metric}" in r.stderr) == (status == 2)


def test_compare_errors(tmp_path):
    write_exr(tmp_path / "a.exr", np.zeros((4, 4, 3), np.float32))
    write_exr(tmp_path / "b.exr", np.zeros((4, 5, 3), np.float32))
    nan = np.zeros((4, 4, 3), np.float32)
    nan[0, 0, 0] = np.nan
    write_exr(tmp_path / "n.exr", nan)
    _one_line_error(runner.invoke(app, ["compare", str(tmp_path / "a.exr"), str(tmp_path / "b.exr")]), "4x4", "5x4")
    _one_line_error(runner.invoke(app, ["compare", str(tmp_path / "n.exr"), str(tmp_path / "a.exr")]), "n.exr", "NaN")
    _one_line_error(runner.invoke(app, ["compare", str(tmp_path / "zz.exr"), str(tmp_path / "a.exr")]), "zz.exr")
    _one_line_error(runner.invoke(app, ["compare", str(tmp_path / "a.exr"), str(tmp_path / "a.exr"), "--fail-above",
                                        "nan"]), "--fail-above", "finite")
    _one_line_error(runner.invoke(app, ["compare", str(tmp_path / "a.exr"), str(tmp_path / "a.exr"), "--metric",
                                        "psnr"]), "--metric", "rel-mse")


def test_render_writes_exr_with_metadata_preview_and_reference_mse(tmp_path):
    path = write_scene(tmp_path, GOOD)
    out, png = tmp_path / "out.exr", tmp_path / "out.png"
    r = runner.invoke(app, ["render", str(path), "-o", str(out), "--preview", str(png), "--seed", "5", "-q"])
    assert r.exit_code == 0, r.output
    img, meta = read_exr(out)
    assert img.shape == (8, 8, 3) and np.all(np.isfinite(img))
    assert meta["method"] == "volpath" and meta["spp"] == 2 and meta["seed"] == 5
    assert len(meta["scene_hash"]) == 16 and "time_s" in meta and meta["version"]
    assert png.exists()
    assert "M samples/s" in r.stdout and "peak memory" in r.stdout
    # same seed, same image; the reference MSE is printed (0 against itself)
    out2 = tmp_path / "out2.exr"
    r2 = runner.invoke(app, ["render", str(path), "-o", str(out2), "--seed", "5", "-q", "--reference", str(out)])
    assert r2.exit_code == 0, r2.output
    assert np.array_equal(read_exr(out2)[0], img)
    assert "MSE against reference: 0 " in r2.stdout


def test_render_overrides(tmp_path):
    path = write_scene(tmp_path, GOOD)
    out = tmp_path / "o.exr"
    r = runner.invoke(app, ["render", str(path), "-o", str(out), "--resolution", "6x4", "--spp", "3",
                            "--threads", "1", "--orders", "0", "-q"])
    assert r.exit_code == 0, r.output
    img, meta = read_exr(out)
    assert img.shape == (4, 6, 3) and meta["spp"] == 3 and meta["threads"] == 1 and meta["orders"] == "0"


def test_check_says_where_diffusion_is_poor():
    """The dipole's regime: the marble bunny (about 70 reduced mean free paths, reduced albedo 0.998) suits it; the
    wax sphere (3.3 reduced mean free paths across, blue reduced albedo 0.37) does not."""
    root = Path(__file__).resolve().parent.parent / "configs"
    media = {name: json.loads(runner.invoke(app, ["check", str(root / f"{name}.toml"), "--json"]).stdout)["media"][0]
             for name in ("marble_bunny", "wax_sphere")}
    assert media["marble_bunny"]["diffusion_poor"] == ""
    assert "3.3 reduced mean free paths thick" in media["wax_sphere"]["diffusion_poor"]
    assert "reduced albedo 0.37" in media["wax_sphere"]["diffusion_poor"]


def test_check_says_where_the_point_based_method_reads_low(tmp_path):
    """pbl reads low in a body more than six diffusion lengths thick in half (a marble sphere of radius 3 cm: 7.6 in
    blue, 0.92 of volpath's scattered light there, the dipole 0.99) and where light spreads beyond the multiple-
    scattering table (a forward-scattering body 150 mean free paths across: 0.68 with the table's 40, 0.94 with
    160; docs/pbl.md section 11). The marble bunny (up to 3 diffusion lengths: 1.01-1.08 since the images grew with
    the body), the milk glass, the wax sphere and the oil sphere are in its regime."""
    root = Path(__file__).resolve().parent.parent / "configs"
    media = {name: json.loads(runner.invoke(app, ["check", str(root / f"{name}.toml"), "--json"]).stdout)["media"][0]
             for name in ("marble_bunny", "milk_glass", "wax_sphere", "oil_sphere")}
    assert all(media[name]["pointbased_poor"] == "" for name in media), media

    def poor(medium, radius_cm: float, lut=None) -> str:
        scene = write_scene(tmp_path, {"unit": "cm", "camera": camera((2, 2)),
                                       "render": {"lut": lut} if lut else {},
                                       "lights": [{"type": "environment", "radiance": 1.0}],
                                       "shapes": [{"type": "sphere", "radius": radius_cm, "interface": "dielectric",
                                                   "medium": medium}]})
        return json.loads(runner.invoke(app, ["check", str(scene), "--json"]).stdout)["media"][0]["pointbased_poor"]

    assert poor("marble", 3.0).startswith("half its thickness is 7.6 diffusion lengths (reduced albedo 0.999)")
    assert poor("marble", 3.0).endswith("--method dipole suits it")
    assert poor("marble", 2.0) == ""  # 5.1 diffusion lengths
    forward = {"albedo": 0.9998, "g": 0.8, "mean_free_path": 0.04}  # 150 mean free paths across
    assert poor(forward, 3.0, {"extent": 40.0}).endswith("beyond the multiple-scattering table's 40: pbl reads low "
                                                         "(docs/pbl.md, section 11); set [render.lut] extent = 150")
    assert poor(forward, 3.0) == "" and poor(forward, 3.0, {"extent": 160.0}) == ""  # "auto": 160
    scene = write_scene(tmp_path, {"unit": "cm", "camera": camera((2, 2)),
                                   "lights": [{"type": "environment", "radiance": 1.0}],
                                   "shapes": [{"type": "sphere", "radius": 3.0, "medium": forward}]})
    assert "multiple-scattering table: 160 mean free paths in half" in runner.invoke(app, ["check", str(scene)]).stdout
    # a body whose light would spread over 600 mean free paths (two diffusion lengths: 1150): beyond auto's 320
    farther = {"albedo": 0.99999, "g": 0.9, "mean_free_path": 0.01}
    assert poor(farther, 3.0).endswith("beyond the multiple-scattering table's 320: pbl reads low (docs/pbl.md, "
                                       "section 11); set [render.lut] extent = 600")
    text = runner.invoke(app, ["check", str(root / "marble_bunny.toml")]).stdout
    assert "pbl:" not in text and "dipole suits it better" not in text


def test_check_names_the_flat_faces_of_a_thick_body_behind_a_reflecting_boundary(tmp_path):
    """Grey boxes of albedo 0.999 behind eta 1.5 read 1.02, 0.85 and 0.77 of volpath's scattered light at 8 passes
    60, 120 and 240 reduced mean free paths thick (half of it 1.6, 3.3 and 6.6 diffusion lengths), index-matched
    1.00, 0.98 and 0.97 (docs/pbl.md, section 7): the box 120 thick is named behind glass, not index-matched, and
    not at 60."""
    def poor(mean_free_path: float, interface: str = "dielectric") -> str:
        scene = write_scene(tmp_path, {"camera": camera((2, 2)), "lights": [{"type": "environment", "radiance": 1.0}],
                                       "shapes": [{"type": "box", "size": [30.0, 10.0, 30.0], "interface": interface,
                                                   "eta": 1.5, "medium": {"albedo": 0.999,
                                                                          "mean_free_path": mean_free_path}}]})
        return json.loads(runner.invoke(app, ["check", str(scene), "--json"]).stdout)["media"][0]["pointbased_poor"]

    named = poor(10.0 / 120.0)
    assert named.startswith("flat faces behind a reflecting boundary, half its thickness 3.3 diffusion lengths: "
                            "pbl's bounced light is heavy-tailed under them and reads low over a few passes"), named
    assert named.endswith("--method dipole suits it")
    assert poor(10.0 / 60.0) == "" and poor(10.0 / 5.0) == ""
    for thickness in (60.0, 120.0, 240.0):
        assert poor(10.0 / thickness, "null") == ""


def test_a_pbl_render_of_a_thick_dense_body_says_it_reads_low(tmp_path):
    """The note of check's pointbased_poor, on stderr before the render starts; a body in pbl's regime gets none."""
    def render(unit: str, radius: float = 1.0):
        scene = write_scene(tmp_path, {"unit": unit, "camera": camera((2, 2)),
                                       "render": {"spp": 1, "pbl": {"surface_samples": 64, "segments_per_beam": 2}},
                                       "lights": [{"type": "environment", "radiance": 1.0}],
                                       "shapes": [{"type": "sphere", "radius": radius, "interface": "dielectric",
                                                   "medium": "marble"}]})
        r = runner.invoke(app, ["render", str(scene), "-o", str(tmp_path / "x.exr"), "--method", "pbl",
                                "--components", "single", "-q", "--cache-dir", str(tmp_path / "cache")])
        assert r.exit_code == 0, r.output
        return r.stderr

    err = render("cm", 3.0)  # a marble sphere 6 cm across: half of it 3.5-7.6 diffusion lengths
    assert "medium 'marble': half its thickness is 7.6 diffusion lengths" in err, err
    assert "--method dipole suits it" in err, err
    assert "diffusion lengths" not in render("cm")  # 2 cm across: 44-60 reduced mean free paths, up to 2.5
    assert "diffusion lengths" not in render("mm")  # 2 mm across


def test_check_says_where_the_marching_methods_are_poor():
    """raymarch and vpl: the milk (sealed in glass, 22 mean free paths across, albedo near 1) is far from their
    regime on both counts, the oil sphere only as sealed; the fog suits them, and the smoke in a glass box too (its
    scene lets shadow rays through the flat glass)."""
    root = Path(__file__).resolve().parent.parent / "configs"
    media = {name: json.loads(runner.invoke(app, ["check", str(root / f"{name}.toml"), "--json"]).stdout)["media"][0]
             for name in ("milk_glass", "oil_sphere", "fog_table", "smoke_glass")}
    assert "sealed" in media["milk_glass"]["marching_poor"] and "spike" in media["milk_glass"]["marching_poor"]
    assert "sealed" in media["oil_sphere"]["marching_poor"] and "spike" not in media["oil_sphere"]["marching_poor"]
    assert media["fog_table"]["marching_poor"] == "" and media["smoke_glass"]["marching_poor"] == ""


def test_place_samples_for_methods_without_samples(tmp_path):
    """vpl, raymarch and volpath cache nothing: place-samples checks the scene, says so and succeeds; an unknown
    method is refused, and so is a broken scene."""
    scene = write_scene(tmp_path, {"unit": "mm", "camera": camera((8, 8)),
                                   "lights": [{"type": "environment", "radiance": 1.0}],
                                   "shapes": [{"type": "sphere", "radius": 1.0, "interface": "null",
                                               "medium": "marble"}]})
    for method in ("vpl", "raymarch", "volpath"):
        r = runner.invoke(app, ["place-samples", str(scene), "--method", method, "--cache-dir", str(tmp_path)])
        assert r.exit_code == 0 and "nothing to cache" in r.output, r.output
    r = runner.invoke(app, ["place-samples", str(scene), "--method", "nope", "--cache-dir", str(tmp_path)])
    assert r.exit_code == 1 and "--method" in r.output
    scene.write_text(scene.read_text().replace('unit = "mm"', 'unit = "parsec"'))
    r = runner.invoke(app, ["place-samples", str(scene), "--method", "vpl", "--cache-dir", str(tmp_path)])
    assert r.exit_code == 1 and "unit" in r.output
