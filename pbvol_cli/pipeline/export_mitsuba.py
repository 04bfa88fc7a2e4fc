"""`pbvol export-mitsuba`: a pbvol scene as a Mitsuba 3 scene, to cross-check pbvol's `volpath` with Mitsuba's.

Two forms, chosen by the output's suffix:
- `.json`: the dictionary `mi.load_dict` takes. JSON holds no Mitsuba objects, so a transform is written as
  {"type": "transform", "matrix": [[4 rows of 4]]} (row-major, column vectors: the last column is the
  translation), and a "filename" is relative to the JSON file's folder. `benchmarks/mitsuba_reference.py`'s
  `load_dict_form` turns both into what `mi.load_dict` wants (mi.ScalarTransform4f, absolute paths).
- `.xml`: Mitsuba's scene format (`mi.load_file`), the same objects; its files are relative to the XML file.
Meshes and volume grids go beside the output as `<stem>.<key>.ply` and `<stem>.<key>.vol`.

What maps to what (lengths in scene units, coefficients per scene unit, as pbvol resolves them):
- camera -> `perspective`: vertical `fov` (fov_axis y), look-at frame as a to_world matrix (Mitsuba's film x runs
  along the frame's -x: the image is pbvol's, not mirrored), `hdrfilm` of the resolution with a `box` filter,
  an `independent` sampler with the spp and seed. near/far clip: 1e-6 and 1 times a power of ten above 4 times
  the farthest point of the scene from the camera (pbvol has no clip planes).
- render -> `volpath`. pbvol's max_depth D counts scattering events and non-null surface interactions and keeps a
  path's light after up to D of them; Mitsuba's max_depth counts path segments (1: only emitters seen directly), so
  it gets D + 1. pbvol's Russian roulette starts once a path has had rr_depth R interactions; Mitsuba's once it has
  had more than rr_depth: it gets max(R - 1, 0). Both undo the eta^2 radiance scale in the survival probability;
  Mitsuba caps it at 0.95, pbvol does not (a difference in noise only). Mitsuba's sampler and light selection
  differ from pbvol's: the images agree in expectation, not pixel for pixel.
- shapes: `sphere` -> `sphere` (center, radius after the transform; analytic in both), `box` -> `cube` and `quad`
  -> `rectangle` (a to_world matrix: the same flat faces), `cylinder`, `bumpy_sphere`, `cup` and `mesh` -> `ply`
  files of the triangles and shading normals pbvol builds (geometry/primitives.py: a cylinder's facets, a mesh file
  as pbvol reads it, any transform applied), one file per cup surface (glass, glass-liquid, free surface).
- interfaces: dielectric -> `dielectric` with int_ior / ext_ior the interior / exterior index (equal indices ->
  `null`, as pbvol does), null -> `null`, diffuse -> `twosided` `diffuse` (pbvol's reflects on both sides), mirror
  -> `twosided` `conductor` of material "none" (a perfect mirror) times the albedo.
- media: every shape names the media on both of its sides (`interior`, `exterior`, references to one top-level
  medium each), so nested media need nothing more. Homogeneous -> `homogeneous` with sigma_t / max(sigma_t) as RGB
  and scale max(sigma_t) (Mitsuba's RGB values are bounded by 1), albedo sigma_s / sigma_t. A density grid ->
  `heterogeneous` with a `gridvolume` (.vol file: density x scale x sigma_t / max, one channel when sigma_t is grey,
  else three: an RGB variant; trilinear between voxel centres and clamped at the border, 0 outside the box, as
  pbvol). Phases `isotropic`, `hg`, `rayleigh` map to Mitsuba's.
- lights: point -> `point` (intensity), directional -> `directional` (irradiance, direction of travel), sphere ->
  a `sphere` shape with an `area` emitter and a black BSDF (pbvol's lights absorb what meets them), quad -> a
  `rectangle` the same way (two_sided: a second one flipped, 1e-6 of its size behind it, since Mitsuba's area
  emitters emit on one side), environment -> `constant` (several summed: Mitsuba takes one environment).

What Mitsuba 3 lacks (a ConfigError naming the scene file and the field, or a warning returned):
- emission in a medium: error (Mitsuba's media do not emit; the export would lose that light);
- an exponential density: warning; baked into a grid of its values at voxel centres (trilinear), its largest
  relative error (prod cosh(b u_k h_k / 2) - 1 for spacing h_k) in the message;
- the phases `schlick`, `mie_hazy`, `mie_murky`: warning; tabulated (`tabphase`, TABPHASE_POINTS cosines, linear
  between them), the table's largest relative error in the message.
pbvol's other settings ([render.pbl], threads, time_limit, ...) belong to other methods or to the run, not to
the image, and are left out.
"""

from __future__ import annotations

import json
import math
import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pbvol_cli import config as C
from pbvol_cli.errors import ConfigError, PbvolError
from pbvol_cli.geometry.scene_build import SceneMedia
from pbvol_cli.pipeline.cache import write_bytes_atomic
from pbvol_cli.physics.phase import KINDS, phase_eval

FORMATS = (".json", ".xml")
TABPHASE_POINTS = 1025  # cosines of a tabulated phase function, regularly spaced over [-1, 1]
BAKE_TOLERANCE = 1e-4  # relative error per axis of a baked exponential density
BAKE_MAX_PER_AXIS = 1024
BAKE_MAX_VOXELS = 1 << 24  # 64 MB of float32
TWO_SIDED_GAP = 1e-6  # the gap between a two-sided quad light's rectangles, relative to its size

# The XML element of each plugin type the export writes (load_dict infers it; XML names it).
PLUGIN_TAGS = {
    "volpath": "integrator", "volpathmis": "integrator", "path": "integrator", "perspective": "sensor",
    "independent": "sampler", "hdrfilm": "film", "box": "rfilter", "sphere": "shape", "rectangle": "shape",
    "cube": "shape", "ply": "shape", "obj": "shape", "null": "bsdf", "dielectric": "bsdf", "conductor": "bsdf",
    "diffuse": "bsdf", "twosided": "bsdf", "homogeneous": "medium", "heterogeneous": "medium",
    "isotropic": "phase", "hg": "phase", "rayleigh": "phase", "tabphase": "phase", "gridvolume": "volume",
    "area": "emitter", "point": "emitter", "directional": "emitter", "constant": "emitter",
}
POINT_KEYS = {"center", "position"}  # a 3-vector under these keys is an XML <point>, under others a <vector>


@dataclass
class MitsubaExport:
    """A scene in Mitsuba's terms: the load_dict dictionary (transforms as {"type": "transform", ...}), the files
    it names (name beside the output -> bytes), and the warnings (approximations)."""

    scene: dict
    files: dict[str, bytes] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def export_mitsuba(scene_path: Path, out_path: Path, spp: int | None = None, resolution=None) -> list[str]:
    """Write the scene file scene_path as a Mitsuba 3 scene at out_path (.json: the load_dict form; .xml), its meshes
    and grids beside it, each file written to a temporary name and renamed. spp, resolution (W, H): override the
    scene's. Returns the warnings; raises PbvolError (ConfigError naming the file and field) otherwise."""
    scene_path, out_path = Path(scene_path), Path(out_path)
    suffix = out_path.suffix.lower()
    if suffix not in FORMATS:
        raise PbvolError(f"{out_path}: expected a .json (mi.load_dict form) or .xml output, got {suffix or 'none'!r}")
    if spp is not None and not 1 <= spp <= C.MAX_SPP:
        raise PbvolError(f"--spp: expected 1 to {C.MAX_SPP}, got {spp}")
    if resolution is not None and not (len(resolution) == 2 and all(1 <= x <= C.MAX_RESOLUTION for x in resolution)):
        raise PbvolError(f"--resolution: expected W x H, each 1 to {C.MAX_RESOLUTION}, got {resolution}")
    scene = C.load_scene(scene_path)
    exported = mitsuba_scene(scene, scene_path, out_path.stem, spp, resolution)
    text = to_json(exported.scene) if suffix == ".json" else to_xml(exported.scene)
    try:
        out_path.parent.mkdir(parents=True, exist_ok=True)
        for name, data in exported.files.items():
            write_bytes_atomic(out_path.parent / name, data)
        write_bytes_atomic(out_path, text.encode())
    except OSError as e:
        raise PbvolError(f"{out_path}: cannot write: {e.strerror or e}") from None
    return exported.warnings


# --------------------------------------------------------------------------- the scene


class _Export:
    """The export under construction: media by config.medium_key, what bounds each medium (for baking), the scene's
    points (for the clip planes)."""

    def __init__(self, scene: C.Scene, path: Path, stem: str):
        self.scene, self.path, self.stem = scene, path, stem
        self.table = SceneMedia(scene, path)
        self.media = [(m.label, m.material, m.sigma_a, m.sigma_s) for m in self.table.info]
        self.bounding: dict[int, list[np.ndarray]] = {}  # medium -> points of the surfaces with it on a side
        self.points: list[np.ndarray] = []
        self.objects: dict[str, dict] = {}  # shapes and lights, in the scene's order
        self.out = MitsubaExport({"type": "scene"})

    def medium(self, ref, fld: str) -> int:
        return self.table.get(ref, fld)

    def eta(self, k: int) -> float | None:
        return self.table.eta(k)

    def add_points(self, pts, media=()):
        pts = np.asarray(pts, float).reshape(-1, 3)
        self.points.append(pts)
        for k in media:
            if k >= 0:
                self.bounding.setdefault(k, []).append(pts)


def mitsuba_scene(scene: C.Scene, path: Path, stem: str = "scene", spp: int | None = None,
                  resolution=None) -> MitsubaExport:
    """The Mitsuba 3 scene of a validated pbvol scene (path: where its relative files are, and how errors name it;
    stem: the prefix of the files beside the output). Reads the meshes and grids; writes nothing. Its keys: the
    integrator, the sensor, the media (before the shapes that refer to them), shapes, lights."""
    path = Path(path)
    ex = _Export(scene, path, stem)
    _check_media(ex)
    w, h = resolution or scene.camera.resolution
    rs = scene.render
    for i, shape in enumerate(scene.shapes):
        _shape(ex, i, shape)
    _lights(ex)
    d = ex.out.scene
    d["integrator"] = {"type": "volpath", "max_depth": int(rs.max_depth) + 1,
                       "rr_depth": max(int(rs.volpath.rr_depth) - 1, 0), "hide_emitters": False}
    d["sensor"] = _sensor(ex, int(w), int(h), int(spp if spp is not None else rs.spp), int(rs.seed))
    for k in range(len(ex.media)):
        d[_medium_key(k)] = _medium(ex, k)
    d.update(ex.objects)
    return ex.out


def _medium_key(k: int) -> str:
    return f"medium_{k}"


def _ref(k: int) -> dict:
    return {"type": "ref", "id": _medium_key(k)}


def _rgb(v) -> dict:
    return {"type": "rgb", "value": [float(x) for x in v]}


def _black() -> dict:
    """A light's BSDF: pbvol's lights absorb what meets them."""
    return {"type": "diffuse", "reflectance": _rgb((0.0, 0.0, 0.0))}


def transform_entry(M: np.ndarray) -> dict:
    """The JSON form of a 4x4 transform (row-major)."""
    return {"type": "transform", "matrix": [[float(x) for x in row] for row in np.asarray(M, float)]}


def _material_field(ex: _Export, k: int, name: str) -> str:
    """The scene field that sets medium k's `name`: its [materials] entry's, an inline table's, else the field of
    the first shape naming the medium (a preset or a material file)."""
    label, mat = ex.media[k][0], ex.media[k][1]
    if ex.scene.materials.get(label) == mat:
        return f"materials.{label}.{name}"
    for i, shape in enumerate(ex.scene.shapes):
        for fld in C.MEDIUM_FIELDS:
            ref = getattr(shape, fld, None)
            if ref is not None and ex.medium(ref, f"shapes[{i}].{fld}") == k:
                return f"shapes[{i}].{fld}" + (f".{name}" if isinstance(ref, C.Material) else "")
    return label


def _check_media(ex: _Export):
    for k, (label, mat, _, _) in enumerate(ex.media):
        if mat.emission is not None and any(x > 0 for x in mat.emission):
            raise ConfigError(ex.path, _material_field(ex, k, "emission"),
                              f"medium {label!r} has emission {list(mat.emission)}: Mitsuba 3's media do not emit "
                              "light, so the export would lose it; cannot export")


# --------------------------------------------------------------------------- camera


def look_at_matrix(cam: C.Camera) -> np.ndarray:
    """Mitsuba's look-at camera-to-world matrix: columns (left, up, forward, position); pbvol's image right is
    -left, its up the same up (scene_build.camera_params)."""
    pos = np.asarray(cam.position, float)
    fwd = np.asarray(cam.look_at, float) - pos
    fwd /= np.linalg.norm(fwd)
    left = np.cross(np.asarray(cam.up, float), fwd)
    left /= np.linalg.norm(left)
    up = np.cross(fwd, left)
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = left, up, fwd, pos
    return M


def _sensor(ex: _Export, w: int, h: int, spp: int, seed: int) -> dict:
    cam = ex.scene.camera
    pts = np.concatenate(ex.points) if ex.points else np.zeros((1, 3))
    far = 4.0 * max(float(np.max(np.linalg.norm(pts - np.asarray(cam.position), axis=1))), 1e-30)
    far_clip = 10.0 ** math.ceil(math.log10(far))
    return {"type": "perspective", "fov": float(cam.fov), "fov_axis": "y", "near_clip": far_clip * 1e-6,
            "far_clip": far_clip, "to_world": transform_entry(look_at_matrix(cam)),
            "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
            "film": {"type": "hdrfilm", "width": w, "height": h, "pixel_format": "rgb", "component_format": "float32",
                     "rfilter": {"type": "box"}}}


# --------------------------------------------------------------------------- shapes


def _bsdf(kind: str, eta_in: float, eta_out: float, albedo) -> dict:
    if kind == "dielectric" and eta_in != eta_out:
        return {"type": "dielectric", "int_ior": float(eta_in), "ext_ior": float(eta_out)}
    if kind in ("dielectric", "null"):
        return {"type": "null"}
    if kind == "mirror":
        return {"type": "twosided", "bsdf": {"type": "conductor", "material": "none",
                                             "specular_reflectance": _rgb(albedo)}}
    return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": _rgb(albedo)}}


def _with_media(entry: dict, m_in: int, m_out: int) -> dict:
    if m_in >= 0:
        entry["interior"] = _ref(m_in)
    if m_out >= 0:
        entry["exterior"] = _ref(m_out)
    return entry


def _shape(ex: _Export, i: int, shape):
    """The Mitsuba shapes of pbvol shape i: its surfaces' BSDFs and media as scene_build.build_scene sets them."""
    from pbvol_cli.geometry.primitives import shape_parts  # trimesh import deferred

    fld = f"shapes[{i}]"
    m_in = ex.medium(shape.medium, f"{fld}.medium")
    m_out = ex.medium(shape.exterior_medium, f"{fld}.exterior_medium")
    eta_out = shape.exterior_eta
    if shape.interface == "dielectric":
        eta_in = shape.eta if shape.eta is not None else (ex.eta(m_in) or 1.5)
    else:
        eta_in = eta_out
    roles = {"body": (shape.interface, m_in, m_out, eta_in, eta_out)}
    if isinstance(shape, C.CupShape):
        liquid = ex.medium(shape.liquid, f"{fld}.liquid")
        eta_l = shape.liquid_eta or ex.eta(liquid) or 1.33
        roles["glass"] = roles["body"]
        roles["liquid_glass"] = ("dielectric", liquid, m_in, eta_l, eta_in)
        roles["liquid_free"] = ("dielectric", liquid, m_out, eta_l, eta_out)
    d = ex.objects
    key = f"shape_{i}"
    if isinstance(shape, C.SphereShape):
        c, r = np.asarray(shape.center, float), float(shape.radius)
        if shape.transform is not None:
            s = np.asarray(shape.transform.scale)
            if np.ptp(s) > 1e-12 * s.max():
                raise ConfigError(ex.path, f"{fld}.transform.scale",
                                  "a sphere takes only a uniform scale (use a mesh for an ellipsoid)")
            M = shape.transform.matrix()
            c, r = M[:3, :3] @ c + M[:3, 3], r * float(s[0])
        ex.add_points([c - r, c + r], (m_in, m_out))
        d[key] = _with_media({"type": "sphere", "center": [float(x) for x in c], "radius": r,
                              "bsdf": _bsdf(shape.interface, eta_in, eta_out, shape.albedo)}, m_in, m_out)
        return
    try:
        parts = shape_parts(shape, ex.path.parent)
    except ValueError as e:
        raise ConfigError(ex.path, fld + (".file" if shape.type == "mesh" else ""), str(e)) from None
    M = shape.transform.matrix() if shape.transform is not None else np.eye(4)
    if isinstance(shape, (C.BoxShape, C.QuadShape)):
        ex.add_points(np.concatenate([p.vertices for p in parts]), (m_in, m_out))
        if isinstance(shape, C.BoxShape):
            local = np.diag([*(0.5 * np.asarray(shape.size, float)), 1.0])
            entry = {"type": "cube"}
        else:  # Mitsuba's rectangle: [-1, 1]^2 in z = 0, normal +z -> pbvol's xz quad, normal +y
            hx, hz = 0.5 * shape.size[0], 0.5 * shape.size[1]
            local = np.array([[hx, 0, 0, 0], [0, 0, 1, 0], [0, -hz, 0, 0], [0, 0, 0, 1]], float)
            entry = {"type": "rectangle"}
        T = np.eye(4)
        T[:3, 3] = shape.center
        entry["to_world"] = transform_entry(M @ T @ local)
        entry["bsdf"] = _bsdf(shape.interface, eta_in, eta_out, shape.albedo)
        d[key] = _with_media(entry, m_in, m_out)
        return
    for role, (kind, a, b, e_in, e_out) in roles.items():
        mine = [p for p in parts if p.role == role]
        if not mine:
            continue
        name = key if role == "body" else f"{key}_{role}"
        V, N, F = _merged(mine)
        ex.add_points(V, (a, b))
        fname = f"{ex.stem}.{name}.ply"
        ex.out.files[fname] = ply_bytes(V, N, F)
        d[name] = _with_media({"type": "ply", "filename": fname, "bsdf": _bsdf(kind, e_in, e_out, shape.albedo)},
                              a, b)


def _merged(parts) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices, unit normals, faces) of mesh parts in one mesh: flat parts get their face normal at each corner."""
    Vs, Ns, Fs, n = [], [], [], 0
    for p in parts:
        V, F = np.asarray(p.vertices, float), np.asarray(p.faces, np.int64)
        if p.normals is None:
            V = V[F].reshape(-1, 3)
            fn = np.cross(V[1::3] - V[0::3], V[2::3] - V[0::3])
            fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
            N = np.repeat(fn, 3, axis=0)
            F = np.arange(len(V)).reshape(-1, 3)
        else:
            N = np.asarray(p.normals, float)
        Vs.append(V)
        Ns.append(N)
        Fs.append(F + n)
        n += len(V)
    return np.concatenate(Vs), np.concatenate(Ns), np.concatenate(Fs)


def ply_bytes(V: np.ndarray, N: np.ndarray, F: np.ndarray) -> bytes:
    """A binary little-endian PLY of vertices with normals (float32) and triangles."""
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(V)}\n"
              + "".join(f"property float {c}\n" for c in ("x", "y", "z", "nx", "ny", "nz"))
              + f"element face {len(F)}\nproperty list uchar int vertex_indices\nend_header\n")
    verts = np.concatenate([V, N], axis=1).astype("<f4")
    faces = np.zeros(len(F), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"], faces["i"] = 3, F
    return header.encode() + verts.tobytes() + faces.tobytes()


# --------------------------------------------------------------------------- lights


def _lights(ex: _Export):
    d = ex.objects
    env = np.zeros(3)
    for i, L in enumerate(ex.scene.lights):
        key = f"light_{i}"
        if L.type == "point":
            ex.add_points([L.position])
            d[key] = {"type": "point", "position": [float(x) for x in L.position], "intensity": _rgb(L.intensity)}
        elif L.type == "directional":
            u = np.asarray(L.direction, float) / np.linalg.norm(L.direction)
            d[key] = {"type": "directional", "direction": [float(x) for x in u], "irradiance": _rgb(L.irradiance)}
        elif L.type == "sphere":
            c = np.asarray(L.center, float)
            ex.add_points([c - L.radius, c + L.radius])
            d[key] = {"type": "sphere", "center": [float(x) for x in c], "radius": float(L.radius), "bsdf": _black(),
                      "emitter": {"type": "area", "radiance": _rgb(L.emitted_radiance())}}
        elif L.type == "quad":
            p0, e1, e2 = (np.asarray(v, float) for v in (L.corner, L.edge1, L.edge2))
            n = np.cross(e1, e2)
            n /= np.linalg.norm(n)
            ex.add_points([p0, p0 + e1, p0 + e2, p0 + e1 + e2])
            gap = TWO_SIDED_GAP * math.sqrt(L.area()) if L.two_sided else 0.0
            sides = [(1.0, False)] + ([(-1.0, True)] if L.two_sided else [])
            for s, flip in sides:
                M = np.eye(4)
                M[:3, 0], M[:3, 1], M[:3, 2] = 0.5 * e1, 0.5 * e2, n
                M[:3, 3] = p0 + 0.5 * (e1 + e2) + s * 0.5 * gap * n
                entry = {"type": "rectangle", "to_world": transform_entry(M), "bsdf": _black(),
                         "emitter": {"type": "area", "radiance": _rgb(L.emitted_radiance())}}
                if flip:
                    entry["flip_normals"] = True
                d[key + ("_back" if flip else "")] = entry
        else:
            env += np.asarray(L.radiance, float)
    if any(L.type == "environment" for L in ex.scene.lights):
        d["environment"] = {"type": "constant", "radiance": _rgb(env)}


# --------------------------------------------------------------------------- media


def _medium(ex: _Export, k: int) -> dict:
    label, mat, sigma_a, sigma_s = ex.media[k]
    sigma_t = sigma_a + sigma_s
    smax = float(sigma_t.max())
    albedo = np.where(sigma_t > 0, sigma_s / np.where(sigma_t > 0, sigma_t, 1.0), 0.0)
    entry = {"type": "homogeneous", "albedo": _rgb(albedo), "sigma_t": _rgb(sigma_t / smax if smax > 0 else sigma_t),
             "scale": smax if smax > 0 else 1.0, "phase": _phase(ex, k, mat)}
    dens = mat.density
    if dens is None:
        return entry
    if isinstance(dens, C.GridDensity):
        from pbvol_cli.geometry.density_grid import load_grid

        grid, _ = load_grid(ex.path, dens, f"medium {label!r}")
        grid, lo, hi = grid * dens.scale, np.asarray(dens.bounds[0], float), np.asarray(dens.bounds[1], float)
    else:
        grid, lo, hi = _bake_exponential(ex, k, dens)
    rel = sigma_t / smax if smax > 0 else np.ones(3)
    data = grid.transpose(2, 1, 0)[..., None]  # Mitsuba's order: z, y, x, channel
    if np.ptp(rel) > 0:
        data = data * rel
    fname = f"{ex.stem}.{_medium_key(k)}.vol"
    ex.out.files[fname] = vol_bytes(data, lo, hi)
    T = np.diag([*(hi - lo), 1.0])
    T[:3, 3] = lo
    entry["type"] = "heterogeneous"
    entry["sigma_t"] = {"type": "gridvolume", "filename": fname, "to_world": transform_entry(T)}
    return entry


def vol_bytes(data: np.ndarray, lo, hi) -> bytes:
    """Mitsuba's .vol grid (version 3, float32) of data shaped (z, y, x, channels), spanning the box lo..hi."""
    nz, ny, nx, nc = data.shape
    header = b"VOL" + bytes([3]) + struct.pack("<5i", 1, nx, ny, nz, nc) + struct.pack("<6f", *lo, *hi)
    return header + np.ascontiguousarray(data, "<f4").tobytes()


def _bake_exponential(ex: _Export, k: int, dens: C.ExponentialDensity):
    """(grid (nx, ny, nz), lo, hi): a e^(-b h) at voxel centres placed on the medium's bounding box (its ends
    included), so that trilinear interpolation covers the box; a warning gives its largest relative error."""
    fld = _material_field(ex, k, "density")
    pts = ex.bounding.get(k)
    if not pts:
        raise ConfigError(ex.path, fld, "an exponential density needs a medium bounded by a shape")
    p = np.concatenate(pts)
    lo, hi = p.min(0), p.max(0)
    up = np.asarray(dens.up, float) / np.linalg.norm(dens.up)
    slope = np.abs(dens.b * up) * (hi - lo)  # the exponent's change across the box, per axis
    step = 2.0 * math.acosh(1.0 + BAKE_TOLERANCE)  # per-axis exponent step keeping cosh(step / 2) - 1 at tolerance
    n = np.where(slope > 0, np.minimum(np.ceil(slope / step) + 1, BAKE_MAX_PER_AXIS), 1).astype(int)
    while n.prod() > BAKE_MAX_VOXELS:
        n = np.where(n > 2, n * 3 // 4, n)  # an axis the density varies along keeps two voxels at least
    h = np.where(n > 1, (hi - lo) / np.maximum(n - 1, 1), hi - lo)
    ticks = [lo[c] + h[c] * np.arange(n[c]) if n[c] > 1 else np.array([0.5 * (lo[c] + hi[c])]) for c in range(3)]
    X, Y, Z = np.meshgrid(*ticks, indexing="ij")
    height = (np.stack([X, Y, Z], -1) - np.asarray(dens.origin, float)) @ up
    with np.errstate(over="ignore"):
        grid = dens.a * np.exp(-dens.b * height)
    if not np.all(np.isfinite(grid)):
        raise ConfigError(ex.path, fld, "the exponential density overflows inside its shape's box; expected a finite "
                          "density (lower b or move the origin)")
    err = float(np.prod(np.cosh(np.abs(dens.b * up) * np.where(n > 1, h, 0.0) / 2))) - 1.0
    box_lo = np.where(n > 1, lo - h / 2, lo)
    box_hi = np.where(n > 1, hi + h / 2, hi)
    ex.out.warnings.append(f"{ex.path}: {fld}: medium {ex.media[k][0]!r}: Mitsuba 3 has no exponential density: "
                           f"baked into a {n[0]}x{n[1]}x{n[2]} grid (trilinear), relative error up to {err:.1e}")
    return grid, box_lo, box_hi


def _phase(ex: _Export, k: int, mat: C.Material) -> dict:
    if mat.phase == "isotropic":
        return {"type": "isotropic"}
    if mat.phase == "hg":
        return {"type": "hg", "g": float(mat.g)}
    if mat.phase == "rayleigh":
        return {"type": "rayleigh"}
    values, err = tabulated_phase(mat.phase, mat.g)
    ex.out.warnings.append(f"{ex.path}: {_material_field(ex, k, 'phase')}: medium {ex.media[k][0]!r}: Mitsuba 3 "
                           f"has no {mat.phase!r} phase function: tabulated (tabphase, {TABPHASE_POINTS} cosines), "
                           f"relative error up to {err:.1e}")
    return {"type": "tabphase", "values": ", ".join(f"{v:.9g}" for v in values)}


def tabulated_phase(kind: str, g: float, points: int = TABPHASE_POINTS) -> tuple[np.ndarray, float]:
    """(values at cosines linspace(-1, 1, points), forward scattering at +1 as tabphase reads them; the largest
    relative error of the normalised piecewise-linear table against the phase function, at nodes and midpoints)."""
    kid = KINDS[kind]
    cos = np.linspace(-1.0, 1.0, points)
    values = np.array([phase_eval(kid, g, float(c)) for c in cos])
    mids = 0.5 * (cos[1:] + cos[:-1])
    exact = np.array([phase_eval(kid, g, float(c)) for c in mids])
    norm = 2.0 * math.pi * float(np.sum(0.5 * (values[1:] + values[:-1]) * np.diff(cos)))  # tabphase normalises
    table_mid = 0.5 * (values[1:] + values[:-1]) / norm
    err = max(float(np.max(np.abs(values / norm - values) / values)), float(np.max(np.abs(table_mid - exact) / exact)))
    return values, err


# --------------------------------------------------------------------------- the two file forms


def to_json(scene: dict) -> str:
    """The load_dict form as JSON text (transforms as {"type": "transform", "matrix": ...})."""
    return json.dumps(scene, indent=1) + "\n"


def to_xml(scene: dict) -> str:
    """The same scene in Mitsuba 3's XML format: top-level objects take their key as id."""
    root = ET.Element("scene", version="3.0.0")
    for key, value in scene.items():
        if key != "type":
            _xml_value(root, key, value, top=True)
    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _num(x) -> str:
    return repr(float(x))


def _xml_value(parent: ET.Element, key: str, value, top: bool = False):
    if isinstance(value, dict):
        kind = value["type"]
        if kind == "ref":
            ET.SubElement(parent, "ref", name=key, id=value["id"])
        elif kind == "transform":
            t = ET.SubElement(parent, "transform", name=key)
            ET.SubElement(t, "matrix", value=" ".join(_num(x) for row in value["matrix"] for x in row))
        elif kind == "rgb":
            ET.SubElement(parent, "rgb", name=key, value=", ".join(_num(x) for x in value["value"]))
        else:
            el = ET.SubElement(parent, PLUGIN_TAGS[kind], type=kind, **({"id": key} if top else {"name": key}))
            for k, v in value.items():
                if k != "type":
                    _xml_value(el, k, v)
    elif isinstance(value, bool):
        ET.SubElement(parent, "boolean", name=key, value=str(value).lower())
    elif isinstance(value, int):
        ET.SubElement(parent, "integer", name=key, value=str(value))
    elif isinstance(value, float):
        ET.SubElement(parent, "float", name=key, value=_num(value))
    elif isinstance(value, str):
        ET.SubElement(parent, "string", name=key, value=value)
    elif isinstance(value, list) and len(value) == 3:
        x, y, z = (_num(v) for v in value)
        ET.SubElement(parent, "point" if key in POINT_KEYS else "vector", name=key, x=x, y=y, z=z)
    else:
        raise TypeError(f"{key}: no XML form for {value!r}")
