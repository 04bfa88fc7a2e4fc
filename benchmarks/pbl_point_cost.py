#!/usr/bin/env python3
"""What one evaluation of the point-based estimators costs: single, double and multiple scattering at random points
of a scene's first medium, from its cached light samples, on one thread.

    .venv/bin/python benchmarks/pbl_point_cost.py [--scene oil_sphere] [--points 3000] [--terms single,double,...]

The points are uniform in the sphere of radius --radius about the origin (the example spheres), each with a random
direction and its tangent plane on that sphere as the boundary plane. Prints, per term, the best and median of five
timed runs in microseconds a point, and a checksum of the values (equal checksums: the same arithmetic). The term
single-by-samples is single scattering at all the points at once, sample by sample (single_scattering.py): its
time a point falls as the points grow against the samples (compare with single at --points 10000 and 100000).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def scene_samples(scene_arg: str, cache: Path):
    """(scene file, BuiltScene at 64 x 64, its first medium's SampleSet) from the scene's cached light samples."""
    from pbvol_cli import config as C
    from pbvol_cli.geometry.scene_build import build_scene
    from pbvol_cli.pipeline.render import RenderOptions, light_side
    from pbvol_cli.pointbased.passes import kernel_tables
    from pbvol_cli.pointbased.volume_samples import SampleSet

    path = Path(scene_arg) if scene_arg.endswith(".toml") else ROOT / "configs" / f"{scene_arg}.toml"
    scene = C.load_scene(path)
    bs = build_scene(scene, path, (64, 64))
    side = light_side(scene, bs, scene.render.seed, 2, RenderOptions(method="pbl", quiet=True, cache_dir=cache),
                      "point cost")
    bs = side.built  # (its media after [render.pbl] similarity)
    return path, scene, bs, SampleSet(side.samples.samples, 0, bs.media, kernel_tables(side.tables[0]),
                                      scene.render.pbl.beam_width)


def point_args(ap, points: int):
    """The arguments both point-cost scripts take: --scene, --points, --radius, --cache."""
    ap.add_argument("--scene", default="oil_sphere", help="a config name in configs/ or a scene file")
    ap.add_argument("--points", type=int, default=points)
    ap.add_argument("--radius", type=float, default=5.0, help="the medium's sphere, scene units")
    ap.add_argument("--cache", type=Path, default=ROOT / ".bench-cache")


def points_in_sphere(m: int, radius: float, rng):
    """(m points uniform in the sphere of that radius about the origin, their directions from it (unit))."""
    normal = rng.normal(size=(m, 3))
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    return normal * (radius * rng.random(m) ** (1 / 3))[:, None], normal


def main():
    from pbvol_cli.pointbased.gather import gather_settings
    from pbvol_cli.pointbased.radiance_cache import ScatteredPoints, _evaluate, all_terms
    from pbvol_cli.pointbased.single_scattering import single_scattering_by_samples
    from pbvol_cli.pointbased.volume_samples import medium_params

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    point_args(ap, 3000)
    ap.add_argument("--terms", default="single,double,multiple,double+multiple")
    args = ap.parse_args()
    path, scene, bs, sample_set = scene_samples(args.scene, args.cache)
    med = medium_params(bs.media, 0)
    rng = np.random.default_rng(3)
    m = args.points
    pos, normal = points_in_sphere(m, args.radius, rng)
    dirs = rng.normal(size=(m, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    plane = np.column_stack([normal, np.full(m, args.radius)])  # n . x = radius: the tangent plane above
    pts = ScatteredPoints(pos, dirs, np.ones((m, 3)), plane, np.arange(m))
    reps = np.arange(m)
    print(f"{path.stem}: {sample_set.count} volume samples, {m} points, one thread")
    for term in args.terms.split(","):
        values = np.zeros((m, 3, 3))
        if term == "single-by-samples":  # the same sums, sample by sample over a grid of all the points at once
            def run(k=m):
                values[:k, 0] = single_scattering_by_samples(None, 1, sample_set.kernel, med, pos[:k], dirs[:k])
        else:
            names = tuple(term.split("+"))
            settings = gather_settings(scene.render.pbl, names)
            single = "single" in names
            streams = np.arange(m, dtype=np.uint64) * np.uint64(2654435761) + np.uint64(1)

            def run(k=m):
                _evaluate(reps[:k], all_terms(settings, k), pts, streams.copy(), med, sample_set.kernel, settings,
                          single, values)
        run(10)  # compile
        times = []
        for _ in range(5):
            values[:] = 0.0
            t = time.perf_counter()
            run()
            times.append(time.perf_counter() - t)
        times.sort()
        print(f"  {term:18s} {1e6 * times[0] / m:8.1f} µs best, {1e6 * times[2] / m:8.1f} median, "
              f"checksum {float(values.sum()):.9g}")


if __name__ == "__main__":
    main()
