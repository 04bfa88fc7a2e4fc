#!/usr/bin/env python3
"""Single scattering's largest flush of a pass, timed alone, with the same points and samples every time.

    .venv/bin/python benchmarks/pbl_single_flush.py [--scene oil_sphere] [--resolution 256] [--repeat 8]
        [--threads 2] [--cache DIR]

A warm 1-spp render of the scene (after one at 8 x 8, so that compiling is not timed) with
`single_scattering.single_scattering_by_samples` wrapped to keep its largest call's camera points and volume
samples; then that call again, --repeat times on one thread and --repeat times on --threads threads, alternately.
Prints the flush's size (points, volume samples, legs), per thread count the fastest and the median seconds (the
machine's drift is in the median; compare the fastest), and the image's channel sums. Run it from a worktree of
another commit to compare two versions of the kernel: the same sums say they add the same shares.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from pbl_bench import one_scene_args, parsed_scene  # noqa: E402


def main():
    import pbvol_cli.pointbased.single_scattering as single_scattering
    from pbvol_cli.pipeline.render import RenderOptions, render_scene

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    one_scene_args(ap, 256)
    ap.add_argument("--repeat", type=int, default=8)
    args, scene = parsed_scene(ap)
    by_samples = single_scattering.single_scattering_by_samples
    kept = []

    def keep(pool, threads, vs, med, pts, wdir):
        if not kept or len(pts) > len(kept[0][2]):
            kept[:] = [(vs, med, pts.copy(), wdir.copy())]
        return by_samples(pool, threads, vs, med, pts, wdir)

    single_scattering.single_scattering_by_samples = keep
    opts = dict(method="pbl", threads=args.threads, cache_dir=args.cache, quiet=True)
    out = ROOT / "bench-out"
    out.mkdir(exist_ok=True)
    render_scene(scene, out / "single-flush-warm.exr", RenderOptions(spp=1, resolution=(8, 8), **opts))
    kept.clear()
    render_scene(scene, out / "single-flush.exr",
                 RenderOptions(spp=1, resolution=(args.resolution, args.resolution), **opts))
    single_scattering.single_scattering_by_samples = by_samples
    if not kept:
        sys.exit(f"{scene.stem}: no single-scattering flush went sample by sample at {args.resolution}²")
    vs, med, pts, wdir = kept[0]
    print(f"{scene.stem} {args.resolution}²: {len(pts)} points, {vs.start.shape[0]} volume samples, "
          f"{len(vs.leg_first)} legs")
    pool = ThreadPoolExecutor(args.threads) if args.threads > 1 else None
    seconds = {1: [], args.threads: []}
    for _ in range(args.repeat):
        for threads in seconds:
            t = time.perf_counter()
            sums = by_samples(pool if threads > 1 else None, threads, vs, med, pts, wdir)
            seconds[threads].append(time.perf_counter() - t)
    for threads, s in seconds.items():
        print(f"  {threads} thread(s): fastest {min(s):.3f} s, median {statistics.median(s):.3f} s")
    print("  sums (R, G, B): " + ", ".join(f"{v:.10g}" for v in sums.sum(axis=0)))


if __name__ == "__main__":
    main()
