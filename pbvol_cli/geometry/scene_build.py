"""Config -> a built scene: flat numpy tables that every method's kernels read.

Surfaces. Every triangle and every analytic sphere points to a surface row (SURF_COLS columns):
  0 type (DIFFUSE, DIELECTRIC, MIRROR, NULL)  1 interior medium  2 exterior medium
  3 interior eta  4 exterior eta  5-7 albedo RGB (diffuse albedo or mirror reflectance)
The geometric normal points to the exterior. Medium -1 is vacuum (air).
A dielectric whose two indices are equal transmits without refraction and is turned into NULL here.

Media (MED_COLS columns): 0-2 sigma_a RGB, 3-5 sigma_s RGB (1/scene unit), 6 phase kind, 7 g, 8 sealed.
"Sealed" media are enclosed only by refracting or opaque surfaces: no shadow ray from inside can reach a
light, so next-event estimation is skipped there (it would always be blocked).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pbvol_cli import config as C
from pbvol_cli.errors import ConfigError
from pbvol_cli.geometry.distance_grid import build_distance_grid
from pbvol_cli.physics.lights import ENVIRONMENT, SPHERE, QUAD, light_rows
from pbvol_cli.physics.phase import KINDS

DIFFUSE, DIELECTRIC, MIRROR, NULL = 0, 1, 2, 3
INTERFACES = {"diffuse": DIFFUSE, "dielectric": DIELECTRIC, "mirror": MIRROR, "null": NULL}
SURF_COLS = 8
MED_COLS = 9


@dataclass
class MediumInfo:
    label: str
    material: C.Material
    sigma_a: np.ndarray
    sigma_s: np.ndarray


@dataclass
class BuiltScene:
    """Everything a renderer needs, as arrays. Lengths in scene units."""

    vertices: np.ndarray  # (nv, 3) float32, all meshes merged
    faces: np.ndarray  # (nt, 3) int32
    tri_surface: np.ndarray  # (nt,) int32
    tri_normals: np.ndarray  # (nt, 3, 3) float32 shading normal at each corner
    spheres: np.ndarray  # (ns, 5) float64: centre, radius, surface
    surfaces: np.ndarray  # (nsurf, SURF_COLS) float64
    media: np.ndarray  # (nm, MED_COLS) float64
    lights: np.ndarray  # (nl, LIGHT_COLS) float64
    camera: np.ndarray  # (14,) see camera_params
    grid_params: np.ndarray
    grid_cells: np.ndarray
    eps: float  # ray offset, scene units
    extent: float  # bounding-box diagonal of the geometry
    bbox: np.ndarray  # (2, 3)
    medium_info: list[MediumInfo] = field(default_factory=list)
    surface_names: list[str] = field(default_factory=list)
    surface_shape: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # shape index of each surface
    shape_triangles: list[tuple[str, int]] = field(default_factory=list)

    @property
    def has_environment(self) -> bool:
        return bool(np.any(self.lights[:, 0] == ENVIRONMENT))


def camera_params(cam: C.Camera, resolution: tuple[int, int] | None = None) -> np.ndarray:
    """[position, forward, right * tan(fov/2) * aspect, up * tan(fov/2), width, height]."""
    w, h = resolution or cam.resolution
    pos = np.asarray(cam.position, float)
    fwd = np.asarray(cam.look_at, float) - pos
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(cam.up, float))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    t = math.tan(math.radians(cam.fov) / 2)
    return np.concatenate([pos, fwd, right * t * w / h, up * t, [w, h]])


class _Media:
    """Deduplicating registry of media."""

    def __init__(self, scene: C.Scene, path: Path):
        self.scene, self.path = scene, path
        self.info: list[MediumInfo] = []
        self._keys: dict[str, int] = {}

    def get(self, ref, field_name: str) -> int:
        if ref is None:
            return -1
        mat, label = C.resolve_medium(ref, self.scene, self.path, field_name)
        key = mat.model_dump_json()
        if key not in self._keys:
            sa, ss = mat.coefficients(self.scene.unit)
            self._keys[key] = len(self.info)
            self.info.append(MediumInfo(label, mat, sa, ss))
        return self._keys[key]

    def eta(self, idx: int) -> float | None:
        return None if idx < 0 else self.info[idx].material.eta


def build_scene(scene: C.Scene, path: Path, resolution: tuple[int, int] | None = None) -> BuiltScene:
    """Build every table. Raises ConfigError for problems only visible now (unreadable mesh...)."""
    from pbvol_cli.geometry.primitives import shape_parts  # trimesh import deferred

    path = Path(path)
    media = _Media(scene, path)
    surfaces: list[list[float]] = []
    names: list[str] = []
    owner: list[int] = []
    verts, faces, tri_surf, tri_norm, spheres = [], [], [], [], []
    shape_tris: list[tuple[str, int]] = []
    nv = 0

    def add_surface(kind, m_in, m_out, eta_in, eta_out, albedo, name):
        if kind == DIELECTRIC and eta_in == eta_out:
            kind = NULL
        surfaces.append([kind, m_in, m_out, eta_in, eta_out, *albedo])
        names.append(name)
        owner.append(i)
        return len(surfaces) - 1

    for i, shape in enumerate(scene.shapes):
        fld = f"shapes[{i}]"
        name = shape.name or f"{shape.type}#{i}"
        kind = INTERFACES[shape.interface]
        m_in = media.get(shape.medium, f"{fld}.medium")
        m_out = media.get(shape.exterior_medium, f"{fld}.exterior_medium")
        eta_out = shape.exterior_eta
        if kind == DIELECTRIC:
            eta_in = shape.eta if shape.eta is not None else (media.eta(m_in) or 1.5)
        else:
            eta_in = eta_out
        role_surface = {"body": add_surface(kind, m_in, m_out, eta_in, eta_out, shape.albedo, name)}
        if isinstance(shape, C.CupShape):
            liquid = media.get(shape.liquid, f"{fld}.liquid")
            eta_l = shape.liquid_eta or media.eta(liquid) or 1.33
            role_surface["glass"] = role_surface["body"]
            role_surface["liquid_glass"] = add_surface(DIELECTRIC, liquid, m_in, eta_l, eta_in, shape.albedo,
                                                       name + ":liquid-glass")
            role_surface["liquid_free"] = add_surface(DIELECTRIC, liquid, m_out, eta_l, eta_out, shape.albedo,
                                                      name + ":liquid-air")
        if isinstance(shape, C.SphereShape):
            c = np.asarray(shape.center, float)
            r = shape.radius
            if shape.transform is not None:
                M = shape.transform.matrix()
                s = np.asarray(shape.transform.scale)
                if np.ptp(s) > 1e-12 * s.max():
                    raise ConfigError(path, f"{fld}.transform.scale",
                                      "a sphere takes only a uniform scale (use a mesh for an ellipsoid)")
                c = M[:3, :3] @ c + M[:3, 3]
                r = r * s[0]
            spheres.append([*c, r, role_surface["body"]])
            shape_tris.append((name, 0))
            continue
        try:
            parts = shape_parts(shape, path.parent)
        except ValueError as e:
            raise ConfigError(path, fld + (".file" if shape.type == "mesh" else ""), str(e)) from None
        count = 0
        for p in parts:
            V = np.asarray(p.vertices, float)
            Fc = np.asarray(p.faces, np.int64)
            verts.append(V)
            faces.append(Fc + nv)
            nv += len(V)
            tri_surf.append(np.full(len(Fc), role_surface[p.role], np.int32))
            if p.normals is None:
                e1 = V[Fc[:, 1]] - V[Fc[:, 0]]
                e2 = V[Fc[:, 2]] - V[Fc[:, 0]]
                n = np.cross(e1, e2)
                n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
                tri_norm.append(np.repeat(n[:, None, :], 3, axis=1))
            else:
                tri_norm.append(np.asarray(p.normals, float)[Fc])
            count += len(Fc)
        shape_tris.append((name, count))

    V = np.concatenate(verts).astype(np.float32) if verts else np.zeros((0, 3), np.float32)
    F = np.concatenate(faces).astype(np.int32) if faces else np.zeros((0, 3), np.int32)
    S = np.asarray(spheres, float).reshape(-1, 5)
    surf = np.asarray(surfaces, float).reshape(-1, SURF_COLS)
    lights = light_rows(scene.lights)

    # Scene bounds (geometry and area lights) -> ray offset.
    pts = [V.astype(float)] if len(V) else []
    for s in S:
        pts.append(np.array([s[:3] - s[3], s[:3] + s[3]]))
    for L in lights:
        if L[0] == SPHERE:
            pts.append(np.array([L[4:7] - L[13], L[4:7] + L[13]]))
        elif L[0] == QUAD:
            pts.append(np.array([L[4:7], L[4:7] + L[7:10] + L[10:13]]))
    allp = np.concatenate(pts) if pts else np.zeros((1, 3))
    bbox = np.array([allp.min(0), allp.max(0)])
    extent = float(np.linalg.norm(bbox[1] - bbox[0])) or 1.0
    eps = 2e-5 * max(extent, float(np.abs(bbox).max()))

    # Media table, with the sealed flag.
    med = np.zeros((len(media.info), MED_COLS))
    for k, mi in enumerate(media.info):
        med[k, 0:3], med[k, 3:6] = mi.sigma_a, mi.sigma_s
        med[k, 6], med[k, 7] = KINDS[mi.material.phase], mi.material.g
        sides = (surf[:, 1] == k) | (surf[:, 2] == k)
        med[k, 8] = float(not np.any(sides & (surf[:, 0] == NULL)))

    # Distance grid over where the media are (triangles bounding media, spheres holding media).
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    if len(F):
        tri_media = (surf[tri_surf_all := np.concatenate(tri_surf), 1] >= 0) | (surf[tri_surf_all, 2] >= 0)
        if tri_media.any():
            tv = V[F[tri_media]].reshape(-1, 3)
            lo, hi = np.minimum(lo, tv.min(0)), np.maximum(hi, tv.max(0))
    for s in S:
        if surf[int(s[4]), 1] >= 0 or surf[int(s[4]), 2] >= 0:
            lo, hi = np.minimum(lo, s[:3] - s[3]), np.maximum(hi, s[:3] + s[3])
    gp, gc = build_distance_grid(V, F, lo, hi, eps)

    return BuiltScene(
        vertices=V, faces=F,
        tri_surface=np.concatenate(tri_surf) if tri_surf else np.zeros(0, np.int32),
        tri_normals=(np.concatenate(tri_norm) if tri_norm else np.zeros((0, 3, 3))).astype(np.float32),
        spheres=S, surfaces=surf, media=med, lights=lights,
        camera=camera_params(scene.camera, resolution),
        grid_params=gp, grid_cells=gc, eps=eps, extent=extent, bbox=bbox,
        medium_info=media.info, surface_names=names, shape_triangles=shape_tris,
        surface_shape=np.asarray(owner, np.int64),
    )
