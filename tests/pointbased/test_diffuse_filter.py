"""The medium's light after a first diffuse bounce, pooled among neighbouring vertices (path-space filtering)."""

import math

import numpy as np

from conftest import camera, medium_sphere_scene, write_scene
from pbvol_cli.imageio import read_layers
from pbvol_cli.pipeline.render import RenderOptions, render_scene
from pbvol_cli.pointbased.diffuse_filter import FILTER_LAYERS, DiffuseVertices


def _store(cell=4.0, angle=0.01, seed=1):
    return DiffuseVertices(np.random.default_rng(seed), angle, cell)


def _light(values):
    """(n, FILTER_LAYERS, 3) with values (n,) in every layer and channel."""
    return np.repeat(np.asarray(values, float)[:, None, None], FILTER_LAYERS * 3, axis=1).reshape(-1, FILTER_LAYERS, 3)


def _flush(store, npix):
    layers = [np.zeros((npix, 3)) for _ in range(FILTER_LAYERS)]
    bins = store.flush(layers)
    return layers, bins


def test_vertices_of_one_bin_share_its_light_in_proportion_to_their_weights_those_that_found_nothing_too():
    """Four vertices close together (one bin) of weights 1, 2, 1, 0.5 find light 3, 0, 1, 0: each takes its weight x
    the bin's light over its weight (4 / 4.5), the two that found nothing too; the bin's total, 4, is kept."""
    store = _store(cell=4.0, angle=0.01)
    pos = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.0, 0.01], [0.01, 0.0, 0.01]]) + 0.5
    w = np.array([1.0, 2.0, 1.0, 0.5])
    # 4 footprints at a reach of 1e6: cells 65536 wide, the points in one of them whatever the shift
    ids = store.add(pos, np.tile([0.0, 1.0, 0.0], (4, 1)), np.zeros(4, int), np.full(4, 1e6),
                    np.repeat(w[:, None], 3, axis=1), np.arange(4))
    store.accumulate(ids[:2], _light([3.0, 0.0]))
    store.accumulate(ids[2:3], _light([1.0]))
    layers, bins = _flush(store, 4)
    assert bins == 1
    for layer in layers:
        assert np.allclose(layer[:, 0], w * 4.0 / 4.5) and np.isclose(layer[:, 0].sum(), 4.0)
    assert store.count == 0  # emptied for the next pass


def test_a_constant_glow_comes_through_unchanged_and_surfaces_sides_and_distant_vertices_stay_apart():
    """Where every vertex's light per unit weight is the same the pooled image is the unpooled one exactly; vertices
    on two surfaces, on two sides of one surface, or farther apart than a few cells do not share."""
    rng = np.random.default_rng(5)
    n = 400
    store = _store(cell=2.0, angle=0.01)
    pos = rng.random((n, 3)) * 10.0
    normal = np.tile([0.0, 0.0, 1.0], (n, 1))
    w = rng.random((n, 3)) + 0.1
    ids = store.add(pos, normal, rng.integers(0, 3, n), rng.random(n) * 20.0, w, rng.integers(0, 50, n))
    store.accumulate(ids, _light(np.ones(n))[:, :, :] * w[:, None, :] * 0.7)
    pix = store.pixel[0].copy()
    layers, _ = _flush(store, 50)
    expected = np.stack([np.bincount(pix, weights=0.7 * w[:, c], minlength=50) for c in range(3)], axis=1)
    for layer in layers:
        assert np.allclose(layer, expected)

    # two vertices at one point: one on surface 0, one on surface 1 (or the other side): each keeps its own
    for surface, side in (((0, 1), (1.0, 1.0)), ((0, 0), (1.0, -1.0))):
        store = _store(cell=4.0, angle=0.01)
        ids = store.add(np.full((2, 3), 0.5), np.array([[0.0, side[0], 0.0], [0.0, side[1], 0.0]]),
                        np.array(surface), np.full(2, 1e6), np.ones((2, 3)), np.array([0, 1]))
        store.accumulate(ids[:1], _light([2.0]))
        layers, bins = _flush(store, 2)
        assert bins == 2 and np.allclose(layers[1][:, 1], [2.0, 0.0])

    # near the camera a cell is small: vertices 1 apart at a reach of 1 (cells of 0.04) do not share
    store = _store(cell=4.0, angle=0.01)
    ids = store.add(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), np.tile([0.0, 1.0, 0.0], (2, 1)), np.zeros(2, int),
                    np.ones(2), np.ones((2, 3)), np.array([0, 1]))
    store.accumulate(ids[:1], _light([2.0]))
    layers, bins = _flush(store, 2)
    assert bins == 2 and np.allclose(layers[0][:, 2], [2.0, 0.0])


def _floor_glow_scene():
    """A medium sphere (scattering much of a directional light) just above a diffuse floor, the camera looking down
    at the floor beside it: most of the medium layers' light in the image is the sphere's glow on the floor."""
    scene = medium_sphere_scene(surface_samples=800, segments_per_beam=4, bounce_samples=64)
    scene["camera"] = camera((12, 12), position=(2.2, 3.0, 2.2), fov=40)
    scene["camera"]["look_at"] = [1.6, -1.0, 1.6]
    scene["shapes"].append({"type": "quad", "center": [0, -1.05, 0], "size": [10.0, 10.0], "interface": "diffuse",
                            "albedo": 0.7})
    return scene


def test_pooling_keeps_the_floors_glow_and_cuts_its_noise(tmp_path):
    """The floor's glow (the medium layers, seen after a diffuse bounce) rendered with diffuse_filter 0 and 4 over
    eight seeds: its image mean stays within 4 standard errors of the seed-to-seed spread, and its per-pixel
    variance over the seeds falls at least twofold (pooling a dozen vertices or more a cell)."""
    scene = _floor_glow_scene()
    path_runs = {}
    for cell in (0.0, 4.0):
        scene["render"]["pbl"]["diffuse_filter"] = cell
        path = write_scene(tmp_path, scene)
        runs = []
        for seed in range(8):
            render_scene(path, tmp_path / "o.exr", RenderOptions(method="pbl", spp=2, seed=seed, cache_dir=tmp_path,
                                                                 quiet=True))
            L = read_layers(tmp_path / "o.exr")
            runs.append(sum(L[c].astype(float) for c in ("single", "double", "multiple", "bounced")))
        path_runs[cell] = np.array(runs)  # (seed, H, W, 3)
    a, b = path_runs[0.0], path_runs[4.0]
    ma, mb = a.mean((1, 2, 3)), b.mean((1, 2, 3))
    se = math.hypot(ma.std(ddof=1), mb.std(ddof=1)) / math.sqrt(len(ma))
    va, vb = a.var(axis=0, ddof=1).mean(), b.var(axis=0, ddof=1).mean()
    print("glow mean unpooled, pooled, se:", ma.mean(), mb.mean(), se, "variance:", va, vb)
    assert ma.mean() > 0 and abs(ma.mean() - mb.mean()) < 4 * se
    assert vb < 0.5 * va, (va, vb)
