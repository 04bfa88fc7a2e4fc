"""Config -> a built scene: flat numpy tables that every method's kernels read.

Surfaces. Every triangle and every analytic sphere points to a surface row, columns SURF_*: its type (DIFFUSE,
DIELECTRIC, MIRROR, NULL), interior and exterior medium, interior and exterior eta, RGB albedo (diffuse albedo or
mirror reflectance). The geometric normal points to the exterior. Medium -1 is vacuum (air). A dielectric whose
two indices are equal transmits without refraction and is turned into NULL here.

Media, columns MED_*: sigma_a and sigma_s (RGB, 1/scene unit), phase function kind (physics.phase.KINDS), g, and
"sealed": enclosed only by refracting or opaque surfaces, so that no shadow ray from inside can reach a light and
next-event estimation is skipped there (it would always be blocked). A heterogeneous or emissive medium also has
its density kind (MED_KIND: HOMOGENEOUS, GRID, EXPONENTIAL; TRACKED_HOMOGENEOUS for an emissive homogeneous one),
the majorant of its sigma_t over space and channels (MED_MAJORANT), its emitted radiance (MED_EMIT, RGB), its
field's parameters (MED_FIELD + GRID_* or EXP_*) and a coarse grid of local majorants (MED_MAJ + MAJ_*; none: 0
cells); grids' voxels and majorant cells are in BuiltScene.density_data (render/media.py).

Spheres (analytic sphere shapes), columns SPH_*: centre, radius, surface row. Camera: see camera_params.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pbvol_cli import config as C
from pbvol_cli.errors import ConfigError
from pbvol_cli.geometry.distance_grid import build_distance_grid
from pbvol_cli.physics.lights import (LIGHT_E1, LIGHT_E2, LIGHT_P0, LIGHT_RADIUS, LIGHT_TYPE, QUAD, SPHERE,
                                     light_rows)
from pbvol_cli.physics.phase import KINDS

DIFFUSE, DIELECTRIC, MIRROR, NULL = 0, 1, 2, 3  # SURF_TYPE values
INTERFACES = {"diffuse": DIFFUSE, "dielectric": DIELECTRIC, "mirror": MIRROR, "null": NULL}
SURF_TYPE, SURF_MEDIUM_IN, SURF_MEDIUM_OUT, SURF_ETA_IN, SURF_ETA_OUT, SURF_ALBEDO = 0, 1, 2, 3, 4, 5  # albedo: 3
SURF_COLS = 8
MED_SIGMA_A, MED_SIGMA_S, MED_PHASE, MED_G, MED_SEALED = 0, 3, 6, 7, 8  # sigma_a, sigma_s: 3 (RGB) each
MED_KIND, MED_MAJORANT, MED_EMIT, MED_FIELD = 9, 10, 11, 14  # emit: 3 (RGB); field: FIELD_COLS parameters
FIELD_COLS = 12
MED_MAJ = MED_FIELD + FIELD_COLS  # a coarse grid of majorants: box corners, cell counts, offset of its cells
MAJ_LO, MAJ_HI, MAJ_DIMS, MAJ_OFFSET = 0, 3, 6, 9
MAJ_COLS = 10
MAJ_CELLS = 16  # majorant cells per axis at most
MED_COLS = MED_MAJ + MAJ_COLS
HOMOGENEOUS, GRID, EXPONENTIAL, TRACKED_HOMOGENEOUS = 0, 1, 2, 3  # MED_KIND values
# MED_FIELD + ...: a grid's box corners, voxel counts, offset of its voxels (and of its emission voxels, -1: none)
GRID_LO, GRID_HI, GRID_DIMS, GRID_OFFSET, GRID_EMIT_OFFSET = 0, 3, 6, 9, 10
# an exponential's a, b, unit up direction, origin
EXP_A, EXP_B, EXP_UP, EXP_ORIGIN = 0, 1, 2, 5
SPH_CENTER, SPH_RADIUS, SPH_SURFACE = 0, 3, 4
SPH_COLS = 5
# camera_params: position, forward, right (scaled), up (scaled): 3 each; then the image size
CAM_POS, CAM_FORWARD, CAM_RIGHT, CAM_UP, CAM_WIDTH, CAM_HEIGHT = 0, 3, 6, 9, 12, 13


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
    spheres: np.ndarray  # (ns, SPH_COLS) float64: centre, radius, surface
    surfaces: np.ndarray  # (nsurf, SURF_COLS) float64
    media: np.ndarray  # (nm, MED_COLS) float64
    lights: np.ndarray  # (nl, LIGHT_COLS) float64
    camera: np.ndarray  # (14,) see camera_params (CAM_*)
    grid_params: np.ndarray
    grid_cells: np.ndarray
    eps: float  # ray offset, scene units
    extent: float  # bounding-box diagonal of the geometry
    bbox: np.ndarray  # (2, 3)
    medium_info: list[MediumInfo] = field(default_factory=list)
    density_data: np.ndarray = field(default_factory=lambda: np.zeros(1))  # grids' voxels (render/media.py)
    surface_shape: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # shape index of each surface
    shape_triangles: list[tuple[str, int]] = field(default_factory=list)

    @property
    def resolution(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return int(self.camera[CAM_WIDTH]), int(self.camera[CAM_HEIGHT])

    def medium_sigmas(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """(sigma_a, sigma_s) of medium m, RGB, 1/scene unit."""
        return (self.media[m, MED_SIGMA_A:MED_SIGMA_A + 3], self.media[m, MED_SIGMA_S:MED_SIGMA_S + 3])

    def surfaces_bounding(self, m: int) -> np.ndarray:
        """Boolean mask over surface rows: those with medium m on either side."""
        return (self.surfaces[:, SURF_MEDIUM_IN] == m) | (self.surfaces[:, SURF_MEDIUM_OUT] == m)

    def medium_box(self, m: int) -> np.ndarray | None:
        """(lo, hi) corners (scene units) of the bounding box of the surfaces that bound medium m (None: none)."""
        surf = np.flatnonzero(self.surfaces_bounding(m))
        pts = []
        if len(self.faces):
            tri = np.isin(self.tri_surface, surf)
            if tri.any():
                pts.append(self.vertices[self.faces[tri]].reshape(-1, 3).astype(float))
        for s in self.spheres:
            if int(s[SPH_SURFACE]) in surf:
                pts.append(sphere_bounds(s))
        if not pts:
            return None
        p = np.concatenate(pts)
        return np.array([p.min(0), p.max(0)])

    def medium_side(self, m: int) -> float | None:
        """The smallest side (scene units) of medium_box(m) (None: no box)."""
        box = self.medium_box(m)
        return None if box is None else float(np.min(box[1] - box[0]))

    def medium_is_convex(self, m: int, max_pairs: int = 4 * 10**8) -> bool:
        """Whether medium m fills a convex region: one analytic sphere with m inside, or triangles whose every plane
        has all the boundary's vertices on m's side (the geometric normal points to the exterior). A ray from any
        point of m then meets its boundary once. False where m lies outside a surface (an object immersed in it,
        the space around a shape), for spheres mixed with triangles, and for boundaries of more than max_pairs
        (triangle, vertex) pairs, which are not tested."""
        bound = self.surfaces_bounding(m)
        if not bound.any() or np.any(self.surfaces[bound, SURF_MEDIUM_OUT] == m):
            return False
        sph = self.spheres[np.isin(self.spheres[:, SPH_SURFACE].astype(np.int64), np.flatnonzero(bound))]
        tri = np.flatnonzero(np.isin(self.tri_surface, np.flatnonzero(bound))) if len(self.faces) else []
        if len(sph):
            return len(sph) == 1 and len(tri) == 0
        F = self.faces[tri].astype(np.int64)
        V = self.vertices[np.unique(F)].astype(np.float64)
        if len(F) * len(V) > max_pairs:
            return False
        P = self.vertices[F].astype(np.float64)
        n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
        # the winding's normal oriented as the corners' shading normals (exterior)
        n *= np.where(np.einsum("ij,ij->i", n, self.tri_normals[tri].sum(axis=1)) < 0, -1.0, 1.0)[:, None]
        tol = 1e-6 * self.extent
        offset = np.einsum("ij,ij->i", n, P[:, 0])
        for a in range(0, len(F), max(1, 2**22 // max(len(V), 1))):
            b = a + max(1, 2**22 // max(len(V), 1))
            if np.any(n[a:b] @ V.T - offset[a:b, None] > tol):
                return False
        return True

    def reflects_into(self, m: int) -> bool:
        """Whether medium m's boundary reflects light back into it somewhere: a surface bounding it that is not a
        null boundary or an index-matched dielectric."""
        s = self.surfaces[self.surfaces_bounding(m)]
        matched = (s[:, SURF_TYPE] == NULL) | ((s[:, SURF_TYPE] == DIELECTRIC)
                                               & (s[:, SURF_ETA_IN] == s[:, SURF_ETA_OUT]))
        return bool(np.any(~matched))


def sphere_bounds(row: np.ndarray) -> np.ndarray:
    """(2, 3) bounding box of a spheres-table row."""
    c, r = row[SPH_CENTER:SPH_CENTER + 3], row[SPH_RADIUS]
    return np.array([c - r, c + r])


def camera_params(cam: C.Camera, resolution: tuple[int, int] | None = None) -> np.ndarray:
    """[position, forward, right * tan(fov/2) * aspect, up * tan(fov/2), width, height] (columns CAM_*)."""
    w, h = resolution or cam.resolution
    pos = np.asarray(cam.position, float)
    fwd = np.asarray(cam.look_at, float) - pos
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(cam.up, float))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    t = math.tan(math.radians(cam.fov) / 2)
    return np.concatenate([pos, fwd, right * t * w / h, up * t, [w, h]])


class SceneMedia:
    """The scene's distinct media (config.scene_media) as MediumInfo (coefficients in scene units), indexed in the
    order the shapes first name them: the one numbering of media, for the built tables and the Mitsuba export."""

    def __init__(self, scene: C.Scene, path: Path):
        self.scene, self.path = scene, path
        self.info = [MediumInfo(label, mat, *mat.coefficients(scene.unit)) for label, mat in C.scene_media(scene, path)]
        self._index = {C.medium_key(mi.material): k for k, mi in enumerate(self.info)}

    def get(self, ref, field_name: str) -> int:
        if ref is None:
            return -1
        mat, _ = C.resolve_medium(ref, self.scene, self.path, field_name)
        return self._index[C.medium_key(mat)]

    def eta(self, idx: int) -> float | None:
        return None if idx < 0 else self.info[idx].material.eta


def build_scene(scene: C.Scene, path: Path, resolution: tuple[int, int] | None = None) -> BuiltScene:
    """Build every table. Raises ConfigError for problems only visible now (unreadable mesh...)."""
    from pbvol_cli.geometry.primitives import shape_parts  # trimesh import deferred

    path = Path(path)
    media = SceneMedia(scene, path)
    surfaces: list[list[float]] = []
    owner: list[int] = []
    verts, faces, tri_surf, tri_norm, spheres = [], [], [], [], []
    shape_tris: list[tuple[str, int]] = []
    nv = 0

    def add_surface(kind, m_in, m_out, eta_in, eta_out, albedo):
        if kind == DIELECTRIC and eta_in == eta_out:
            kind = NULL
        surfaces.append([kind, m_in, m_out, eta_in, eta_out, *albedo])
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
        role_surface = {"body": add_surface(kind, m_in, m_out, eta_in, eta_out, shape.albedo)}
        if isinstance(shape, C.CupShape):
            liquid = media.get(shape.liquid, f"{fld}.liquid")
            eta_l = shape.liquid_eta or media.eta(liquid) or 1.33
            role_surface["glass"] = role_surface["body"]
            role_surface["liquid_glass"] = add_surface(DIELECTRIC, liquid, m_in, eta_l, eta_in, shape.albedo)
            role_surface["liquid_free"] = add_surface(DIELECTRIC, liquid, m_out, eta_l, eta_out, shape.albedo)
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
    S = np.asarray(spheres, float).reshape(-1, SPH_COLS)
    surf = np.asarray(surfaces, float).reshape(-1, SURF_COLS)
    lights = light_rows(scene.lights)

    # Scene bounds (geometry and area lights) -> ray offset.
    pts = [V.astype(float)] if len(V) else []
    for s in S:
        pts.append(sphere_bounds(s))
    for L in lights:
        p0, e1, e2 = (L[c:c + 3] for c in (LIGHT_P0, LIGHT_E1, LIGHT_E2))
        if L[LIGHT_TYPE] == SPHERE:
            pts.append(np.array([p0 - L[LIGHT_RADIUS], p0 + L[LIGHT_RADIUS]]))
        elif L[LIGHT_TYPE] == QUAD:
            pts.append(np.array([p0, p0 + e1 + e2]))
    allp = np.concatenate(pts) if pts else np.zeros((1, 3))
    bbox = np.array([allp.min(0), allp.max(0)])
    extent = float(np.linalg.norm(bbox[1] - bbox[0])) or 1.0
    eps = 2e-5 * max(extent, float(np.abs(bbox).max()))

    # Media table, with the sealed flag and any density field.
    med = np.zeros((len(media.info), MED_COLS))
    voxels = [np.zeros(1)]
    for k, mi in enumerate(media.info):
        med[k, MED_SIGMA_A:MED_SIGMA_A + 3], med[k, MED_SIGMA_S:MED_SIGMA_S + 3] = mi.sigma_a, mi.sigma_s
        med[k, MED_PHASE], med[k, MED_G] = KINDS[mi.material.phase], mi.material.g
        sides = (surf[:, SURF_MEDIUM_IN] == k) | (surf[:, SURF_MEDIUM_OUT] == k)
        med[k, MED_SEALED] = float(not np.any(sides & (surf[:, SURF_TYPE] == NULL)))
        _density_columns(med[k], mi, k, path, voxels, _medium_bounds(V, F, tri_surf, S, surf, k))

    # Distance grid over where the media are (triangles bounding media, spheres holding media).
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    holds_medium = (surf[:, SURF_MEDIUM_IN] >= 0) | (surf[:, SURF_MEDIUM_OUT] >= 0)
    if len(F):
        tri_media = holds_medium[np.concatenate(tri_surf)]
        if tri_media.any():
            tv = V[F[tri_media]].reshape(-1, 3)
            lo, hi = np.minimum(lo, tv.min(0)), np.maximum(hi, tv.max(0))
    for s in S:
        if holds_medium[int(s[SPH_SURFACE])]:
            b = sphere_bounds(s)
            lo, hi = np.minimum(lo, b[0]), np.maximum(hi, b[1])
    gp, gc = build_distance_grid(V, F, lo, hi, eps)

    return BuiltScene(
        vertices=V, faces=F,
        tri_surface=np.concatenate(tri_surf) if tri_surf else np.zeros(0, np.int32),
        tri_normals=(np.concatenate(tri_norm) if tri_norm else np.zeros((0, 3, 3))).astype(np.float32),
        spheres=S, surfaces=surf, media=med, lights=lights,
        camera=camera_params(scene.camera, resolution),
        grid_params=gp, grid_cells=gc, eps=eps, extent=extent, bbox=bbox,
        medium_info=media.info, shape_triangles=shape_tris,
        surface_shape=np.asarray(owner, np.int64), density_data=np.concatenate(voxels),
    )


def _medium_bounds(V, F, tri_surf, S, surf, k: int):
    """(lo, hi) of the surfaces bounding medium k, or None (it bounds nothing: the scene's outside)."""
    sides = (surf[:, SURF_MEDIUM_IN] == k) | (surf[:, SURF_MEDIUM_OUT] == k)
    pts = []
    if len(F):
        tri = sides[np.concatenate(tri_surf)]
        if tri.any():
            pts.append(V[F[tri]].reshape(-1, 3).astype(float))
    for row in S:
        if sides[int(row[SPH_SURFACE])]:
            pts.append(sphere_bounds(row))
    if not pts:
        return None
    p = np.concatenate(pts)
    return p.min(0), p.max(0)


def _density_columns(row: np.ndarray, mi: MediumInfo, k: int, path: Path, voxels: list, bounds):
    """Fill a media-table row's MED_KIND, MED_MAJORANT, MED_EMIT and MED_FIELD columns from its material; a grid's
    voxels are appended to `voxels` (their offset counted from the first array)."""
    mat = mi.material
    dens, emit = mat.density, np.asarray(mat.emission if mat.emission is not None else (0.0, 0.0, 0.0), float)
    where = f"medium {mi.label!r}"
    row[MED_EMIT:MED_EMIT + 3] = emit
    st = float(np.max(mi.sigma_a + mi.sigma_s))
    f = MED_FIELD
    if dens is None:
        row[MED_KIND] = TRACKED_HOMOGENEOUS if emit.any() else HOMOGENEOUS
        row[MED_MAJORANT] = st
        return
    if isinstance(dens, C.GridDensity):
        from pbvol_cli.geometry.density_grid import load_grid

        grid, emission = load_grid(path, dens, where)
        row[MED_KIND] = GRID
        row[f + GRID_LO:f + GRID_LO + 3], row[f + GRID_HI:f + GRID_HI + 3] = dens.bounds[0], dens.bounds[1]
        row[f + GRID_DIMS:f + GRID_DIMS + 3] = grid.shape
        row[f + GRID_OFFSET] = sum(len(v) for v in voxels)
        voxels.append(grid.ravel() * dens.scale)
        row[f + GRID_EMIT_OFFSET] = -1.0
        if emission is not None:
            row[f + GRID_EMIT_OFFSET] = sum(len(v) for v in voxels)
            voxels.append(emission.ravel())
        row[MED_MAJORANT] = st * float(grid.max(initial=0.0)) * dens.scale
        _majorant_grid(row, voxels, dens.bounds, _grid_cell_maxima(grid, dens.scale * st))
        return
    up = np.asarray(dens.up, float) / np.linalg.norm(dens.up)
    if bounds is None:
        raise ConfigError(path, where, "an exponential density needs a medium bounded by a shape (its majorant is "
                          "taken over the shape's box)")
    corners = np.array([[bounds[i][0], bounds[j][1], bounds[l][2]] for i in (0, 1) for j in (0, 1) for l in (0, 1)])
    h = (corners - np.asarray(dens.origin, float)) @ up
    with np.errstate(over="ignore"):
        dmax = dens.a * float(np.exp(-dens.b * (h.min() if dens.b > 0 else h.max())))
    if not math.isfinite(dmax * st):
        raise ConfigError(path, where, f"the exponential density reaches {dmax:.3g} inside its shape's box; "
                          "expected a finite density (lower b or move the origin)")
    row[MED_KIND] = EXPONENTIAL
    row[f + EXP_A], row[f + EXP_B] = dens.a, dens.b
    row[f + EXP_UP:f + EXP_UP + 3], row[f + EXP_ORIGIN:f + EXP_ORIGIN + 3] = up, dens.origin
    row[MED_MAJORANT] = st * dmax
    # cells of the shape's box: the density is monotone along up, so a cell's largest is at one of its corners
    lo, hi = np.asarray(bounds[0], float), np.asarray(bounds[1], float)
    n = MAJ_CELLS
    ticks = [np.linspace(lo[c], hi[c], n + 1) for c in range(3)]
    X, Y, Z = np.meshgrid(*ticks, indexing="ij")
    h = (np.stack([X, Y, Z], -1) - np.asarray(dens.origin, float)) @ up
    with np.errstate(over="ignore"):
        corner = dens.a * np.exp(-dens.b * h)
    cells = np.max([corner[a:a + n, b:b + n, c:c + n] for a in (0, 1) for b in (0, 1) for c in (0, 1)], axis=0)
    _majorant_grid(row, voxels, (lo, hi), cells * st)


def _grid_cell_maxima(grid: np.ndarray, factor: float) -> np.ndarray:
    """Upper bounds of a voxel grid's trilinear field over MAJ_CELLS cells per axis (fewer where the grid has fewer
    voxels): the largest voxel whose centre lies within one voxel of the cell, times factor."""
    shape = grid.shape
    n = [min(MAJ_CELLS, k) for k in shape]
    out = np.zeros(n)
    edges = [np.linspace(0.0, shape[c], n[c] + 1) for c in range(3)]  # cell edges in voxel units
    rng = [[(max(int(np.floor(e0 - 0.5)), 0), min(int(np.ceil(e1 - 0.5)), shape[c] - 1))
            for e0, e1 in zip(edges[c][:-1], edges[c][1:])] for c in range(3)]
    for i, (a0, a1) in enumerate(rng[0]):
        for j, (b0, b1) in enumerate(rng[1]):
            for k, (c0, c1) in enumerate(rng[2]):
                out[i, j, k] = grid[a0:a1 + 1, b0:b1 + 1, c0:c1 + 1].max()
    return out * factor


def _majorant_grid(row: np.ndarray, voxels: list, bounds, cells: np.ndarray):
    """Store a grid of majorant cells over the box bounds in the row's MED_MAJ columns and its cells in voxels."""
    g = MED_MAJ
    row[g + MAJ_LO:g + MAJ_LO + 3], row[g + MAJ_HI:g + MAJ_HI + 3] = bounds[0], bounds[1]
    row[g + MAJ_DIMS:g + MAJ_DIMS + 3] = cells.shape
    row[g + MAJ_OFFSET] = sum(len(v) for v in voxels)
    voxels.append(np.ascontiguousarray(cells, np.float64).ravel())
