"""Shared helpers: scenes written from dicts, rendered in-process at small sizes."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import tomli_w

from pbvol_cli import config as C
from pbvol_cli.geometry.scene_build import (CAM_FORWARD, CAM_POS, CAM_RIGHT, CAM_UP, MED_COLS, MED_G, MED_MAJORANT,
                                           MED_PHASE, MED_SIGMA_A, MED_SIGMA_S, build_scene)
from pbvol_cli.physics.phase import KINDS


def write_scene(tmp_path: Path, scene: dict, name: str = "scene.toml") -> Path:
    p = Path(tmp_path) / name
    p.write_bytes(tomli_w.dumps(scene).encode())
    return p


def medium_row(phase: str, g: float, sigma_a, sigma_s) -> np.ndarray:
    """One homogeneous medium's row of the media table (scene_build's MED_* columns; coefficients in 1/unit)."""
    row = np.zeros(MED_COLS)
    row[MED_SIGMA_A:MED_SIGMA_A + 3], row[MED_SIGMA_S:MED_SIGMA_S + 3] = sigma_a, sigma_s
    row[MED_PHASE], row[MED_G] = KINDS[phase], g
    row[MED_MAJORANT] = np.max(np.add(sigma_a, sigma_s))
    return row


def camera(res=(16, 16), position=(0.0, 0.0, 4.0), fov=40.0):
    return {"position": list(position), "look_at": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fov": fov,
            "resolution": list(res)}


# the point-based tests' medium: chromatic, anisotropic, in an index-matched sphere under a directional light
SPHERE_SIGMA_S, SPHERE_SIGMA_A, SPHERE_G = np.array([0.6, 1.0, 2.0]), np.array([0.2, 0.5, 0.1]), 0.5
SPHERE_LIGHT_DIR = [-1.0, -0.5, -0.7]


def medium_sphere_scene(**pbl) -> dict:
    """A radius-1 index-matched sphere of the SPHERE_* medium under a directional light (irradiance 2), 12x12
    pixels, 4 spp; pbl: [render.pbl] settings. Its multiple-scattering tables are coarse (2000 particles: seconds
    to build, not a minute): no test of this scene measures the multiple term."""
    return {"camera": camera((12, 12), position=(0, 0, 3.5), fov=40),
            "render": {"spp": 4, "pbl": pbl, "lut": {"particles": 2000}},
            "lights": [{"type": "directional", "direction": SPHERE_LIGHT_DIR, "irradiance": 2.0}],
            "shapes": [{"type": "sphere", "radius": 1.0, "interface": "null",
                        "medium": {"sigma_a": SPHERE_SIGMA_A.tolist(), "sigma_s": SPHERE_SIGMA_S.tolist(),
                                   "g": SPHERE_G}}]}


def build(tmp_path: Path, scene: dict):
    p = write_scene(tmp_path, scene)
    return build_scene(C.load_scene(p), p)


def volpath(built, spp=16, seed=1, orders=None, max_depth=100000, rr_depth=8, batch=1 << 17, threads=2,
            split_depth=None, split_rule="auto"):
    from pbvol_cli.render.volpath import SPLIT_DEPTH, render_volpath

    split = SPLIT_DEPTH if split_depth is None else split_depth
    img, _, _ = render_volpath(built, spp, seed, max_depth, rr_depth, orders, batch, threads, split_depth=split,
                               split_rule=split_rule)
    return img


def render_layers(tmp_path: Path, scene: dict, method: str, spp: int, seed: int = 1, **settings) -> dict:
    """The layers of a render of scene by method through the pipeline, settings in [render.<method>], and their sum
    under "image"."""
    from pbvol_cli.imageio import read_layers
    from pbvol_cli.pipeline.render import RenderOptions, render_scene

    scene = dict(scene, render=dict(scene["render"], **{method: settings}))
    out = tmp_path / f"{method}.exr"
    render_scene(write_scene(tmp_path, scene), out, RenderOptions(method=method, spp=spp, seed=seed,
                                                                  cache_dir=tmp_path, quiet=True, timings=False))
    layers = {k: v.astype(float) for k, v in read_layers(out).items()}
    return dict(layers, image=sum(layers.values()))


def smooth_layers(tmp_path: Path, scene: dict, seeds) -> np.ndarray:
    """The smooth layers (double, multiple, bounced) of 2-pass pbl renders of scene, one per seed: (seed, layer, H,
    W, 3)."""
    from pbvol_cli.imageio import read_layers
    from pbvol_cli.pipeline.render import RenderOptions, render_scene

    path = write_scene(tmp_path, scene)
    out = []
    for seed in seeds:
        render_scene(path, tmp_path / "o.exr", RenderOptions(method="pbl", spp=2, seed=seed, cache_dir=tmp_path,
                                                             quiet=True))
        L = read_layers(tmp_path / "o.exr")
        out.append([L[c].astype(float) for c in ("double", "multiple", "bounced")])
    return np.array(out)


def camera_ray(cam, x, y):
    """The built camera's ray through the image point (x, y) in [-1, 1] (y up): origin, direction (not unit)."""
    d = cam[CAM_FORWARD:CAM_FORWARD + 3] + x * cam[CAM_RIGHT:CAM_RIGHT + 3] + y * cam[CAM_UP:CAM_UP + 3]
    return cam[CAM_POS:CAM_POS + 3], d


def single_scattering_reference(built, sigma_s, sigma_t, g, light_dir, E, R, k=6):
    """Order-1 radiance of a null-bounded sphere of radius R at the origin under a directional light,
    by quadrature along each camera ray (independent of the renderer's sampling)."""
    cam = built.camera
    W, H = built.resolution
    u = -np.asarray(light_dir, float) / np.linalg.norm(light_dir)  # toward the light
    xs, ws = np.polynomial.legendre.leggauss(48)
    out = np.zeros((H, W, 3))
    covered = np.ones((H, W), bool)
    for py in range(H):
        for px in range(W):
            acc = np.zeros(3)
            for sy in range(k):
                for sx in range(k):
                    x = 2 * (px + (sx + 0.5) / k) / W - 1
                    y = 1 - 2 * (py + (sy + 0.5) / k) / H
                    o, d = camera_ray(cam, x, y)
                    d /= np.linalg.norm(d)
                    b = o @ d
                    disc = b * b - (o @ o - R * R)
                    if disc <= 0:
                        covered[py, px] = False
                        continue
                    t0, t1 = -b - math.sqrt(disc), -b + math.sqrt(disc)
                    t = 0.5 * (t1 - t0) * xs + 0.5 * (t1 + t0)
                    P = o + t[:, None] * d
                    pu = P @ u
                    s = -pu + np.sqrt(np.maximum(pu * pu - (np.sum(P * P, 1) - R * R), 0))
                    mu = d @ u  # cos between propagation of the light (-u) and toward the camera (-d)
                    ph = (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * mu) ** 1.5)
                    f = sigma_s[None] * np.exp(-sigma_t[None] * ((t - t0)[:, None] + s[:, None])) * ph * E
                    acc += 0.5 * (t1 - t0) * (ws[:, None] * f).sum(0)
            out[py, px] = acc / (k * k)
    return out, covered


def random_volume_samples(rng, n, half=2.0):
    """n volume samples in the cube [-half, half]^3: random directions, lengths, kernel areas and boundary ends
    (continued at the boundary), entry planes facing their legs, as VolumeSamples (no multiple-scattering tables)."""
    from pbvol_cli.multiple_scattering.table import empty_table
    from pbvol_cli.pointbased.octree import build_octree, node_lobes
    from pbvol_cli.pointbased.volume_samples import VolumeSamples

    start = rng.uniform(-half, half, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    length = rng.uniform(0.05, 0.8, n)
    area = math.pi * rng.uniform(0.05, 0.2, n) ** 2
    power = rng.uniform(0.5, 1.5, (n, 3))
    ends = rng.integers(0, 4, n)
    plane = np.zeros((n, 8))
    plane[:, 0:3] = -d  # the entry plane through the start, its normal against the leg
    plane[:, 3] = np.einsum("ij,ij->i", -d, start)
    plane[:, 4:7] = d
    plane[:, 7] = np.einsum("ij,ij->i", d, start) + length
    rb = np.sqrt(area / math.pi)
    a, b = start - 3 * rb[:, None] * d, start + (length + 3 * rb)[:, None] * d
    lo, hi = np.minimum(a, b) - rb[:, None], np.maximum(a, b) + rb[:, None]
    centre = start + 0.5 * length[:, None] * d
    tree = build_octree(centre, lo, hi, d, power).arrays()
    return VolumeSamples(tree, start, d, length, power, area, centre, power, rb, ends, plane,
                         (empty_table().render_args(),) * 3, 0.0, node_lobes(tree))


_AHEAD = {}


def pytest_collection_finish(session):
    import kernels_ahead

    _AHEAD["proc"] = kernels_ahead.start(len(session.items))


def pytest_sessionfinish(session, exitstatus):
    import kernels_ahead

    kernels_ahead.finish(_AHEAD.pop("proc", None))
