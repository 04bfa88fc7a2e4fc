#!/usr/bin/env python3
"""How noisy one evaluation of each point-based term is at fixed points in a medium: the light side's spread (from
light-sample set to light-sample set) and the stochastic light cut's (from random stream to random stream, one set).

    .venv/bin/python benchmarks/pbl_point_spread.py [--scene bumpy_sphere] [--start 0,5,-4] [--end 0,5,4]
        [--points 17] [--direction 0,0,1] [--sets 4] [--streams 16] [--terms single,double,multiple] [--set k=v]

The points lie evenly on the segment from --start to --end (inside the scene's first medium), each looking along
--direction (the camera ray's propagation direction there); the boundary plane is the one --plane gives (n_x, n_y,
n_z, q: n . x = q, normal outward; default: none). Each of --sets light-sample sets (seeds 100, 101, ...) is placed
as a render places pass 0's (cached), and each term is evaluated --streams times at every point with independent
random streams, as the camera pass evaluates a bin's point. Prints, per term, the mean over the points of: the
term's value; one evaluation's relative standard deviation within a set (the cut's noise: single scattering has
none); the relative standard deviation of the set means (the light side's); the largest evaluation over its mean.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pbl_bench import pbl_overrides  # noqa: E402


def _vector(text: str) -> np.ndarray:
    return np.array([float(v) for v in text.split(",")])


def main():
    from pbvol_cli import config as C
    from pbvol_cli.geometry.scene_build import build_scene
    from pbvol_cli.pipeline.render import RenderOptions, light_side
    from pbvol_cli.pointbased.gather import gather_settings
    from pbvol_cli.pointbased.passes import kernel_tables
    from pbvol_cli.pointbased.radiance_cache import ScatteredPoints, _evaluate, all_terms
    from pbvol_cli.pointbased.volume_samples import SampleSet, medium_params

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="bumpy_sphere", help="a config name in configs/ or a scene file")
    ap.add_argument("--start", type=_vector, default=_vector("0,5,-4"))
    ap.add_argument("--end", type=_vector, default=_vector("0,5,4"))
    ap.add_argument("--points", type=int, default=17)
    ap.add_argument("--direction", type=_vector, default=_vector("0,0,1"))
    ap.add_argument("--plane", type=_vector, default=None)
    ap.add_argument("--sets", type=int, default=4)
    ap.add_argument("--streams", type=int, default=16)
    ap.add_argument("--terms", default="single,double,multiple")
    ap.add_argument("--set", action="append", default=[], dest="overrides", help="a [render.pbl] override k=v")
    ap.add_argument("--cache", type=Path, default=ROOT / ".bench-cache")
    args = ap.parse_args()
    path = Path(args.scene) if args.scene.endswith(".toml") else ROOT / "configs" / f"{args.scene}.toml"
    scene = C.load_scene(path)
    over = pbl_overrides(",".join(args.overrides))
    pbl = scene.render.pbl.model_copy(update=over)
    scene = scene.model_copy(update={"render": scene.render.model_copy(update={"pbl": pbl})})
    bs = build_scene(scene, path, (64, 64))
    m = args.points
    pos = args.start + np.linspace(0.0, 1.0, m)[:, None] * (args.end - args.start)
    dirs = np.tile(args.direction / np.linalg.norm(args.direction), (m, 1))
    plane = np.tile(args.plane if args.plane is not None else np.array([0.0, 0.0, 1.0, np.inf]), (m, 1))
    pts = ScatteredPoints(pos, dirs, np.ones((m, 3)), plane, np.arange(m))
    terms = args.terms.split(",")
    values = {t: np.zeros((args.sets, args.streams, m)) for t in terms}
    for li in range(args.sets):
        side = light_side(scene, bs, 100 + li, 2, RenderOptions(method="pbl", quiet=True, cache_dir=args.cache),
                          path)
        media = side.built.media  # (after [render.pbl] similarity)
        med = medium_params(media, 0)
        kernel = SampleSet(side.samples.samples, 0, media, kernel_tables(side.tables[0]), pbl.beam_width).kernel
        for term in terms:
            settings = gather_settings(pbl, (term,))
            layer = ("single", "double", "multiple").index(term)
            for si in range(args.streams if term != "single" else 1):
                out = np.zeros((m, 3, 3))
                streams = np.arange(m, dtype=np.uint64) * np.uint64(2654435761) + np.uint64(1 + 7919 * si)
                _evaluate(np.arange(m), all_terms(settings, m), pts, streams, med, kernel, settings, term == "single",
                          out)
                values[term][li, si] = out[:, layer].sum(axis=1)
            if term == "single":
                values[term][li, 1:] = values[term][li, 0]
    print(f"{path.stem}: {m} points from {args.start.tolist()} to {args.end.tolist()} looking along "
          f"{args.direction.tolist()}, {args.sets} light-sample sets x {args.streams} streams"
          + (f", {over}" if over else ""))
    for term in terms:
        v = values[term]
        mean = v.mean(axis=(0, 1))
        ok = mean > 0.0
        within = np.sqrt(v.var(axis=1, ddof=1).mean(axis=0)) if args.streams > 1 else np.zeros(m)
        between = np.sqrt(v.mean(axis=1).var(axis=0, ddof=1)) if args.sets > 1 else np.zeros(m)
        print(f"  {term:9s} value {mean[ok].mean():.4g}, one evaluation's relative std within a set "
              f"{np.mean(within[ok] / mean[ok]):.2f}, of the set means {np.mean(between[ok] / mean[ok]):.2f}, "
              f"largest / mean {np.mean(v.max(axis=(0, 1))[ok] / mean[ok]):.1f}")


if __name__ == "__main__":
    main()
