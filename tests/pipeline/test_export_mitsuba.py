"""`export-mitsuba`: every example scene exports in both forms with the values pbvol resolves; with Mitsuba 3 at hand
($PBVOL_MITSUBA_PYTHON: a python with mitsuba installed), the exports load, and small renders agree with pbvol's
volpath within their measured standard errors."""

import importlib.util
import json
import math
import os
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from conftest import camera, write_scene
from pbvol_cli import config as C
from pbvol_cli.errors import ConfigError, PbvolError
from pbvol_cli.geometry.primitives import shape_parts
from pbvol_cli.geometry.scene_build import CAM_FORWARD, CAM_POS, CAM_RIGHT, CAM_UP, camera_params
from pbvol_cli.pipeline.export_mitsuba import export_mitsuba, look_at_matrix, tabulated_phase

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = sorted((ROOT / "configs").glob("*.toml"))
BENCHMARK = ROOT / "benchmarks" / "mitsuba_reference.py"
MITSUBA_PYTHON = os.environ.get("PBVOL_MITSUBA_PYTHON")
MITSUBA_VARIANT = os.environ.get("PBVOL_MITSUBA_VARIANT", "scalar_rgb")
needs_mitsuba = pytest.mark.skipif(not MITSUBA_PYTHON, reason="set PBVOL_MITSUBA_PYTHON to a python with mitsuba "
                                   "installed (python3 -m venv V && V/bin/pip install mitsuba numpy)")

# what the example scenes cannot export as they are, and what they export only approximately
REFUSED = {"candle_flame": ("materials.flame.emission", "Mitsuba 3's media do not emit light")}
WARNED = {"fog_table": ["materials.fog.density: medium 'fog': Mitsuba 3 has no exponential density: baked into a "
                        "1x228x1 grid"]}


def export(tmp_path, scene_path, suffix, **kw):
    """(the exported JSON dict or XML root, warnings)."""
    out = tmp_path / f"{Path(scene_path).stem}{suffix}"
    warnings = export_mitsuba(scene_path, out, **kw)
    if suffix == ".json":
        return json.loads(out.read_text()), warnings
    return ET.parse(out).getroot(), warnings


def export_dict(tmp_path, scene: dict, **kw) -> tuple[dict, list[str]]:
    return export(tmp_path, write_scene(tmp_path, scene), ".json", **kw)


def referenced_files(node) -> list[str]:
    if isinstance(node, dict):
        return [v for k, v in node.items() if k == "filename"] + [f for v in node.values() for f in referenced_files(v)]
    return []


def scene_with(shapes, lights=None, **extra) -> dict:
    return {"camera": camera((16, 16)), "lights": lights or [{"type": "environment", "radiance": 0.5}],
            "shapes": shapes, **extra}


# --------------------------------------------------------------------------- every example scene


@pytest.mark.parametrize("config", CONFIGS, ids=[p.stem for p in CONFIGS])
@pytest.mark.parametrize("suffix", [".json", ".xml"])
def test_every_example_scene_exports_or_is_refused_with_its_reason(tmp_path, config, suffix):
    if config.stem in REFUSED:
        fld, why = REFUSED[config.stem]
        with pytest.raises(ConfigError) as e:
            export(tmp_path, config, suffix)
        assert str(e.value).startswith(f"{config}: {fld}: ") and why in str(e.value) and "\n" not in str(e.value)
        assert not list(tmp_path.iterdir())  # nothing written
        return
    doc, warnings = export(tmp_path, config, suffix)
    assert [w for w in warnings if not any(w.startswith(f"{config}: {x}") for x in WARNED.get(config.stem, []))] == []
    assert len(warnings) == len(WARNED.get(config.stem, []))
    if suffix == ".json":
        files = referenced_files(doc)
        assert doc["type"] == "scene" and doc["sensor"]["type"] == "perspective"
    else:
        files = [s.get("value") for s in doc.iter("string") if s.get("name") == "filename"]
        assert doc.tag == "scene" and doc.find("sensor").get("type") == "perspective"
        ids = {el.get("id") for el in doc}
        assert all(r.get("id") in ids for r in doc.iter("ref"))
    for f in files:  # beside the output, relative to it
        assert (tmp_path / f).is_file() and "/" not in f
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


def test_the_output_format_follows_the_suffix(tmp_path):
    with pytest.raises(PbvolError, match="expected a .json"):
        export_mitsuba(ROOT / "configs" / "wax_sphere.toml", tmp_path / "scene.obj")


# --------------------------------------------------------------------------- values


def test_a_sphere_keeps_its_centre_and_radius_through_its_transform(tmp_path):
    d, _ = export_dict(tmp_path, scene_with([
        {"type": "sphere", "center": [1.0, 2.0, 3.0], "radius": 0.5, "interface": "diffuse", "albedo": 0.3,
         "transform": {"scale": 2.0, "translate": [0.0, 1.0, 0.0]}}]))
    s = d["shape_0"]
    assert s["type"] == "sphere" and s["center"] == pytest.approx([2.0, 5.0, 6.0]) and s["radius"] == 1.0
    assert s["bsdf"] == {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb",
                                                                                         "value": [0.3] * 3}}}
    with pytest.raises(ConfigError, match=r"shapes\[0\].transform.scale: a sphere takes only a uniform scale"):
        export_dict(tmp_path, scene_with([{"type": "sphere", "transform": {"scale": [1.0, 2.0, 1.0]}}]))


def test_a_medium_has_its_coefficients_in_scene_units(tmp_path):
    # coefficients per mm in a scene measured in cm: ten times larger per scene unit
    medium = {"length_unit": "mm", "sigma_a": [0.1, 0.2, 0.3], "sigma_s": [2.0, 1.0, 0.5], "g": 0.4}
    d, _ = export_dict(tmp_path, scene_with([{"type": "sphere", "interface": "null", "medium": medium}], unit="cm"))
    m = d["medium_0"]
    sigma_t = np.array(m["sigma_t"]["value"]) * m["scale"]
    assert sigma_t == pytest.approx(10 * np.array([2.1, 1.2, 0.8]))
    assert max(m["sigma_t"]["value"]) == 1.0  # Mitsuba's RGB values are bounded by 1: the scale carries the size
    assert m["albedo"]["value"] == pytest.approx([2.0 / 2.1, 1.0 / 1.2, 0.5 / 0.8])
    assert m["phase"] == {"type": "hg", "g": 0.4} and m["type"] == "homogeneous"
    assert d["shape_0"]["interior"] == {"type": "ref", "id": "medium_0"} and "exterior" not in d["shape_0"]


def test_dielectric_indices_are_the_interior_and_exterior_ones(tmp_path):
    d, _ = export_dict(tmp_path, scene_with([
        {"type": "sphere", "interface": "dielectric", "eta": 1.33, "exterior_eta": 1.1},
        {"type": "sphere", "center": [3.0, 0, 0], "interface": "dielectric", "medium": "wax"},  # the medium's 1.44
        {"type": "sphere", "center": [6.0, 0, 0], "interface": "dielectric"},  # 1.5
        {"type": "sphere", "center": [9.0, 0, 0], "interface": "dielectric", "eta": 1.2, "exterior_eta": 1.2},
        {"type": "sphere", "center": [12.0, 0, 0], "interface": "mirror", "albedo": [0.9, 0.8, 0.7]}]))
    assert d["shape_0"]["bsdf"] == {"type": "dielectric", "int_ior": 1.33, "ext_ior": 1.1}
    assert d["shape_1"]["bsdf"] == {"type": "dielectric", "int_ior": 1.44, "ext_ior": 1.0}
    assert d["shape_2"]["bsdf"] == {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0}
    assert d["shape_3"]["bsdf"] == {"type": "null"}  # index-matched, as pbvol's scene_build makes it
    assert d["shape_4"]["bsdf"] == {"type": "twosided", "bsdf": {
        "type": "conductor", "material": "none", "specular_reflectance": {"type": "rgb", "value": [0.9, 0.8, 0.7]}}}


def test_lights_keep_their_radiance(tmp_path):
    lights = [{"type": "sphere", "center": [0.0, 5.0, 0.0], "radius": 0.5, "power": 100.0},
              {"type": "quad", "corner": [-1.0, 4.0, -1.0], "edge1": [2.0, 0.0, 0.0], "edge2": [0.0, 0.0, 3.0],
               "radiance": [3.0, 2.0, 1.0], "two_sided": True},
              {"type": "point", "position": [1.0, 2.0, 3.0], "intensity": 7.0},
              {"type": "directional", "direction": [0.0, -2.0, 0.0], "irradiance": [1.0, 2.0, 3.0]},
              {"type": "environment", "radiance": 0.25}, {"type": "environment", "radiance": [0.5, 0.0, 0.0]}]
    d, _ = export_dict(tmp_path, scene_with([{"type": "sphere"}], lights))
    assert d["light_0"]["emitter"]["radiance"]["value"] == pytest.approx([100.0 / (math.pi * 4 * math.pi * 0.25)] * 3)
    assert d["light_0"]["bsdf"]["reflectance"]["value"] == [0.0, 0.0, 0.0]  # pbvol's lights absorb
    front, back = d["light_1"], d["light_1_back"]
    assert front["emitter"]["radiance"]["value"] == [3.0, 2.0, 1.0] == back["emitter"]["radiance"]["value"]
    M = np.array(front["to_world"]["matrix"])
    # corners of Mitsuba's [-1, 1]^2 rectangle land on the quad; its normal (edge1 x edge2 = -y) is the third column
    assert M[:3, :3] @ [-1, -1, 0] + M[:3, 3] == pytest.approx([-1.0, 4.0, -1.0], abs=1e-5)
    assert M[:3, :3] @ [1, 1, 0] + M[:3, 3] == pytest.approx([1.0, 4.0, 2.0], abs=1e-5)
    assert M[:3, 2] == pytest.approx([0.0, -1.0, 0.0]) and "flip_normals" not in front
    assert back["flip_normals"] is True and np.array(back["to_world"]["matrix"])[1, 3] > M[1, 3]  # behind it
    assert d["light_2"] == {"type": "point", "position": [1.0, 2.0, 3.0], "intensity": {"type": "rgb",
                                                                                       "value": [7.0] * 3}}
    assert d["light_3"]["direction"] == [0.0, -1.0, 0.0] and d["light_3"]["irradiance"]["value"] == [1.0, 2.0, 3.0]
    assert d["environment"] == {"type": "constant", "radiance": {"type": "rgb", "value": [0.75, 0.25, 0.25]}}


def test_the_camera_is_pbvols(tmp_path):
    cam = {"position": [1.0, 2.0, 9.0], "look_at": [0.5, 0.0, 0.0], "up": [0.1, 1.0, 0.0], "fov": 33.0,
           "resolution": [40, 20]}
    path = write_scene(tmp_path, dict(scene_with([{"type": "sphere"}]), camera=cam, render={"spp": 5, "seed": 3}))
    d, _ = export(tmp_path, path, ".json", resolution=(30, 10))
    xml, _ = export(tmp_path, path, ".xml", spp=7)
    s = d["sensor"]
    M = np.array(s["to_world"]["matrix"])
    p = camera_params(C.Camera.model_validate(cam), (30, 10))
    t = math.tan(math.radians(33.0) / 2)
    assert M[:3, 3] == pytest.approx(p[CAM_POS:CAM_POS + 3])
    assert M[:3, 2] == pytest.approx(p[CAM_FORWARD:CAM_FORWARD + 3])
    assert M[:3, 1] == pytest.approx(p[CAM_UP:CAM_UP + 3] / t)
    assert M[:3, 0] == pytest.approx(-p[CAM_RIGHT:CAM_RIGHT + 3] / (t * 30 / 10))  # Mitsuba's film x runs along -x
    assert (s["fov"], s["fov_axis"]) == (33.0, "y")
    assert (s["film"]["width"], s["film"]["height"], s["sampler"]["sample_count"], s["sampler"]["seed"]) == \
        (30, 10, 5, 3)
    assert s["film"]["rfilter"] == {"type": "box"}
    sensor = xml.find("sensor")
    matrix = [float(x) for x in sensor.find("transform").find("matrix").get("value").split()]
    assert matrix == pytest.approx(look_at_matrix(C.Camera.model_validate(cam)).ravel())
    assert sensor.find("sampler").find("integer[@name='sample_count']").get("value") == "7"
    assert sensor.find("film").find("integer[@name='width']").get("value") == "40"


def test_depths_map_to_mitsubas_conventions(tmp_path):
    d, _ = export_dict(tmp_path, scene_with([{"type": "sphere"}], render={"max_depth": 3,
                                                                          "volpath": {"rr_depth": 5}}))
    assert d["integrator"] == {"type": "volpath", "max_depth": 4, "rr_depth": 4, "hide_emitters": False}
    d, _ = export_dict(tmp_path, scene_with([{"type": "sphere"}], render={"volpath": {"rr_depth": 0}}))
    assert d["integrator"]["rr_depth"] == 0


def test_nested_media_name_both_sides_of_every_surface(tmp_path):
    """An index-matched sphere of fog holding a glass ball of wax in the fog, a floor in the fog, and a cup of milk
    (glass, glass-milk and milk-air surfaces)."""
    fog = {"albedo": 0.9, "mean_free_path": 4.0, "phase": "isotropic"}
    shapes = [{"type": "sphere", "radius": 5.0, "interface": "null", "medium": fog},
              {"type": "sphere", "radius": 1.0, "interface": "dielectric", "eta": 1.44, "medium": "wax",
               "exterior_medium": fog},
              {"type": "quad", "center": [0.0, -2.0, 0.0], "size": [4.0, 4.0], "exterior_medium": fog},
              {"type": "cup", "center": [8.0, 0.0, 0.0], "radius": 1.0, "height": 2.0, "wall": 0.1, "bottom": 0.2,
               "fill": 0.5, "liquid": "milk", "interface": "dielectric", "eta": 1.5, "segments": 16}]
    path = write_scene(tmp_path, scene_with(shapes))
    d, _ = export(tmp_path, path, ".json")
    fog_ref, wax_ref, milk_ref = ({"type": "ref", "id": f"medium_{k}"} for k in range(3))
    assert d["medium_0"]["phase"] == {"type": "isotropic"} and d["medium_1"]["phase"]["g"] == 0.8  # wax
    assert d["shape_0"]["interior"] == fog_ref and "exterior" not in d["shape_0"]
    assert d["shape_0"]["bsdf"] == {"type": "null"}
    assert (d["shape_1"]["interior"], d["shape_1"]["exterior"]) == (wax_ref, fog_ref)
    assert d["shape_1"]["bsdf"] == {"type": "dielectric", "int_ior": 1.44, "ext_ior": 1.0}
    assert d["shape_2"]["exterior"] == fog_ref and "interior" not in d["shape_2"]
    glass, wall, free = d["shape_3_glass"], d["shape_3_liquid_glass"], d["shape_3_liquid_free"]
    assert "interior" not in glass and "exterior" not in glass
    assert glass["bsdf"] == {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0}
    milk_eta = C.load_material(C.materials_dir() / "milk.toml").eta
    assert wall["interior"] == milk_ref and "exterior" not in wall  # the glass holds no medium
    assert wall["bsdf"] == {"type": "dielectric", "int_ior": milk_eta, "ext_ior": 1.5}
    assert free["interior"] == milk_ref and free["bsdf"]["ext_ior"] == 1.0
    # the XML form says the same
    xml, _ = export(tmp_path, path, ".xml")
    shapes_xml = {s.get("id"): {r.get("name"): r.get("id") for r in s.findall("ref")} for s in xml.iter("shape")}
    assert shapes_xml["shape_1"] == {"interior": "medium_1", "exterior": "medium_0"}
    assert shapes_xml["shape_3_liquid_glass"] == {"interior": "medium_2"}
    assert [el.get("id") for el in xml].index("medium_0") < [el.get("id") for el in xml].index("shape_0")


def read_ply(path: Path):
    data = path.read_bytes()
    head, body = data.split(b"end_header\n", 1)
    lines = head.decode().splitlines()
    nv = int(next(x for x in lines if x.startswith("element vertex")).split()[-1])
    nf = int(next(x for x in lines if x.startswith("element face")).split()[-1])
    verts = np.frombuffer(body[:nv * 24], "<f4").reshape(nv, 6)
    faces = np.frombuffer(body[nv * 24:], dtype=[("n", "u1"), ("i", "<i4", (3,))], count=nf)
    return verts[:, :3], verts[:, 3:], faces


def test_meshes_are_written_as_pbvol_builds_them(tmp_path):
    shape = {"type": "cylinder", "center": [0.0, 1.0, 0.0], "radius": 1.0, "height": 2.0, "segments": 12,
             "interface": "dielectric", "transform": {"rotate": [30.0, 0.0, 0.0], "scale": [1.0, 2.0, 1.0]}}
    d, _ = export_dict(tmp_path, scene_with([shape]))
    V, N, F = read_ply(tmp_path / d["shape_0"]["filename"])
    parts = shape_parts(C.Scene.model_validate(scene_with([shape])).shapes[0], tmp_path)
    assert len(F) == sum(len(p.faces) for p in parts) and np.all(F["n"] == 3)
    assert np.linalg.norm(N, axis=1) == pytest.approx(1.0, abs=1e-6)
    tri = V[F["i"]]
    ref = np.concatenate([p.vertices[p.faces] for p in parts])
    assert tri == pytest.approx(ref, abs=1e-5)  # the same triangles, the same winding (normals outward)


def test_a_density_grid_becomes_a_vol_file(tmp_path):
    rng = np.random.default_rng(1)
    grid = rng.uniform(0, 2, (3, 4, 5))
    np.savez(tmp_path / "g.npz", density=grid)
    bounds = [[-1.0, -1.0, -1.0], [1.0, 2.0, 3.0]]
    for sigma_s, channels in ((1.0, 1), ([1.0, 0.5, 0.25], 3)):
        medium = {"sigma_a": 0.5, "sigma_s": sigma_s, "phase": "rayleigh",
                  "density": {"type": "grid", "file": "g.npz", "bounds": bounds, "scale": 2.0}}
        d, _ = export_dict(tmp_path, scene_with([{"type": "box", "size": 2.0, "interface": "null",
                                                  "medium": medium}]))
        m = d["medium_0"]
        assert m["type"] == "heterogeneous" and m["phase"] == {"type": "rayleigh"}
        vol = (tmp_path / m["sigma_t"]["filename"]).read_bytes()
        assert vol[:4] == b"VOL\x03"
        enc, nx, ny, nz, nc = np.frombuffer(vol[4:24], "<i4")
        assert (enc, nx, ny, nz, nc) == (1, 3, 4, 5, channels)
        assert np.frombuffer(vol[24:48], "<f4") == pytest.approx(np.ravel(bounds))
        data = np.frombuffer(vol[48:], "<f4").reshape(nz, ny, nx, nc)
        sigma_t = 0.5 + np.asarray(sigma_s, float) * np.ones(3)
        expect = grid.transpose(2, 1, 0)[..., None] * 2.0 * (sigma_t / sigma_t.max() if channels == 3 else 1.0)
        assert data == pytest.approx(expect, rel=1e-6) and m["scale"] == pytest.approx(sigma_t.max())
        T = np.array(m["sigma_t"]["to_world"]["matrix"])
        assert T[:3, :3] @ [1, 1, 1] + T[:3, 3] == pytest.approx(bounds[1])  # the unit cube onto the bounds
        assert T[:3, 3] == pytest.approx(bounds[0])


def test_an_exponential_density_is_baked_with_a_warning(tmp_path):
    medium = {"albedo": 0.9, "mean_free_path": 2.0,
              "density": {"type": "exponential", "a": 2.0, "b": 0.5, "origin": [0.0, 1.0, 0.0]}}
    d, warnings = export_dict(tmp_path, scene_with([{"type": "box", "center": [0.0, 2.0, 0.0], "size": 4.0,
                                                     "interface": "null", "medium": medium}]))
    assert len(warnings) == 1 and "shapes[0].medium.density" in warnings[0] and "baked into a 1x" in warnings[0]
    err = float(warnings[0].rsplit(" ", 1)[1])
    assert 0 < err <= 1.1e-4
    m = d["medium_0"]
    vol = (tmp_path / m["sigma_t"]["filename"]).read_bytes()
    _, nx, ny, nz, nc = np.frombuffer(vol[4:24], "<i4")
    lo, hi = np.frombuffer(vol[24:48], "<f4").reshape(2, 3)
    data = np.frombuffer(vol[48:], "<f4").reshape(nz, ny, nx)
    centres = lo[1] + (np.arange(ny) + 0.5) * (hi[1] - lo[1]) / ny  # voxel centres span the box, ends included
    assert centres[0] == pytest.approx(0.0, abs=1e-5) and centres[-1] == pytest.approx(4.0, abs=1e-5)
    assert data[0, :, 0] * m["scale"] == pytest.approx(0.5 * 2.0 * np.exp(-0.5 * (centres - 1.0)), rel=1e-5)


def test_phase_functions_mitsuba_lacks_are_tabulated_with_a_warning(tmp_path):
    d, warnings = export_dict(tmp_path, scene_with([{"type": "sphere", "interface": "null", "medium": {
        "albedo": 0.5, "mean_free_path": 1.0, "phase": "mie_murky"}}]))
    assert d["medium_0"]["phase"]["type"] == "tabphase" and len(d["medium_0"]["phase"]["values"].split(",")) == 1025
    assert len(warnings) == 1 and "shapes[0].medium.phase" in warnings[0] and "'mie_murky'" in warnings[0]
    for kind, g in (("schlick", 0.7), ("mie_hazy", 0.0), ("mie_murky", 0.0)):
        values, err = tabulated_phase(kind, g)
        assert err < 1e-3 and values[-1] > values[0]  # forward scattering at cos = +1, as tabphase reads it


def test_an_emissive_medium_is_refused_naming_its_field(tmp_path):
    medium = {"albedo": 0.0, "mean_free_path": 1.0, "emission": [1.0, 0.5, 0.0]}
    with pytest.raises(ConfigError, match=r"scene.toml: shapes\[0\].medium.emission: medium 'inline' has emission"):
        export_dict(tmp_path, scene_with([{"type": "sphere", "interface": "null", "medium": medium}]))


def benchmark_module():
    spec = importlib.util.spec_from_file_location("mitsuba_reference", BENCHMARK)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)  # imports no pbvol and no mitsuba at load time
    return mod


def test_the_benchmarks_built_in_scene_is_the_export_of_wax_sphere(tmp_path):
    d, _ = export(tmp_path, ROOT / "configs" / "wax_sphere.toml", ".json")
    built_in = benchmark_module().BUILTIN_SCENES["wax_sphere"]()
    assert list(built_in) == list(d)

    def close(a, b):
        if isinstance(a, dict):
            return a.keys() == b.keys() and all(close(a[k], b[k]) for k in a)
        if isinstance(a, list):
            return len(a) == len(b) and all(close(x, y) for x, y in zip(a, b))
        if isinstance(a, float):
            return a == pytest.approx(b, rel=1e-12, abs=1e-12)
        return a == b

    assert close(built_in, d)


def test_the_benchmarks_loader_turns_the_json_conventions_into_mitsubas():
    class FakeMitsuba:
        @staticmethod
        def ScalarTransform4f(m):
            return ("transform", m)

    desc = {"type": "scene", "s": {"type": "ply", "filename": "a.ply",
                                   "to_world": {"type": "transform", "matrix": [[1, 0, 0, 2]] * 4}},
            "t": {"type": "obj", "filename": "/abs/b.obj"}}
    out = benchmark_module().load_dict_form(FakeMitsuba, desc, "/base")
    assert out["s"] == {"type": "ply", "filename": os.path.join("/base", "a.ply"),
                        "to_world": ("transform", [[1, 0, 0, 2]] * 4)}
    assert out["t"]["filename"] == "/abs/b.obj" and desc["s"]["filename"] == "a.ply"


# --------------------------------------------------------------------------- with Mitsuba 3

LOAD = r"""
import importlib.util, json, os, sys
import numpy as np
import mitsuba as mi
mi.set_variant(sys.argv[2])
spec = importlib.util.spec_from_file_location("mref", sys.argv[1])
mref = importlib.util.module_from_spec(spec)
spec.loader.exec_module(mref)
out = {}
for stem in sys.argv[3:]:
    with open(stem + ".json") as f:
        a = mi.load_dict(mref.load_dict_form(mi, json.load(f), os.path.dirname(stem)))
    b = mi.load_file(stem + ".xml")
    ia, ib = (np.array(mi.render(s, spp=2, seed=5)) for s in (a, b))
    out[stem] = {"shapes": [len(a.shapes()), len(b.shapes())], "emitters": [len(a.emitters()), len(b.emitters())],
                 "close": float(np.isclose(ia, ib, rtol=1e-4, atol=1e-6).mean()),
                 "finite": bool(np.isfinite(ia).all() and np.isfinite(ib).all())}
print(json.dumps(out))
"""

RENDER = r"""
import importlib.util, json, os, sys
import numpy as np
import mitsuba as mi
mi.set_variant(sys.argv[2])
spec = importlib.util.spec_from_file_location("mref", sys.argv[1])
mref = importlib.util.module_from_spec(spec)
spec.loader.exec_module(mref)
path, runs, spp, out = sys.argv[3], int(sys.argv[4]), int(sys.argv[5]), sys.argv[6]
with open(path) as f:
    scene = mi.load_dict(mref.load_dict_form(mi, json.load(f), os.path.dirname(path)))
np.save(out, np.stack([np.array(mi.render(scene, spp=spp, seed=1000 + k)) for k in range(runs)]))
"""


def run_mitsuba(script: str, *args) -> str:
    r = subprocess.run([MITSUBA_PYTHON, "-c", script, str(BENCHMARK), MITSUBA_VARIANT, *map(str, args)],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    return r.stdout


@needs_mitsuba
def test_every_exported_example_scene_loads_in_mitsuba_in_both_forms(tmp_path):
    stems = []
    for config in CONFIGS:
        if config.stem in REFUSED:
            continue
        for suffix in (".json", ".xml"):
            export_mitsuba(config, tmp_path / f"{config.stem}{suffix}", spp=2, resolution=(6, 4))
        stems.append(tmp_path / config.stem)
    result = json.loads(run_mitsuba(LOAD, *stems).strip().splitlines()[-1])
    for stem in stems:
        r = result[str(stem)]
        assert r["shapes"][0] == r["shapes"][1] > 0 and r["emitters"][0] == r["emitters"][1] > 0, (stem, r)
        # the two forms are the same scene: the same image for the same seed, but for float parsing's last bits (one
        # path that they turn another way may change one pixel)
        assert r["close"] >= 0.95 and r["finite"], (stem, r)


GLASS_SPHERE = {  # a chromatic, forward-scattering medium behind glass under a sphere light and a sky
    "camera": camera((16, 16), position=(0.0, 0.5, 4.0), fov=36.0),
    "render": {"max_depth": 200},
    "lights": [{"type": "sphere", "center": [2.0, 3.0, 1.0], "radius": 1.0, "radiance": 4.0},
               {"type": "environment", "radiance": [0.2, 0.25, 0.3]}],
    "shapes": [{"type": "sphere", "radius": 1.0, "interface": "dielectric", "eta": 1.5,
                "medium": {"albedo": [0.9, 0.7, 0.5], "mean_free_path": [0.3, 0.5, 0.8], "g": 0.4}}]}
FOG_FLOOR = {  # a grid of chromatic, Rayleigh-scattering fog over a diffuse floor, a mirror ball, a two-sided light
    "camera": camera((16, 16), position=(0.0, 1.5, 6.0), fov=45.0),
    "lights": [{"type": "quad", "corner": [-1.0, 2.5, -1.0], "edge1": [2.0, 0.0, 0.0], "edge2": [0.0, 0.0, 2.0],
                "radiance": 3.0, "two_sided": True},
               {"type": "environment", "radiance": 0.1}],
    "materials": {"fog": {"sigma_a": [0.05, 0.1, 0.1], "sigma_s": [0.6, 0.4, 0.3],
                          "phase": "rayleigh",
                          "density": {"type": "grid", "file": "fog.npz", "bounds": [[-3, -1, -3], [3, 3, 3]]}}},
    "shapes": [{"type": "box", "center": [0.0, 1.0, 0.0], "size": [6.0, 4.0, 6.0], "interface": "null",
                "medium": "fog"},
               {"type": "quad", "center": [0.0, -0.5, 0.0], "size": [5.0, 5.0], "albedo": [0.6, 0.5, 0.4],
                "exterior_medium": "fog"},
               {"type": "sphere", "center": [0.8, 0.3, 0.0], "radius": 0.7, "interface": "mirror", "albedo": 0.9,
                "exterior_medium": "fog"}]}
LIQUID_CUP = {  # a glass of a scattering liquid on a table: three nested interfaces from meshes
    "camera": camera((16, 16), position=(0.0, 3.0, 7.0), fov=40.0),
    "lights": [{"type": "sphere", "center": [-3.0, 5.0, 2.0], "radius": 1.5, "radiance": 3.0},
               {"type": "environment", "radiance": [0.3, 0.3, 0.35]}],
    "shapes": [{"type": "cup", "center": [0.0, 0.01, 0.0], "radius": 1.2, "height": 2.5, "wall": 0.1,
                "bottom": 0.2, "fill": 0.7, "interface": "dielectric", "eta": 1.5, "segments": 24,
                "liquid": {"albedo": [0.95, 0.8, 0.6], "mean_free_path": 0.4, "g": 0.5, "eta": 1.33}},
               {"type": "quad", "size": [20.0, 20.0], "albedo": [0.5, 0.5, 0.5]}]}
RUNS, SPP = 8, 256


def regions(img):
    """The image and its four quadrants (a mirrored or shifted image disagrees there)."""
    h, w = img.shape[-3] // 2, img.shape[-2] // 2
    return {"image": img, "top left": img[..., :h, :w, :], "top right": img[..., :h, w:, :],
            "bottom left": img[..., h:, :w, :], "bottom right": img[..., h:, w:, :]}


def mean_and_error(runs: np.ndarray):
    """(mean per channel, its standard error) of a region from independent runs (K, h, w, 3): per-pixel standard
    errors of the K-run mean, combined over the region's independent pixels."""
    k = runs.shape[0]
    pixel_var = runs.var(axis=0, ddof=1) / k
    n = runs.shape[1] * runs.shape[2]
    return runs.mean(axis=(0, 1, 2)), np.sqrt(pixel_var.sum(axis=(0, 1))) / n


@needs_mitsuba
@pytest.mark.slow
@pytest.mark.parametrize("name", ["glass_sphere", "fog_floor", "liquid_cup"])
def test_mitsubas_render_of_the_export_agrees_with_volpath(tmp_path, name):
    import pbvol

    scene = {"glass_sphere": GLASS_SPHERE, "fog_floor": FOG_FLOOR, "liquid_cup": LIQUID_CUP}[name]
    if name == "fog_floor":
        rng = np.random.default_rng(3)
        np.savez(tmp_path / "fog.npz", density=rng.uniform(0.2, 1.5, (5, 4, 5)))
    path = write_scene(tmp_path, scene)
    assert export_mitsuba(path, tmp_path / "scene.json") == []
    run_mitsuba(RENDER, tmp_path / "scene.json", RUNS, SPP, tmp_path / "mitsuba.npy")
    theirs = np.load(tmp_path / "mitsuba.npy").astype(float)
    loaded = pbvol.load_scene(path)
    ours = np.stack([pbvol.render(loaded, spp=SPP, seed=k, threads=2).image for k in range(RUNS)])
    assert ours.shape == theirs.shape == (RUNS, 16, 16, 3)
    report = []
    for region, a in regions(ours).items():
        b = regions(theirs)[region]
        (ma, ea), (mb, eb) = mean_and_error(a), mean_and_error(b)
        bound = 4.0 * np.sqrt(ea ** 2 + eb ** 2) + 0.01 * np.abs(ma)
        report.append(f"{region}: pbvol {np.round(ma, 5)} ± {np.round(ea, 5)}, Mitsuba {np.round(mb, 5)} ± "
                      f"{np.round(eb, 5)}, bound {np.round(bound, 5)}")
        assert np.all(np.abs(ma - mb) <= bound), "\n".join(report)
    print("\n".join(report))
