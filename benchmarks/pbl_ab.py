#!/usr/bin/env python3
"""pbl settings side by side on one scene: time, noise and image means, without a reference.

    .venv/bin/python benchmarks/pbl_ab.py --scene wax_sphere [--resolution 128] [--spp 1] [--seeds 11,12]
        --set cache_cell=0 --set cache_cell=0.5 [--set 'kmax=2,cache_cell=0.5'] [--threads 2] [--cache DIR]

Each --set is one variant: comma-separated [render.pbl] overrides (numbers, true/false or words). Each variant
renders the scene once per seed (each in this process after a warm-up render of the same size, so that compiling
and loading kernels are not timed) and
prints the mean time per render, the noise (relMSE between two seeds' images / 2: one image's variance in relMSE
units, where the method is unbiased) and the image and layer means and noise over the seeds (each layer's on its own
scale, then on the image's: the second says which layer the image's noise comes from): a variant that keeps the
means and lowers noise x time is the better one.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def main():
    import numpy as np
    import tomli_w

    from pbl_bench import files_made_absolute, pbl_overrides

    from pbvol_cli.imageio import read_exr, read_layers
    from pbvol_cli.pipeline.render import RenderOptions, render_scene

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", required=True, help="a config name in configs/ or a scene file")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--spp", type=int, default=1)
    ap.add_argument("--seeds", default="11,12")
    ap.add_argument("--set", action="append", default=[], dest="variants")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=ROOT / ".bench-cache")
    args = ap.parse_args()
    path = Path(args.scene) if args.scene.endswith(".toml") else ROOT / "configs" / f"{args.scene}.toml"
    base = files_made_absolute(tomllib.loads(path.read_text()), path.parent)
    seeds = [int(s) for s in args.seeds.split(",")]
    tmp = Path(tempfile.mkdtemp())
    res = (args.resolution, args.resolution)
    for variant in args.variants or [""]:
        over = pbl_overrides(variant)
        scene = {**base, "render": {**base.get("render", {})}}
        scene["render"]["pbl"] = {**scene["render"].get("pbl", {}), **over}
        spath = tmp / path.name
        spath.write_bytes(tomli_w.dumps(scene).encode())
        opts = dict(method="pbl", threads=args.threads, cache_dir=args.cache, quiet=True)
        # warm-up at the measured size and up to 3 passes (the automatic paths and shares start at the third): an
        # 8 x 8 one left kernels for the first timed render to load (the first variant read up to 35 % slow)
        render_scene(spath, tmp / "warm.exr", RenderOptions(spp=min(args.spp, 3), seed=0, resolution=res, **opts))
        imgs, times, layers, planes = [], [], [], []
        for seed in seeds:
            out = tmp / f"o{seed}.exr"
            s = render_scene(spath, out, RenderOptions(spp=args.spp, seed=seed, resolution=res, **opts))
            times.append(s["time_s"])
            imgs.append(read_exr(out)[0].astype(np.float64))
            planes.append({k: v.astype(np.float64) for k, v in read_layers(out).items()})
            layers.append({k: float(v.mean()) for k, v in planes[-1].items()})
        mean = sum(imgs) / len(imgs)

        def spread(images):
            # relMSE between two seeds' images (their mean as reference) halved: one image's variance
            return float(np.mean([((a - b) ** 2 / ((0.5 * (a + b)) ** 2 + 0.01)).mean()
                                  for i, a in enumerate(images) for b in images[i + 1:]])) / 2

        def share(layer, images):
            # a layer's seed-to-seed spread over the image's own scale (its sum over the layers is the image's
            # noise less the layers' covariances): which layer the noise comes from
            return float(np.mean([((a - b) ** 2 / ((0.5 * (ia + ib)) ** 2 + 0.01)).mean()
                                  for i, (a, ia) in enumerate(zip(layer, images))
                                  for b, ib in zip(layer[i + 1:], images[i + 1:])])) / 2

        noise = spread(imgs)
        t = float(np.mean(times))
        print(f"{path.stem} {variant or '(scene settings)'}: {t:.2f} s per render, noise {noise:.5f}, "
              f"noise x time {noise * t:.4f}, image mean {np.round(mean.mean((0, 1)), 6).tolist()}")
        print("    layer means " + ", ".join(f"{k} {np.mean([L[k] for L in layers]):.6f}" for k in layers[0]))
        print("    layer noise " + ", ".join(f"{k} {spread([P[k] for P in planes]):.6f}" for k in planes[0]))
        print("    of the image's noise " + ", ".join(f"{k} {share([P[k] for P in planes], imgs):.6f}"
                                                    for k in planes[0]))


if __name__ == "__main__":
    main()
