"""The scene and material formats described from their Pydantic models: the JSON Schema (`pbvol schema`) and the
field reference docs/scene-format.md (`pbvol schema --markdown`), so that the documentation cannot drift from
what the loader accepts (tests/test_config_reference.py checks the committed file)."""

from __future__ import annotations

import json

from pydantic import BaseModel

from pbvol_cli import config as C

SCHEMAS = {"scene": C.Scene, "material": C.Material}

EXAMPLE = '''\
unit = "cm"                       # one scene unit is a centimetre

[camera]
position = [0.0, 8.0, 30.0]
look_at = [0.0, 4.0, 0.0]
fov = 35.0                        # vertical, degrees
resolution = [256, 256]

[render]
spp = 16
seed = 1

[[lights]]                        # a small sphere light: give radiance or total power
type = "sphere"
center = [-10.0, 16.0, -9.0]
radius = 0.5
power = 2000.0                    # W, grey; [r, g, b] for a colour

[[lights]]                        # a soft box above: emits on the side edge1 x edge2 points to (-y: down)
type = "quad"
corner = [-8.0, 20.0, -8.0]
edge1 = [16.0, 0.0, 0.0]
edge2 = [0.0, 0.0, 16.0]
radiance = 2.0

[[lights]]
type = "environment"
radiance = [0.05, 0.05, 0.06]

[[shapes]]                        # a marble statue: a closed mesh holding a medium
type = "mesh"
file = "statue.obj"               # relative to this file
interface = "dielectric"          # eta: the medium's (1.5 for the marble preset)
medium = "marble"                 # preset, per mm: converted to cm by `unit`
transform = { scale = 2.0, rotate = [0.0, 30.0, 0.0], translate = [0.0, 0.0, 0.0] }

[[shapes]]
type = "sphere"
center = [7.0, 2.0, 0.0]
radius = 2.0
interface = "dielectric"
medium = { albedo = [0.99, 0.95, 0.9], mean_free_path = 0.2, g = 0.3, eta = 1.4 }

[[shapes]]                        # the floor: a quad in the xz plane, normal +y
type = "quad"
size = [100.0, 100.0]
albedo = 0.5
'''


def json_schema(kind: str = "scene") -> dict:
    """The JSON Schema of a scene file (kind "scene") or a material file ("material")."""
    return SCHEMAS[kind].model_json_schema()


def _bounds(p: dict) -> str:
    parts = []
    for key, sym in (("minimum", ">="), ("exclusiveMinimum", ">"), ("maximum", "<="), ("exclusiveMaximum", "<")):
        if key in p:
            parts.append(f"{sym} {p[key]:g}")
    return ", ".join(parts)


def _type(p: dict) -> str:
    """A field's JSON schema as a short type."""
    if "$ref" in p:
        name = p["$ref"].rsplit("/", 1)[-1]
        return "material" if name == "Material" else f"[{name}](#{name.lower()})"
    if "anyOf" in p:
        options = [o for o in p["anyOf"] if o.get("type") != "null"]
        if len(options) == 2 and options[0].get("type") == "number" and options[1].get("type") == "array":
            b = _bounds(options[0])
            return "colour: number or [R, G, B]" + (f" (each {b})" if b else "")
        if any(o.get("$ref", "").endswith("/Material") for o in options):
            return "material: preset name, file (.toml) or inline table"
        return " or ".join(_type(o) for o in options)
    if "const" in p:
        return json.dumps(p["const"])
    if "enum" in p:
        return " \\| ".join(json.dumps(v) for v in p["enum"])
    t = p.get("type")
    if t == "array":
        if "prefixItems" in p:
            n, inner = len(p["prefixItems"]), {_type(q) for q in p["prefixItems"]}
            return ("[x, y, z]" if n == 3 else f"{n} numbers") + f" ({inner.pop()})"
        items = p.get("items", {})
        if "oneOf" in items:
            return "list of tables, by `type` (below)"
        if "enum" in items:
            return "list of " + " \\| ".join(json.dumps(v) for v in items["enum"])
        return f"list of {_type(items)}"
    if t == "object":
        return f"table of {_type(p.get('additionalProperties', {}))}"
    names = {"integer": "int", "number": "float", "string": "string", "boolean": "bool"}
    b = _bounds(p)
    return names.get(t, str(t)) + (f", {b}" if b else "")


def _default(model: type[BaseModel], name: str) -> str:
    field = model.model_fields[name]
    if field.is_required():
        return "required"
    if field.default_factory is not None:
        return f"`{json.dumps(field.default_factory())}`" if field.default_factory in (list, dict) else "see below"
    d = field.default
    if d is None:
        return "none"
    if isinstance(d, BaseModel):
        return "its defaults"
    if isinstance(d, tuple):
        d = list(d)
    return f"`{json.dumps(d)}`"


def _table(model: type[BaseModel], skip: tuple[str, ...] = ()) -> list[str]:
    props = model.model_json_schema()["properties"]
    rows = ["| field | type | default | meaning |", "|---|---|---|---|"]
    for name in model.model_fields:
        if name in skip:
            continue
        p = props[name]
        desc = (model.model_fields[name].description or "").replace("|", "\\|")
        rows.append(f"| `{name}` | {_type(p)} | {_default(model, name)} | {desc} |")
    return rows


def _section(title: str, model: type[BaseModel], skip: tuple[str, ...] = (), level: int = 2) -> list[str]:
    anchor = f'<a id="{model.__name__.lower()}"></a>'
    doc = " ".join((model.__doc__ or "").split())
    return [f"{'#' * level} {title} {anchor}", "", *([doc, ""] if doc else []), *_table(model, skip), ""]


def markdown_reference() -> str:
    """docs/scene-format.md."""
    out = [
        "# Scene and material files",
        "",
        "Generated from the Pydantic models in `pbvol_cli/config.py` by `pbvol schema --markdown > "
        "docs/scene-format.md`; a test checks that this file matches them. `pbvol schema` prints the JSON Schema of "
        "a scene file (`pbvol schema material`: of a material file), for editors and validators.",
        "",
        "Conventions. A scene is a TOML file. Lengths are in scene units; the scene's `unit` says what a unit is, "
        "so that materials given per mm convert. Positions and directions are `[x, y, z]`; y is up in the "
        "examples, by convention only (the camera's `up` decides). A colour field takes one number (grey) or "
        "`[R, G, B]`. Radiance is in W sr⁻¹ per scene unit², power in W. Unknown fields are errors. `pbvol check "
        "SCENE` validates a scene and describes what the renderer will see.",
        "",
        "## A complete scene",
        "",
        "A mesh of marble and a sphere of an inline medium on a floor, lit by a sphere light, a quad light and a "
        "dim sky:",
        "",
        "```toml",
        EXAMPLE.rstrip(),
        "```",
        "",
    ]
    out += _section("The scene file (top level)", C.Scene)
    out += _section("`[camera]`", C.Camera)
    out += _section("`[render]`", C.RenderSettings)
    out += _section("`[render.volpath]`", C.VolpathSettings, level=3)
    out += _section("`[render.lut]`", C.LutSettings, level=3)
    out += _section("`[render.pbl]`", C.PblSettings, level=3)
    out += _section("`[render.dipole]`", C.DipoleSettings, level=3)
    out += _section("`[render.raymarch]`", C.RaymarchSettings, level=3)
    out += _section("`[render.vpl]`", C.VplSettings, level=3)
    out += ["## `[[lights]]`", "", "Each light is a table with a `type`; a scene needs at least one.", ""]
    for cls in (C.PointLight, C.DirectionalLight, C.SphereLight, C.QuadLight, C.EnvironmentLight):
        kind = cls.model_fields["type"].annotation.__args__[0]
        out += _section(f'`type = "{kind}"`', cls, skip=("type",), level=3)
    out += ["## `[[shapes]]`", "",
            "Each shape is a table with a `type`, the fields of every shape, and its own. The geometric normal of "
            "every surface points to its exterior; each surface names the media and indices on both sides, so "
            "nested media (a glass of liquid) need no special mode.", ""]
    out += _section("Fields of every shape", C.ShapeBase, level=3)
    for cls in (C.SphereShape, C.BumpySphereShape, C.BoxShape, C.CylinderShape, C.QuadShape, C.CupShape,
                C.MeshShape):
        kind = cls.model_fields["type"].annotation.__args__[0]
        own = tuple(n for n in cls.model_fields if n not in C.ShapeBase.model_fields and n != "type")
        out += _section(f'`type = "{kind}"`', cls, skip=tuple(n for n in cls.model_fields if n not in own), level=3)
    out += _section("`transform`", C.Transform, level=3)
    out += _section("Materials", C.Material)
    out += ["A material is a file (`materials/*.toml` are the presets, `pbvol materials` lists them), a table "
            "`[materials.NAME]` in the scene, or an inline table in a shape's `medium`.", ""]
    return "\n".join(out)
