"""Triangle meshes of the shape configs (pbvol_cli.geometry.primitives)."""

import math

import numpy as np
import pytest
import trimesh

from pbvol_cli.config import (
    BoxShape,
    BumpySphereShape,
    CupShape,
    CylinderShape,
    MeshShape,
    QuadShape,
    SphereShape,
    Transform,
)
from pbvol_cli.geometry.primitives import MeshPart, count_triangles, shape_parts

# --------------------------------------------------------------------------- helpers


def face_normals(part):
    v, f = part.vertices, part.faces
    return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])


def merged(parts, reverse=()):
    """One (vertices, faces) from several parts, coincident vertices merged; parts with index in reverse
    are flipped."""
    verts = np.concatenate([p.vertices for p in parts])
    faces, off = [], 0
    for i, p in enumerate(parts):
        f = p.faces.astype(np.int64) + off
        faces.append(f[:, ::-1] if i in reverse else f)
        off += len(p.vertices)
    faces = np.concatenate(faces)
    key = np.round(verts, 9)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    return uniq, inv.reshape(-1)[faces]


def edge_face_counts(faces):
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.sort(e, axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return counts


def assert_closed_oriented(verts, faces):
    """Every undirected edge in exactly 2 faces, every directed edge exactly once (consistent winding)."""
    assert np.all(edge_face_counts(faces) == 2)
    d = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    _, counts = np.unique(d, axis=0, return_counts=True)
    assert np.all(counts == 1)


def signed_volume(verts, faces):
    a, b, c = (verts[faces[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def check_types(parts):
    for p in parts:
        assert isinstance(p, MeshPart)
        assert p.vertices.dtype == np.float64 and p.vertices.shape[1] == 3
        assert p.faces.dtype == np.int32 and p.faces.shape[1] == 3
        assert p.faces.min() >= 0 and p.faces.max() < len(p.vertices)
        if p.normals is not None:
            assert p.normals.dtype == np.float64 and p.normals.shape == p.vertices.shape
            np.testing.assert_allclose(np.linalg.norm(p.normals, axis=1), 1.0, atol=1e-12)


def check_shading_consistent(part, min_cos=0.0):
    """Shading normals at a face's corners within 90 degrees of its geometric normal."""
    fn = face_normals(part)
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    for i in range(3):
        assert np.all(np.einsum("ij,ij->i", part.normals[part.faces[:, i]], fn) > min_cos)


# --------------------------------------------------------------------------- simple shapes


def test_box_volume_and_outward_normals(tmp_path):
    shape = BoxShape(type="box", center=(1, 2, 3), size=(1, 2, 3))
    parts = shape_parts(shape, tmp_path)
    check_types(parts)
    assert len(parts) == 1 and parts[0].role == "body" and parts[0].normals is None
    assert count_triangles(parts) == 12
    v, f = merged(parts)
    assert_closed_oriented(v, f)
    assert signed_volume(v, f) == pytest.approx(6.0, rel=1e-12)
    p = parts[0]
    centroids = p.vertices[p.faces].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", face_normals(p), centroids - np.array([1, 2, 3])) > 0)


def test_cylinder_volume(tmp_path):
    shape = CylinderShape(type="cylinder", center=(0.5, -1, 2), radius=0.7, height=1.3)
    parts = shape_parts(shape, tmp_path)
    check_types(parts)
    assert {p.role for p in parts} == {"body"}
    v, f = merged(parts)
    assert_closed_oriented(v, f)
    assert signed_volume(v, f) == pytest.approx(math.pi * 0.7**2 * 1.3, rel=1e-3)
    smooth = [p for p in parts if p.normals is not None]
    assert len(smooth) == 1
    check_shading_consistent(smooth[0], min_cos=0.99)
    assert np.allclose(smooth[0].normals[:, 1], 0.0)
    assert v[:, 1].min() == pytest.approx(-1) and v[:, 1].max() == pytest.approx(0.3)


def test_quad_plane_and_normal(tmp_path):
    shape = QuadShape(type="quad", center=(0, 1, 0), size=(2, 4))
    (p,) = shape_parts(shape, tmp_path)
    check_types([p])
    assert p.normals is None and len(p.faces) == 2
    n = face_normals(p)
    assert np.all(n[:, 1] > 0) and np.allclose(n[:, [0, 2]], 0)
    assert np.allclose(p.vertices[:, 1], 1.0)
    assert np.abs(n).sum() / 2 == pytest.approx(8.0)  # area
    assert np.ptp(p.vertices[:, 0]) == pytest.approx(2) and np.ptp(p.vertices[:, 2]) == pytest.approx(4)


def test_sphere_is_rejected(tmp_path):
    with pytest.raises(ValueError):
        shape_parts(SphereShape(type="sphere"), tmp_path)


# --------------------------------------------------------------------------- bumpy sphere


def bumpy(**kw):
    args = dict(type="bumpy_sphere", center=(0.3, 0.2, -0.1), radius=2.0, subdivisions=4)
    args.update(kw)
    return BumpySphereShape(**args)


def radii(part, shape):
    return np.linalg.norm(part.vertices - np.asarray(shape.center), axis=1)


def test_bumpy_sphere_amplitude_zero_is_a_sphere(tmp_path):
    s = bumpy(amplitude=0.0)
    (p,) = shape_parts(s, tmp_path)
    np.testing.assert_allclose(radii(p, s), 2.0, rtol=1e-12)


def test_bumpy_sphere_bounds_and_normals(tmp_path):
    s = bumpy(amplitude=0.1, frequency=3.0, seed=5)
    parts = shape_parts(s, tmp_path)
    check_types(parts)
    (p,) = parts
    r = radii(p, s)
    assert r.min() >= 0.9 * 2.0 - 1e-12 and r.max() <= 1.1 * 2.0 + 1e-12
    assert np.ptp(r) > 0.05  # actually bumpy
    v, f = merged(parts)
    assert_closed_oriented(v, f)
    assert signed_volume(v, f) > 0
    check_shading_consistent(p)


def test_bumpy_sphere_normals_match_finite_differences(tmp_path):
    # At high resolution the analytic normals agree with area-weighted vertex normals of the mesh.
    s = bumpy(amplitude=0.1, frequency=2.0, seed=1, subdivisions=6)
    (p,) = shape_parts(s, tmp_path)
    m = trimesh.Trimesh(p.vertices, p.faces, process=False)
    cos = np.einsum("ij,ij->i", m.vertex_normals, p.normals)
    assert cos.min() > 0.999


def test_bumpy_sphere_deterministic(tmp_path):
    a = shape_parts(bumpy(seed=3), tmp_path)[0]
    b = shape_parts(bumpy(seed=3), tmp_path)[0]
    c = shape_parts(bumpy(seed=4), tmp_path)[0]
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_array_equal(a.normals, b.normals)
    assert np.abs(a.vertices - c.vertices).max() > 1e-3


# --------------------------------------------------------------------------- cup

CUP = dict(type="cup", center=(0.1, -0.5, 0.2), radius=1.0, height=2.0, wall=0.1, bottom=0.2)


def test_cup_filled_regions(tmp_path):
    shape = CupShape(**CUP, fill=0.5, liquid="water")
    parts = shape_parts(shape, tmp_path)
    check_types(parts)
    assert {p.role for p in parts} == {"glass", "liquid_glass", "liquid_free"}
    R, r, H, yb = 1.0, 0.9, 2.0, 0.2
    yl = yb + 0.5 * (H - yb)

    # Union of everything: no cracks (no boundary edges); only the three-media ring at the liquid level
    # has three faces per edge (glass wall above, liquid-glass wall below, free surface).
    v, f = merged(parts)
    counts = edge_face_counts(f)
    assert np.all((counts == 2) | (counts == 3))
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    ue, c = np.unique(e, axis=0, return_counts=True)
    triple = ue[c == 3]
    assert len(triple) == shape.segments
    assert np.allclose(v[triple][..., 1], yl - 0.5)
    assert np.allclose(np.linalg.norm(v[triple][..., [0, 2]] - [0.1, 0.2], axis=-1), r)

    # The glass region: "glass" parts + reversed "liquid_glass" parts.
    glass = [p for p in parts if p.role in ("glass", "liquid_glass")]
    rev = {i for i, p in enumerate(glass) if p.role == "liquid_glass"}
    v, f = merged(glass, reverse=rev)
    assert_closed_oriented(v, f)
    vol_glass = math.pi * (R**2 - r**2) * (H - yb) + math.pi * R**2 * yb
    assert signed_volume(v, f) == pytest.approx(vol_glass, rel=1e-2)

    # The liquid region.
    liquid = [p for p in parts if p.role in ("liquid_glass", "liquid_free")]
    v, f = merged(liquid)
    assert_closed_oriented(v, f)
    assert signed_volume(v, f) == pytest.approx(math.pi * r**2 * (yl - yb), rel=1e-2)

    free = [p for p in parts if p.role == "liquid_free"]
    assert all(np.all(face_normals(p)[:, 1] > 0) for p in free)
    for p in parts:
        if p.normals is not None:
            check_shading_consistent(p, min_cos=0.99)
            assert len({p.role}) == 1


def test_cup_empty_and_full(tmp_path):
    R, r, H, yb = 1.0, 0.9, 2.0, 0.2
    vol_glass = math.pi * (R**2 - r**2) * (H - yb) + math.pi * R**2 * yb
    parts = shape_parts(CupShape(**CUP), tmp_path)
    assert {p.role for p in parts} == {"glass"}
    v, f = merged(parts)
    assert_closed_oriented(v, f)
    assert signed_volume(v, f) == pytest.approx(vol_glass, rel=1e-2)

    parts = shape_parts(CupShape(**CUP, fill=1.0, liquid="water"), tmp_path)
    glass = [p for p in parts if p.role in ("glass", "liquid_glass")]
    v, f = merged(glass, reverse={i for i, p in enumerate(glass) if p.role == "liquid_glass"})
    assert_closed_oriented(v, f)
    assert signed_volume(v, f) == pytest.approx(vol_glass, rel=1e-2)
    liquid = [p for p in parts if p.role in ("liquid_glass", "liquid_free")]
    v, f = merged(liquid)
    assert_closed_oriented(v, f)
    assert signed_volume(v, f) == pytest.approx(math.pi * r**2 * (H - yb), rel=1e-2)


# --------------------------------------------------------------------------- transforms

T = Transform(translate=(1.0, -2.0, 0.5), rotate=(30.0, 45.0, -60.0), scale=(2.0, 0.5, 1.5))


@pytest.mark.parametrize(
    "shape",
    [
        BoxShape(type="box", size=(1, 2, 3)),
        CylinderShape(type="cylinder", radius=0.5, height=2.0, segments=64),
        BumpySphereShape(type="bumpy_sphere", subdivisions=4, amplitude=0.05),
        QuadShape(type="quad", size=(1, 2)),
        CupShape(**CUP, fill=0.3, liquid="water", segments=64),
    ],
    ids=lambda s: s.type,
)
def test_transform(tmp_path, shape):
    plain = shape_parts(shape, tmp_path)
    moved = shape_parts(shape.model_copy(update={"transform": T}), tmp_path)
    check_types(moved)
    M = T.matrix()
    assert len(plain) == len(moved)
    for a, b in zip(plain, moved):
        assert a.role == b.role
        np.testing.assert_allclose(b.vertices, a.vertices @ M[:3, :3].T + M[:3, 3], atol=1e-12)
        np.testing.assert_array_equal(a.faces, b.faces)
        assert (a.normals is None) == (b.normals is None)
        if b.normals is not None:
            check_shading_consistent(b)
    if shape.type != "quad":
        v0, f0 = merged([p for p in plain if p.role in ("body", "glass")])
        v1, f1 = merged([p for p in moved if p.role in ("body", "glass")])
        det = np.linalg.det(M[:3, :3])
        assert det == pytest.approx(1.5)
        if shape.type != "cup":
            assert signed_volume(v1, f1) == pytest.approx(det * signed_volume(v0, f0), rel=1e-9)
    else:
        n = face_normals(moved[0])
        expected = np.linalg.inv(M[:3, :3]).T @ [0, 1, 0]
        assert np.all(n @ expected > 0)


def test_transformed_normals_are_inverse_transpose(tmp_path):
    shape = CylinderShape(type="cylinder", radius=1.0, height=1.0, segments=32, transform=T)
    wall = next(p for p in shape_parts(shape, tmp_path) if p.normals is not None)
    # The wall's world-space normals are exactly perpendicular to the (straight) vertical edges.
    A = T.matrix()[:3, :3]
    axis = A @ [0, 1, 0]
    np.testing.assert_allclose(wall.normals @ axis, 0.0, atol=1e-12)


# --------------------------------------------------------------------------- mesh files


@pytest.mark.parametrize("ext", ["ply", "obj", "stl"])
def test_mesh_roundtrip(tmp_path, ext):
    src = trimesh.creation.icosphere(subdivisions=2, radius=1.5)
    (tmp_path / "sub").mkdir()
    src.export(tmp_path / "sub" / f"m.{ext}")
    for smooth in (False, True):
        shape = MeshShape(type="mesh", file=f"sub/m.{ext}", smooth=smooth)
        parts = shape_parts(shape, tmp_path)
        check_types(parts)
        assert count_triangles(parts) == len(src.faces)
        (p,) = parts
        assert p.role == "body"
        v, f = merged(parts)
        assert_closed_oriented(v, f)
        assert signed_volume(v, f) == pytest.approx(src.volume, rel=1e-6)
        if smooth:
            assert len(p.vertices) == len(src.vertices)  # no creases above 60 degrees
            check_shading_consistent(p, min_cos=0.9)
            radial = p.vertices / np.linalg.norm(p.vertices, axis=1, keepdims=True)
            assert np.einsum("ij,ij->i", radial, p.normals).min() > 0.99
        else:
            assert p.normals is None


def test_mesh_creases_split_and_inside_out_flipped(tmp_path):
    box = trimesh.creation.box(extents=(1, 2, 3))
    box.invert()  # written inside out
    box.export(tmp_path / "box.ply")
    (p,) = shape_parts(MeshShape(type="mesh", file="box.ply"), tmp_path)
    check_types([p])
    assert len(p.faces) == 12
    assert len(p.vertices) == 24  # each corner split into its 3 faces
    v, f = merged([p])
    assert signed_volume(v, f) == pytest.approx(6.0)
    fn = face_normals(p)
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    for i in range(3):
        np.testing.assert_allclose(p.normals[p.faces[:, i]], fn, atol=1e-12)


def test_mesh_transform_and_smooth_cylinder(tmp_path):
    cyl = trimesh.creation.cylinder(radius=1.0, height=2.0, sections=32)
    cyl.export(tmp_path / "c.obj")
    (p,) = shape_parts(MeshShape(type="mesh", file="c.obj", transform=T), tmp_path)
    check_types([p])
    check_shading_consistent(p)
    assert len(p.faces) == len(cyl.faces)


def test_mesh_missing_file(tmp_path):
    with pytest.raises(ValueError, match="cannot read mesh .*nope.obj"):
        shape_parts(MeshShape(type="mesh", file="nope.obj"), tmp_path)


def test_mesh_garbage_and_empty(tmp_path):
    (tmp_path / "bad.ply").write_bytes(b"this is not a ply file\n\x00\x01")
    with pytest.raises(ValueError, match="cannot read mesh"):
        shape_parts(MeshShape(type="mesh", file="bad.ply"), tmp_path)
    (tmp_path / "empty.obj").write_text("# nothing\n")
    with pytest.raises(ValueError, match="cannot read mesh"):
        shape_parts(MeshShape(type="mesh", file="empty.obj"), tmp_path)
