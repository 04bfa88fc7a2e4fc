#!/usr/bin/env python3
"""Where a pbl render spends its time: the stages of its passes timed (the kernels run as they are).

    .venv/bin/python benchmarks/pbl_profile.py [--scene oil_sphere] [--resolution 128] [--spp 2] [--repeat 1]
        [--cache DIR]

Prints the render's time and, per stage, its total seconds over the passes and how often it ran: the lights' and
the bounced samples' evaluation along camera segments (per point: what is neither shared nor deferred; at a batch's
points: single scattering, deferred to the batch's end; shared: the smooth terms evaluated once per bin), the light
side of a pass (placing a new light-sample set, the octrees over its volume samples, the bounced samples), the
camera paths' surface work and their draws of the truncated peak's deflections. A warm-up render of two passes
first, so that compiling is not counted. With --repeat N the render is repeated N times in the process and each
stage's median printed (stages of a few milliseconds move by a third from render to render).
"""

from __future__ import annotations

import argparse
import collections
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from pbl_bench import one_scene_args, parsed_scene  # noqa: E402


def main():
    import pbvol_cli.pointbased.camera_pass as camera_pass
    import pbvol_cli.pointbased.gather as gather
    import pbvol_cli.pointbased.passes as passes
    import pbvol_cli.pipeline.render as render_module
    import pbvol_cli.pointbased.radiance_cache as radiance_cache
    from pbvol_cli.pipeline.render import RenderOptions, render_scene

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    one_scene_args(ap, 128)
    ap.add_argument("--spp", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1, help="renders in the process; each stage's median printed")
    args, scene = parsed_scene(ap)
    seconds, calls = collections.defaultdict(float), collections.defaultdict(int)

    def timed(module, name, label):
        f = getattr(module, name)

        def wrapper(*a, **k):
            t = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                seconds[label] += time.perf_counter() - t
                calls[label] += 1

        setattr(module, name, wrapper)

    timed(gather, "_on_threads", "medium terms per point (single, and all after a diffuse bounce)")
    timed(gather, "single_scattering_at_points", "single scattering at a batch's points (by samples or point by point)")
    timed(radiance_cache.DeferredBins, "flush", "medium terms shared in bins (double, multiple, bounced)")
    timed(camera_pass, "_pilot", "the pilot's surface-only paths (the first passes' path counts)")
    timed(render_module, "light_side", "light side: the cache's light samples and tables read")
    timed(passes, "kernel_tables", "light side: the tables expanded for the kernels")
    timed(passes, "place_light_samples", "light side: a new light-sample set")
    timed(passes, "SampleSet", "light side: octrees over the volume samples")
    timed(passes, "_bounced_set", "light side: the bounced samples")
    timed(camera_pass, "caustic_map", "caustics: photons traced and gridded")
    timed(camera_pass, "_gather_caustics", "caustics: gathered at the camera paths' diffuse hits")
    for name in ("closest_surface_hits", "light_hits", "visible", "_interact", "segment_planes"):
        timed(camera_pass, name, "camera paths: hits, shadow rays, interfaces")
    timed(camera_pass, "draw_deflections", "camera paths: the truncated peak's deflections drawn")
    opts = dict(method="pbl", threads=args.threads, cache_dir=args.cache, quiet=True)
    (ROOT / "bench-out").mkdir(exist_ok=True)
    # (two passes: a later pass's new light samples compile kernels of their own)
    render_scene(scene, ROOT / "bench-out" / "profile-warm.exr", RenderOptions(spp=2, resolution=(8, 8), **opts))
    per_render, totals = collections.defaultdict(list), []
    for _ in range(max(1, args.repeat)):
        seconds.clear()
        calls.clear()
        s = render_scene(scene, ROOT / "bench-out" / "profile.exr",
                         RenderOptions(spp=args.spp, resolution=(args.resolution, args.resolution), **opts))
        totals.append(s["time_s"])
        for label in seconds:
            per_render[label].append(seconds[label])
    median = {label: statistics.median(v + [0.0] * (len(totals) - len(v))) for label, v in per_render.items()}
    print(f"{scene.stem} {args.resolution}x{args.resolution}, {args.spp} passes: {statistics.median(totals):.2f} s"
          + (f" (median of {len(totals)} renders, {min(totals):.2f}-{max(totals):.2f})" if len(totals) > 1 else ""))
    for label in sorted(median, key=lambda k: -median[k]):
        print(f"  {median[label]:7.3f} s  {calls[label]:5d} calls  {label}")


if __name__ == "__main__":
    main()
