"""Shape configs turned into world-space triangle meshes.

Every :class:`MeshPart` is wound so that the geometric normal ``(v1 - v0) x (v2 - v0)`` points to the
part's EXTERIOR side; per-vertex shading normals (when given) point the same way.  A part's ``role`` says
which pair of media it separates:

- ``"body"``: interior = the shape's ``medium``, exterior = its ``exterior_medium`` (all shapes but the cup);
- ``"glass"``: cup glass (interior) / air (exterior);
- ``"liquid_glass"``: cup liquid (interior) / glass (exterior);
- ``"liquid_free"``: cup liquid (interior) / air (exterior), the free surface.

Several parts may share a role: smooth walls (with shading normals) and flat disks (``normals=None``)
are separate parts.  Rings at the same height use the same angles, so parts meet without cracks.

The shape's ``transform`` is applied after the object-space mesh is built (object space includes the
shape's ``center``): positions by ``M``, normals by the inverse transpose of its 3x3 block, renormalised.
"""

from __future__ import annotations

import math
import pathlib
from dataclasses import dataclass

import numpy as np

__all__ = ["MeshPart", "shape_parts", "count_triangles", "bumpy_noise"]

CREASE_ANGLE = math.radians(60.0)


@dataclass
class MeshPart:
    vertices: np.ndarray  # (n,3) float64, world space
    faces: np.ndarray  # (m,3) int32, CCW seen from the side the normal points to (the exterior)
    normals: np.ndarray | None  # (n,3) float64 unit shading normals per vertex, or None = flat shading
    role: str  # "body", "glass", "liquid_glass" or "liquid_free"


def count_triangles(parts) -> int:
    return int(sum(len(p.faces) for p in parts))


# --------------------------------------------------------------------------- helpers


def _part(vertices, faces, normals, role) -> MeshPart:
    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.ascontiguousarray(faces, dtype=np.int32).reshape(-1, 3)
    n = None if normals is None else np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)
    return MeshPart(v, f, n, role)


def _normalize(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _angles(segments: int) -> np.ndarray:
    return 2.0 * np.pi * np.arange(segments) / segments


def _ring(radius: float, y: float, segments: int) -> np.ndarray:
    """Points (r cos t, y, r sin t) for t = 2 pi j / segments. Same (radius, y, segments) -> same floats."""
    t = _angles(segments)
    return np.stack([radius * np.cos(t), np.full(segments, float(y)), radius * np.sin(t)], axis=1)


def _wall(radius: float, y0: float, y1: float, segments: int, outward: bool, role: str) -> MeshPart:
    """Open cylindrical wall between heights y0 < y1, smooth radial normals (out of or into the axis)."""
    n = segments
    verts = np.concatenate([_ring(radius, y0, n), _ring(radius, y1, n)])
    j = np.arange(n)
    k = (j + 1) % n
    b0, b1, t0, t1 = j, k, j + n, k + n
    # (b0, t0, b1): (t0-b0) x (b1-b0) = (0,h,0) x tangent -> radially outward.
    faces = np.concatenate([np.stack([b0, t0, b1], 1), np.stack([b1, t0, t1], 1)])
    radial = np.concatenate([_ring(1.0, 0.0, n)] * 2)
    if not outward:
        faces = faces[:, ::-1]
        radial = -radial
    return _part(verts, faces, radial, role)


def _disk(radius: float, y: float, segments: int, up: bool, role: str) -> MeshPart:
    """Flat disk at height y (a fan around its centre), normal +y if ``up`` else -y."""
    n = segments
    verts = np.concatenate([[[0.0, float(y), 0.0]], _ring(radius, y, n)])
    j = np.arange(n)
    # (c, p_j, p_{j+1}) has normal -y (counter-clockwise seen from below).
    faces = np.stack([np.zeros(n, int), 1 + j, 1 + (j + 1) % n], 1)
    if up:
        faces = faces[:, ::-1]
    return _part(verts, faces, None, role)


def _annulus(r_in: float, r_out: float, y: float, segments: int, up: bool, role: str) -> MeshPart:
    n = segments
    verts = np.concatenate([_ring(r_in, y, n), _ring(r_out, y, n)])
    j = np.arange(n)
    k = (j + 1) % n
    i0, i1, o0, o1 = j, k, j + n, k + n
    # Same orientation as the disk fan (c, p_j, p_{j+1}): normal -y.
    faces = np.concatenate([np.stack([i0, o0, o1], 1), np.stack([i0, o1, i1], 1)])
    if up:
        faces = faces[:, ::-1]
    return _part(verts, faces, None, role)


def _signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _transform(part: MeshPart, M: np.ndarray) -> MeshPart:
    A = M[:3, :3]
    verts = part.vertices @ A.T + M[:3, 3]
    normals = None
    if part.normals is not None:
        normals = _normalize(part.normals @ np.linalg.inv(A))  # (A^-T n) as rows: n @ A^-1
    faces = part.faces
    if np.linalg.det(A) < 0:  # a mirror would turn the winding inside out
        faces = np.ascontiguousarray(faces[:, ::-1])
    return _part(verts, faces, normals, part.role)


# --------------------------------------------------------------------------- shapes


def _box(shape) -> list[MeshPart]:
    c = np.asarray(shape.center, float)
    h = 0.5 * np.asarray(shape.size, float)
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    verts = c + signs * h  # index = 4*(x>0) + 2*(y>0) + (z>0)
    quads = [
        (0, 1, 3, 2),  # -x
        (4, 6, 7, 5),  # +x
        (0, 4, 5, 1),  # -y
        (2, 3, 7, 6),  # +y
        (0, 2, 6, 4),  # -z
        (1, 5, 7, 3),  # +z
    ]
    faces = [f for a, b, cc, d in quads for f in ((a, b, cc), (a, cc, d))]
    return [_part(verts, faces, None, "body")]


def _cylinder(shape) -> list[MeshPart]:
    r, h, n = shape.radius, shape.height, shape.segments
    parts = [
        _wall(r, 0.0, h, n, True, "body"),
        _disk(r, 0.0, n, False, "body"),
        _disk(r, h, n, True, "body"),
    ]
    return _translated(parts, shape.center)


def _quad(shape) -> list[MeshPart]:
    c = np.asarray(shape.center, float)
    hx, hz = 0.5 * shape.size[0], 0.5 * shape.size[1]
    verts = c + np.array([[-hx, 0, -hz], [-hx, 0, hz], [hx, 0, hz], [hx, 0, -hz]], float)
    # (v1-v0) x (v2-v0) = (0,0,2hz) x (2hx,0,2hz) = (0, 4 hx hz, 0): +y.
    return [_part(verts, [(0, 1, 2), (0, 2, 3)], None, "body")]


def _cup(shape) -> list[MeshPart]:
    R, H, n = shape.radius, shape.height, shape.segments
    r = R - shape.wall
    yb = shape.bottom
    if not (0 < r < R and 0 < yb < H):
        raise ValueError(f"impossible cup dimensions: radius {R}, wall {shape.wall}, height {H}, bottom {yb}")
    fill = shape.fill
    yl = yb + fill * (H - yb) if fill > 0 else yb
    parts = [
        _wall(R, 0.0, H, n, True, "glass"),
        _disk(R, 0.0, n, False, "glass"),
        _annulus(r, R, H, n, True, "glass"),
    ]
    if yl < H:
        parts.append(_wall(r, yl, H, n, False, "glass"))
    if fill > 0:
        parts += [
            _wall(r, yb, yl, n, True, "liquid_glass"),
            _disk(r, yb, n, False, "liquid_glass"),
            _disk(r, yl, n, True, "liquid_free"),
        ]
    else:
        parts.append(_disk(r, yb, n, True, "glass"))
    return _translated(parts, shape.center)


def _translated(parts: list[MeshPart], center) -> list[MeshPart]:
    c = np.asarray(center, float)
    for p in parts:
        p.vertices = p.vertices + c
    return parts


# --------------------------------------------------------------------------- bumpy sphere

N_NOISE_TERMS = 8


def _noise_terms(seed: int):
    rng = np.random.default_rng(seed)
    d = _normalize(rng.normal(size=(N_NOISE_TERMS, 3)))
    a = rng.uniform(0.5, 1.0, size=N_NOISE_TERMS) * rng.choice([-1.0, 1.0], size=N_NOISE_TERMS)
    phi = rng.uniform(0.0, 2.0 * np.pi, size=N_NOISE_TERMS)
    return d, a, phi


def bumpy_noise(w: np.ndarray, seed: int, frequency: float) -> tuple[np.ndarray, np.ndarray]:
    """(n(w), grad n(w)) for unit directions w (k,3); see :func:`_bumpy_sphere`. grad is the R^3 gradient."""
    d, a, phi = _noise_terms(seed)
    arg = frequency * np.pi * (w @ d.T) + phi  # (k, 8)
    s = np.abs(a).sum()
    n = (np.sin(arg) @ a) / s
    grad = ((np.cos(arg) * a) @ d) * (frequency * np.pi / s)
    return n, grad


def _bumpy_sphere(shape) -> list[MeshPart]:
    """Icosphere displaced radially: p(w) = c + r(w) w, r(w) = radius (1 + amplitude n(w)), with

        n(w) = sum_k a_k sin(pi f (d_k . w) + phi_k) / sum_k |a_k|      (in [-1, 1])

    over 8 unit directions d_k, amplitudes a_k (|a_k| in [0.5, 1], random sign) and phases phi_k drawn
    from ``numpy.random.default_rng(seed)``; f = ``frequency``.

    Shading normals are exact: the surface is F(p) = |p| - r(p/|p|) = 0 (p relative to the centre), so

        N ∝ grad F = w - (I - w w^T) g / r(w),   g = grad_w r = radius * amplitude * grad n(w),

    where grad n(w) = pi f sum_k a_k cos(pi f (d_k . w) + phi_k) d_k / sum_k |a_k| (n extended to R^3 by
    the same formula), and (I - w w^T)/|p| is the Jacobian of p -> p/|p| at |p| = r(w).
    """
    import trimesh

    ico = trimesh.creation.icosphere(subdivisions=shape.subdivisions, radius=1.0)
    w = _normalize(np.asarray(ico.vertices, float))
    faces = np.asarray(ico.faces, np.int64)
    n, grad = bumpy_noise(w, shape.seed, shape.frequency)
    rad = shape.radius * (1.0 + shape.amplitude * n)
    g = shape.radius * shape.amplitude * grad
    g_t = g - np.einsum("ij,ij->i", g, w)[:, None] * w
    normals = _normalize(w - g_t / rad[:, None])
    verts = w * rad[:, None]
    if _signed_volume(verts, faces) < 0:
        faces = faces[:, ::-1]
    return [_part(verts + np.asarray(shape.center, float), faces, normals, "body")]


# --------------------------------------------------------------------------- mesh files


def _components(n_nodes: int, edges: np.ndarray) -> np.ndarray:
    """Connected-component labels (min node index per component) by label propagation + pointer jumping."""
    labels = np.arange(n_nodes)
    if len(edges) == 0:
        return labels
    u, v = edges[:, 0], edges[:, 1]
    while True:
        m = np.minimum(labels[u], labels[v])
        new = labels.copy()
        np.minimum.at(new, labels[u], m)  # hook roots onto smaller labels
        np.minimum.at(new, labels[v], m)
        np.minimum.at(new, u, m)
        np.minimum.at(new, v, m)
        while True:  # pointer jumping to the roots
            jumped = new[new]
            if np.array_equal(jumped, new):
                break
            new = jumped
        if np.array_equal(new, labels):
            return labels
        labels = new


def split_creases(vertices: np.ndarray, faces: np.ndarray, adjacency, adjacency_edges, adjacency_angles,
                  angle: float = CREASE_ANGLE):
    """Split vertices where the faces around them meet at creases sharper than ``angle``.

    Returns (vertices, faces, normals): faces keep their order and winding; every face corner maps to a
    new vertex shared by the corners of the same vertex that are connected through smooth edges; its
    normal is the area-weighted mean of those faces' normals.
    """
    F = len(faces)
    corner_vertex = faces.reshape(-1)
    smooth = np.asarray(adjacency_angles) < angle
    adj = np.asarray(adjacency)[smooth]
    edges = np.asarray(adjacency_edges)[smooth]
    links = []
    for col in range(2):
        vert = edges[:, col]
        c0 = 3 * adj[:, 0] + np.argmax(faces[adj[:, 0]] == vert[:, None], axis=1)
        c1 = 3 * adj[:, 1] + np.argmax(faces[adj[:, 1]] == vert[:, None], axis=1)
        links.append(np.stack([c0, c1], 1))
    labels = _components(3 * F, np.concatenate(links) if links else np.zeros((0, 2), int))
    uniq, new_index = np.unique(labels, return_inverse=True)
    new_faces = new_index.reshape(F, 3)
    new_vertices = vertices[corner_vertex[uniq]]
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    area_normals = np.cross(b - a, c - a)  # length = 2 * area
    acc = np.zeros((len(uniq), 3))
    np.add.at(acc, new_index, np.repeat(area_normals, 3, axis=0))
    return new_vertices, new_faces, _normalize(acc)


def _mesh(shape, scene_dir: pathlib.Path) -> list[MeshPart]:
    import trimesh

    path = pathlib.Path(scene_dir) / shape.file
    try:
        mesh = trimesh.load(str(path), force="mesh")
    except Exception as e:  # trimesh raises all sorts of things for unreadable files
        reason = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        if isinstance(e, FileNotFoundError) or not path.exists():
            reason = "file not found"
        raise ValueError(f"cannot read mesh {path}: {reason}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"cannot read mesh {path}: no triangles in the file")
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise ValueError(f"cannot read mesh {path}: all its triangles are degenerate")
    if not np.all(np.isfinite(mesh.vertices)):
        raise ValueError(f"cannot read mesh {path}: non-finite vertex coordinates")
    if shape.medium is not None and not mesh.is_watertight:
        # rays would leave the medium through the holes without meeting a boundary: a silently wrong image
        raise ValueError(f"mesh {path} holds a medium but is not closed (not watertight); expected a closed mesh")
    vertices = np.asarray(mesh.vertices, float)
    faces = np.asarray(mesh.faces, np.int64)
    if mesh.is_watertight and mesh.is_winding_consistent and _signed_volume(vertices, faces) < 0:
        mesh.invert()
        faces = np.asarray(mesh.faces, np.int64)
    if not shape.smooth:
        return [_part(vertices, faces, None, "body")]
    v, f, n = split_creases(vertices, faces, mesh.face_adjacency, mesh.face_adjacency_edges,
                            mesh.face_adjacency_angles)
    return [_part(v, f, n, "body")]


# --------------------------------------------------------------------------- entry point

_BUILDERS = {
    "bumpy_sphere": _bumpy_sphere,
    "box": _box,
    "cylinder": _cylinder,
    "quad": _quad,
    "cup": _cup,
}


def shape_parts(shape, scene_dir: pathlib.Path) -> list[MeshPart]:
    """World-space triangle meshes of a shape config (see the module docstring). ValueError if impossible."""
    kind = getattr(shape, "type", None)
    if kind == "sphere":
        raise ValueError("sphere shapes are intersected analytically and have no triangle mesh")
    if kind == "mesh":
        parts = _mesh(shape, scene_dir)
    elif kind in _BUILDERS:
        parts = _BUILDERS[kind](shape)
    else:
        raise ValueError(f"cannot mesh shape type {kind!r}")
    if shape.transform is not None:
        M = shape.transform.matrix()
        if not np.all(np.isfinite(M)) or abs(np.linalg.det(M[:3, :3])) == 0:
            raise ValueError("transform is not invertible")
        parts = [_transform(p, M) for p in parts]
    return parts
