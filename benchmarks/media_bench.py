#!/usr/bin/env python3
"""The path tracer on the heterogeneous and emissive examples, with the grid of local majorants and with one global
majorant (the cells zeroed: every tentative collision at the largest sigma_t):

    .venv/bin/python benchmarks/media_bench.py [--scenes smoke_glass,fog_table,candle_flame] [--resolution 128]
        [--spp 32] [--repeats 2]

Prints per scene and majorant: seconds (best of --repeats, kernels warm), wavefront steps, ray casts, image mean.
"""

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pbvol_cli import config as C  # noqa: E402
from pbvol_cli.geometry.scene_build import MAJ_DIMS, MED_MAJ, build_scene  # noqa: E402
from pbvol_cli.pipeline.progress import set_threads  # noqa: E402
from pbvol_cli.render.volpath import render_volpath  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="smoke_glass,fog_table,candle_flame")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    set_threads(args.threads)
    for name in args.scenes.split(","):
        path = ROOT / "configs" / f"{name}.toml"
        bs = build_scene(C.load_scene(path), path, (args.resolution, args.resolution))
        render_volpath(bs, 1, 1, 1000, 8, None, 1 << 19, args.threads)  # warm the kernels
        for label in ("cells", "global"):
            if label == "global":
                bs.media[:, MED_MAJ + MAJ_DIMS:MED_MAJ + MAJ_DIMS + 3] = 0
            best, st, img = float("inf"), None, None
            for _ in range(args.repeats):
                t = time.perf_counter()
                img, _, st = render_volpath(bs, args.spp, 1, 1000, 8, None, 1 << 19, args.threads)
                best = min(best, time.perf_counter() - t)
            print(f"{name} {args.resolution}x{args.resolution} {args.spp} spp, {label} majorant: {best:.2f} s, "
                  f"{st['steps']} steps, {st['casts']} casts, mean {img.mean():.4f}", flush=True)


if __name__ == "__main__":
    main()
