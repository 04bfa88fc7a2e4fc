"""docs/scene-format.md and `pbvol schema` describe exactly what the loader accepts."""

import re
import tomllib
from pathlib import Path

import jsonschema
import numpy as np
import pytest
import trimesh

from conftest import write_scene
from pbvol_cli import config as C
from pbvol_cli.config_reference import json_schema, markdown_reference
from pbvol_cli.geometry.scene_build import build_scene
from pbvol_cli.physics.lights import LIGHT_RGB

ROOT = Path(__file__).resolve().parents[1]


def test_the_committed_reference_matches_the_models():
    """Regenerate with: .venv/bin/pbvol schema --markdown > docs/scene-format.md"""
    assert (ROOT / "docs" / "scene-format.md").read_text() == markdown_reference() + "\n"


@pytest.mark.parametrize("kind, folder", [("scene", "configs"), ("scene", "benchmarks/scenes"),
                                          ("material", "materials")])
def test_every_shipped_file_validates_against_the_schema(kind, folder):
    validator = jsonschema.Draft202012Validator(json_schema(kind))
    files = sorted((ROOT / folder).glob("*.toml"))
    assert files
    for f in files:
        errors = [e.message for e in validator.iter_errors(tomllib.loads(f.read_text()))]
        assert not errors, (f.name, errors)


def test_colour_fields_take_one_number_or_three_and_the_schema_says_so():
    validator = jsonschema.Draft202012Validator(json_schema("scene"))
    scene = {"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]},
             "lights": [{"type": "sphere", "center": [0, 3, 0], "radius": 0.5, "radiance": 2.0}]}
    assert validator.is_valid(scene)
    scene["lights"][0]["radiance"] = [1.0, 2.0, 3.0]
    assert validator.is_valid(scene)
    scene["lights"][0]["radiance"] = [1.0, 2.0]
    assert not validator.is_valid(scene)
    scene["shapes"] = [{"type": "sphere", "albedo": 1.5}]  # an albedo is within [0, 1]
    scene["lights"][0]["radiance"] = 1.0
    assert not validator.is_valid(scene)
    assert "colour: number or [R, G, B]" in markdown_reference()


def test_the_reference_example_is_a_complete_scene(tmp_path):
    """The example in docs/scene-format.md validates and builds (with a mesh file beside it): a newcomer can start
    from it. Its quad light emits downward, as its comment says."""
    example = re.search(r"```toml\n(.*?)```", markdown_reference(), re.S).group(1)
    data = tomllib.loads(example)
    assert jsonschema.Draft202012Validator(json_schema("scene")).is_valid(data)
    trimesh.creation.icosphere(subdivisions=2, radius=1.0).export(tmp_path / "statue.obj")
    path = write_scene(tmp_path, data)
    built = build_scene(C.load_scene(path), path)
    quad = C.QuadLight.model_validate(data["lights"][1])
    assert np.cross(quad.edge1, quad.edge2)[1] < 0
    assert built.lights[0, LIGHT_RGB] > 0 and len(built.faces) > 0
