"""The distance grid is a lower bound on the true distance to the triangles (so skipping a cast is safe)."""

import numpy as np
import trimesh

from pbvol_cli.geometry.distance_grid import build_distance_grid, mesh_distance_bound


def _box_distance(p, half):
    """Exact distance from points to the surface of the axis-aligned box [-half, half]."""
    q = np.abs(p) - half
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    inside = -np.minimum(np.max(q, axis=1), 0)
    return np.where(np.all(q <= 0, axis=1), inside, outside)


def test_bound_never_exceeds_true_distance_and_is_useful():
    half = np.array([1.0, 0.6, 0.8])
    box = trimesh.creation.box(extents=2 * half)
    V, F = np.asarray(box.vertices), np.asarray(box.faces)
    params, cells = build_distance_grid(V, F, -half, half, eps=1e-6)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1.5, 1.5, size=(20000, 3))
    bound = np.array([mesh_distance_bound(params, cells, *p) for p in pts])
    true = _box_distance(pts, half)
    assert np.all(bound <= true + 1e-12)
    # deep inside the box (where media are), the bound is a sizeable fraction of the true distance
    deep = np.all(np.abs(pts) < half, axis=1) & (true > 0.2)
    assert np.mean(bound[deep] / true[deep]) > 0.4


def test_no_triangles_means_no_bound_and_triangles_without_grid_means_zero():
    p0, c0 = build_distance_grid(np.zeros((0, 3)), np.zeros((0, 3), int), np.zeros(3), np.ones(3), 1e-6)
    assert mesh_distance_bound(p0, c0, 0.5, 0.5, 0.5) == np.inf
    box = trimesh.creation.box()
    p1, c1 = build_distance_grid(np.asarray(box.vertices), np.asarray(box.faces), np.full(3, np.inf),
                                 np.full(3, -np.inf), 1e-6)
    assert mesh_distance_bound(p1, c1, 0.0, 0.0, 0.0) == 0.0
