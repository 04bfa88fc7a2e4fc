"""Malformed scene and material files, generated: every one gives exit status 0 or the one-line error the README
promises (naming the file), never a traceback; a file damaged in a way no reading can accept is refused.

The default run tries a few hundred files; `pytest -m slow tests/test_malformed_inputs.py` tries 10,000 and more.
The generator is derandomised: a failure reproduces on every machine."""

from __future__ import annotations

import copy
import math

import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from pbvol_cli.main import app

runner = CliRunner()

TETRAHEDRON = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n"

# every light type and shape type, small enough to build in milliseconds
SCENE = {
    "unit": "cm",
    "camera": {"position": [0.0, 2.0, 8.0], "look_at": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fov": 40.0,
               "resolution": [8, 8]},
    "render": {"spp": 1, "seed": 3, "max_depth": 20, "volpath": {"rr_depth": 4},
               "pbl": {"surface_samples": 100, "segments_per_beam": 2, "kmax": 2},
               "lut": {"particles": 2000, "extent": "auto"}},
    "materials": {"jelly": {"albedo": [0.9, 0.8, 0.7], "mean_free_path": 0.5, "g": 0.3, "eta": 1.33}},
    "lights": [
        {"type": "point", "position": [0.0, 5.0, 0.0], "intensity": 3.0},
        {"type": "directional", "direction": [0.0, -1.0, 0.2], "irradiance": [1.0, 0.9, 0.8]},
        {"type": "sphere", "center": [2.0, 6.0, 1.0], "radius": 0.5, "power": 50.0},
        {"type": "quad", "corner": [-1.0, 7.0, -1.0], "edge1": [2.0, 0.0, 0.0], "edge2": [0.0, 0.0, 2.0],
         "radiance": 2.0, "two_sided": False},
        {"type": "environment", "radiance": 0.1},
    ],
    "shapes": [
        {"type": "sphere", "center": [0.0, 1.0, 0.0], "radius": 1.0, "interface": "dielectric", "medium": "wax",
         "transform": {"scale": 1.0, "rotate": [0.0, 10.0, 0.0], "translate": [0.0, 0.0, 0.0]}},
        {"type": "bumpy_sphere", "center": [3.0, 1.0, 0.0], "radius": 0.8, "amplitude": 0.1, "frequency": 3.0,
         "seed": 1, "subdivisions": 1, "interface": "dielectric", "medium": "jelly"},
        {"type": "box", "center": [-3.0, 0.5, 0.0], "size": [1.0, 1.0, 1.0], "interface": "null",
         "medium": {"sigma_a": 0.1, "sigma_s": [1.0, 2.0, 3.0], "g": 0.0, "phase": "isotropic"}},
        {"type": "cylinder", "center": [0.0, 0.0, 3.0], "radius": 0.5, "height": 1.0, "segments": 12,
         "interface": "dielectric", "eta": 1.5, "medium": "material.toml"},
        {"type": "cup", "center": [0.0, 0.0, -3.0], "radius": 1.0, "height": 2.0, "wall": 0.1, "bottom": 0.2,
         "fill": 0.5, "liquid": "wine", "segments": 12, "interface": "dielectric", "eta": 1.5},
        {"type": "mesh", "file": "tetra.obj", "smooth": False, "interface": "dielectric", "medium": "oil",
         "transform": {"translate": [4.0, 0.0, 4.0]}},
        {"type": "quad", "center": [0.0, 0.0, 0.0], "size": [20.0, 20.0], "interface": "diffuse", "albedo": 0.5},
    ],
}

MATERIAL = {"name": "resin", "source": "made up for the test", "length_unit": "mm", "sigma_s_reduced": [1.0, 1.2, 1.4],
            "sigma_a": [0.01, 0.02, 0.03], "g": 0.5, "phase": "hg", "eta": 1.45, "scale": 1.0}

NON_FINITE = [math.nan, math.inf, -math.inf]

# values a field may be given by mistake: wrong types, non-finite, overflowing, out of range, odd lengths
any_value = st.one_of(
    st.sampled_from(NON_FINITE + [0.0, -1.0, 1e-320, 1e308, -1e308, 2.0**64, 10**30, -(10**30), True, False, "", "x",
                                  [], [1.0], [1.0, 2.0], [1.0, 2.0, 3.0, 4.0], {}, {"a": 1}]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.text(max_size=6),
    st.lists(st.one_of(st.floats(), st.integers(-5, 5), st.text(max_size=2)), max_size=4),
)
fresh_value = any_value.map(copy.deepcopy)  # the listed [] and {} are shared: the document may be changed later
unknown_keys = st.text(alphabet="abcdefghijklmnopqrstuvwxyz_", min_size=1, max_size=8)


def _paths(doc, prefix=()):
    """Every place in a nested dict/list document: (path, value)."""
    items = doc.items() if isinstance(doc, dict) else enumerate(doc)
    for k, v in items:
        yield prefix + (k,), v
        if isinstance(v, (dict, list)):
            yield from _paths(v, prefix + (k,))


def _at(doc, path):
    for k in path:
        doc = doc[k]
    return doc


@st.composite
def damaged(draw, base):
    """(document, must_fail): base with up to two faults of any kind, then, when must_fail is drawn, one that no
    reading accepts (a number made non-finite, an unknown field in a table)."""
    doc = copy.deepcopy(base)
    for _ in range(draw(st.integers(0, 2))):
        places = list(_paths(doc))
        if not places:
            break
        path, old = draw(st.sampled_from(places))
        parent = _at(doc, path[:-1])
        if draw(st.booleans()) and isinstance(parent, dict):
            del parent[path[-1]]
        else:
            parent[path[-1]] = draw(fresh_value)
    must_fail = draw(st.booleans())
    if must_fail:
        numbers = [p for p, v in _paths(doc) if isinstance(v, float)]
        tables = [p for p, v in _paths(doc) if isinstance(v, dict) and p[-1] != "materials"] + [()]
        if numbers and draw(st.booleans()):
            path = draw(st.sampled_from(numbers))
            _at(doc, path[:-1])[path[-1]] = draw(st.sampled_from(NON_FINITE))
        else:
            table = _at(doc, draw(st.sampled_from(tables)))
            name = draw(unknown_keys.filter(lambda k: k not in table))
            table[name] = draw(fresh_value)
    return doc, must_fail


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("malformed")
    (d / "tetra.obj").write_text(TETRAHEDRON)
    (d / "material.toml").write_bytes(tomli_w.dumps(MATERIAL).encode())
    return d


def _check(folder, name: str, data: bytes, scene: str = "scene.toml"):
    """Run `pbvol check` on a scene; assert exit 0 or one error line naming the file, never a traceback.
    Returns the exit status."""
    (folder / name).write_bytes(data)
    r = runner.invoke(app, ["check", str(folder / scene)])
    assert r.exit_code in (0, 1), (r.exit_code, r.output, data[:500])
    assert r.exception is None or isinstance(r.exception, SystemExit), (repr(r.exception), data[:500])
    if r.exit_code == 0:
        assert r.stderr == "", (r.stderr, data[:500])  # no warnings either
    else:
        err = r.stderr.strip()
        assert err.startswith("error: ") and "\n" not in err and "Traceback" not in r.output, (err, data[:500])
        assert name in err, (err, data[:500])
    return r.exit_code


def _dump(doc) -> bytes | None:
    try:
        return tomli_w.dumps(doc).encode()
    except (TypeError, ValueError):  # a value TOML cannot hold (the generator made it): not a file anyone can write
        return None


def test_the_base_documents_are_valid(folder):
    assert _check(folder, "scene.toml", tomli_w.dumps(SCENE).encode()) == 0


CASES = {"default": 150, "slow": 3400}  # per kind of file; three kinds: slow generates more than 10,000 files


def _documents(folder, case, base, name, scene):
    """Damaged copies of base written as folder/name, each checked through the scene file `scene`."""
    @settings(max_examples=CASES[case], deadline=None, derandomize=True, database=None,
              suppress_health_check=list(HealthCheck))
    @given(damaged(base))
    def run(damage):
        doc, must_fail = damage
        data = _dump(doc)
        if data is not None:
            status = _check(folder, name, data, scene=scene)
            assert status == 1 or not must_fail, doc

    run()


def _scene_files(folder, case):
    _documents(folder, case, SCENE, "scene.toml", "scene.toml")


def _material_files(folder, case):
    (folder / "uses_material.toml").write_bytes(tomli_w.dumps(
        {**SCENE, "lights": SCENE["lights"][-1:],
         "shapes": [{**SCENE["shapes"][0], "medium": "damaged_material.toml"}]}).encode())
    _documents(folder, case, MATERIAL, "damaged_material.toml", "uses_material.toml")


def _raw_files(folder, case):
    """Bytes that are not TOML, or TOML cut short or spliced."""
    text = tomli_w.dumps(SCENE).encode()

    @settings(max_examples=CASES[case], deadline=None, derandomize=True, database=None,
              suppress_health_check=list(HealthCheck))
    @given(st.one_of(st.binary(max_size=200),
                     st.integers(0, len(text)).map(lambda n: text[:n]),
                     st.tuples(st.integers(0, len(text)), st.binary(min_size=1, max_size=8)).map(
                         lambda t: text[:t[0]] + t[1] + text[t[0]:])))
    def run(data):
        _check(folder, "scene.toml", data)

    run()


@pytest.mark.parametrize("kind", [_scene_files, _material_files, _raw_files], ids=["scene", "material", "raw"])
def test_malformed_files_give_one_line_errors(folder, kind):
    kind(folder, "default")


@pytest.mark.slow
@pytest.mark.parametrize("kind", [_scene_files, _material_files, _raw_files], ids=["scene", "material", "raw"])
def test_ten_thousand_malformed_files_give_one_line_errors(folder, kind):
    kind(folder, "slow")
