"""The preset material files in materials/ and the Material model's validation and unit handling."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pydantic
import pytest

from pbvol_cli.config import Material, load_material

MATERIALS = Path(__file__).resolve().parent.parent / "materials"
FILES = sorted(MATERIALS.glob("*.toml"))

WANG = ["oil", "wine", "wax", "milk", "espresso", "bumpy_sphere"]
JENSEN = [
    "apple", "chicken1", "chicken2", "cream", "ketchup", "marble",
    "potato", "skimmilk", "skin1", "skin2", "spectralon", "wholemilk",
]


def _load(name: str) -> Material:
    return load_material(MATERIALS / f"{name}.toml")


# --------------------------------------------------------------------------- the preset files


def test_count_and_names():
    assert len(FILES) == 18
    assert sorted(p.stem for p in FILES) == sorted(WANG + JENSEN)


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_preset_loads_and_is_physical(path):
    m = load_material(path)
    assert m.name == path.stem
    assert m.source is not None and m.source.strip()
    assert m.phase == "hg"
    assert m.eta > 1.0
    sa, ss = m.coefficients(m.length_unit)
    assert sa.shape == ss.shape == (3,)
    assert np.all(np.isfinite(sa)) and np.all(np.isfinite(ss))
    assert np.all(sa >= 0) and np.all(ss >= 0)
    st = sa + ss
    assert np.all(st > 0)
    albedo = ss / st
    assert np.all((albedo >= 0) & (albedo <= 1))


@pytest.mark.parametrize("name", WANG)
def test_wang_presets_form(name):
    m = _load(name)
    assert m.length_unit == "scene"
    assert m.albedo is not None and m.mean_free_path is not None
    assert m.sigma_a is None and m.sigma_s is None and m.sigma_s_reduced is None
    assert "Wang" in m.source and "not given in the paper" in m.source
    # A scene-unit material goes into a scene of any unit unchanged.
    for unit in ("scene", "mm", "m"):
        np.testing.assert_array_equal(m.coefficients(unit)[0], m.coefficients("scene")[0])


@pytest.mark.parametrize("name", JENSEN)
def test_jensen_presets_form(name):
    m = _load(name)
    assert m.length_unit == "mm"
    assert m.g == 0.0
    assert m.sigma_s_reduced is not None and m.sigma_a is not None and m.diffuse_reflectance is not None
    assert "Jensen, Marschner, Levoy, Hanrahan 2001" in m.source
    sa, ss = m.coefficients("mm")
    np.testing.assert_array_equal(ss, m.sigma_s_reduced)  # g = 0: sigma_s = sigma_s'
    np.testing.assert_array_equal(sa, m.sigma_a)


def test_wax_albedo_mean_free_path():
    m = _load("wax")
    alpha = np.array([0.9803, 0.9615, 0.7500])
    ell = np.array([0.6536, 0.6250, 0.5882])
    assert m.g == 0.8
    sa, ss = m.coefficients("scene")
    st = sa + ss
    np.testing.assert_allclose(st, 1.0 / ell, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ss / st, alpha, rtol=0, atol=1e-12)


def test_bumpy_sphere_values():
    m = _load("bumpy_sphere")
    assert m.albedo == (0.9545, 0.6774, 0.4565)
    assert m.mean_free_path == (4.5455, 3.2258, 2.1739)
    assert m.g == 0.9


def test_marble_unit_conversion():
    m = _load("marble")
    assert m.eta == 1.5
    sa_mm, ss_mm = m.coefficients("mm")
    sa_cm, ss_cm = m.coefficients("cm")
    np.testing.assert_allclose(sa_cm, 10.0 * sa_mm, rtol=1e-12)
    np.testing.assert_allclose(ss_cm, 10.0 * ss_mm, rtol=1e-12)
    np.testing.assert_allclose(ss_mm, [2.19, 2.62, 3.00], rtol=1e-12)
    np.testing.assert_allclose(sa_mm, [0.0021, 0.0041, 0.0071], rtol=1e-12)
    sa_m, _ = m.coefficients("m")
    np.testing.assert_allclose(sa_m, 1000.0 * sa_mm, rtol=1e-12)


@pytest.mark.parametrize("how", ["model_copy", "model_validate"])
def test_jensen_with_anisotropy(how):
    m = _load("skimmilk")
    if how == "model_copy":
        m2 = m.model_copy(update={"g": 0.5})
    else:
        m2 = Material.model_validate({**m.model_dump(), "g": 0.5})
    assert m2.g == 0.5
    sa, ss = m2.coefficients("mm")
    np.testing.assert_allclose(ss, 2.0 * np.asarray(m.sigma_s_reduced), rtol=1e-12)
    np.testing.assert_allclose(sa, m.sigma_a, rtol=1e-12)


def test_scene_unit_material_in_physical_scene_but_not_the_reverse():
    _load("milk").coefficients("mm")  # fine: scene-unit coefficients are taken as they are
    with pytest.raises(ValueError):
        _load("marble").coefficients("scene")


# --------------------------------------------------------------------------- the model's validation

GOOD = {"albedo": [0.5, 0.6, 0.7], "mean_free_path": [1.0, 2.0, 3.0], "g": 0.3, "eta": 1.3}


def test_good_material_validates():
    Material.model_validate(GOOD)


@pytest.mark.parametrize(
    "bad",
    [
        {"albedo": [1.2, 0.5, 0.5]},
        {"albedo": 1.2},
        {"mean_free_path": -1},
        {"mean_free_path": [1.0, -1.0, 1.0]},
        {"g": 1.0},
        {"g": -1.0},
        {"eta": 0},
        {"colour": "red"},  # unknown field
        {"sigma_a": 0.1, "sigma_s": 1.0},  # two complete parameterisations
        {"sigma_a": 0.1, "sigma_s_reduced": 1.0},  # two complete parameterisations
    ],
    ids=[
        "albedo-1.2", "albedo-grey-1.2", "mfp-negative", "mfp-one-negative", "g-1", "g-minus-1",
        "eta-0", "unknown-field", "two-forms-sigma", "two-forms-reduced",
    ],
)
def test_rejects(bad):
    with pytest.raises(pydantic.ValidationError):
        Material.model_validate({**GOOD, **bad})


def test_rejects_no_parameterisation():
    with pytest.raises(pydantic.ValidationError):
        Material.model_validate({"albedo": 0.5})


@pytest.mark.parametrize(
    "stray",
    [
        {"albedo": 0.5, "sigma_a": 0.1, "sigma_s": 1.0},
        {"mean_free_path": 2.0, "sigma_a": 0.1, "sigma_s": 1.0},
        {"albedo": 0.5, "mean_free_path": 2.0, "sigma_s_reduced": 1.0},
    ],
)
def test_stray_field_next_to_complete_form_is_rejected(stray):
    with pytest.raises(pydantic.ValidationError, match="cannot be combined"):
        Material.model_validate(stray)


# --------------------------------------------------------------------------- against the source text

# CI clones the repository with shared/ beside it.
SEEDS = Path(__file__).resolve().parents[2] / "shared" / "seeds"
SEED_WANG = SEEDS / "000_c758302f7812422a.txt"
SEED_JENSEN = SEEDS / "003_8af346c388d70b1b.txt"


def _raw_numbers(name: str, key: str) -> list[str]:
    """The numbers of ``key = [...]`` (or ``key = x``) as written in materials/<name>.toml."""
    text = (MATERIALS / f"{name}.toml").read_text()
    m = re.search(rf"^{key} = \[([^\]]*)\]", text, re.M)
    if m:
        return [s.strip() for s in m.group(1).split(",")]
    return [re.search(rf"^{key} = (\S+)", text, re.M).group(1)]


@pytest.mark.skipif(not SEED_WANG.exists(), reason="seed text not available")
def test_wang_numbers_match_source_text():
    lines = SEED_WANG.read_text().splitlines()
    for name in ["Oil", "Wine", "Wax", "Milk", "Espresso"]:
        row = next(l for l in lines if l.startswith(name + "\t")).split("\t")
        key = name.lower()
        assert _raw_numbers(key, "albedo") == row[1:4]
        assert _raw_numbers(key, "mean_free_path") == row[4:7]
        assert _raw_numbers(key, "g") == [row[7]]
    caption = next(l for l in lines if l.startswith("Figure 4:"))
    nums = re.findall(r"\d+\.\d+", caption)
    assert _raw_numbers("bumpy_sphere", "albedo") == nums[0:3]
    assert _raw_numbers("bumpy_sphere", "mean_free_path") == nums[3:6]
    assert _raw_numbers("bumpy_sphere", "g") == [nums[6]]


@pytest.mark.skipif(not SEED_JENSEN.exists(), reason="seed text not available")
def test_jensen_numbers_match_source_text():
    lines = SEED_JENSEN.read_text().splitlines()
    i = next(i for i, l in enumerate(lines) if l.startswith("Material\t$\\sigma'_s$"))
    rows = [l.split("\t") for l in lines[i + 2 : i + 14]]
    assert sorted(r[0].lower() for r in rows) == sorted(JENSEN)
    for row in rows:
        key = row[0].lower()
        assert _raw_numbers(key, "sigma_s_reduced") == row[1:4]
        assert _raw_numbers(key, "sigma_a") == row[4:7]
        assert _raw_numbers(key, "diffuse_reflectance") == row[7:10]
        assert _raw_numbers(key, "eta") == [row[10]]
