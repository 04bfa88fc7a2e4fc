#!/usr/bin/env python3
"""pbl settings side by side on one scene against a volpath reference, over several seeds.

    .venv/bin/python benchmarks/pbl_seeds.py --scene oil_sphere [--resolution 256] [--spp 1] [--seeds 1,2,3,4]
        [--ref-spp 2048] --set '' --set 'segments_per_beam=8,surface_samples=10000' [--threads 2] [--cache DIR]

Each --set is one variant: comma-separated [render.pbl] overrides ('' : the scene's own settings). Each variant
renders the scene once per seed in this process, after an 8 x 8 render of the same seed (its light samples are
then cached and its kernels compiled: the timed render is warm), and prints the relMSE against the reference per
seed, then the mean time per render, the relMSE (mean, least and largest over the seeds, the reference's own noise
subtracted), error x time and the relMSE of the seeds' mean image over 8 x 8 blocks (noise falls there, a bias
stays: an upper estimate of the variant's bias). The reference is benchmarks/pbl_speed.py's (two volpath halves,
cached under --cache). pbl_ab.py compares noise without a reference; this compares error, bias included.
Pass p of a render takes light-sample set seed + p: with --spp N, seeds fewer than N apart share sets (seeds 2, 3, 4
at 8 passes share six of their eight), so their spread understates the light side's; take seeds N apart for
independent renders.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def main():
    import numpy as np

    from pbl_bench import block_rel_mse, pbl_overrides, reference, rel_mse, with_pbl

    from pbvol_cli.imageio import read_exr
    from pbvol_cli.pipeline.render import RenderOptions, render_scene

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", required=True, help="a config name in configs/")
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--spp", type=int, default=1, help="passes per render")
    ap.add_argument("--seeds", default="1,2,3,4")
    ap.add_argument("--ref-spp", type=int, default=2048)
    ap.add_argument("--set", action="append", default=[], dest="variants")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=ROOT / ".bench-cache")
    args = ap.parse_args()
    path = ROOT / "configs" / f"{args.scene}.toml"
    res = f"{args.resolution}x{args.resolution}"
    ref, ref_noise = reference(path, res, args.ref_spp, args.threads, args.cache)
    seeds = [int(s) for s in args.seeds.split(",")]
    tmp = Path(tempfile.mkdtemp())
    opts = dict(method="pbl", threads=args.threads, cache_dir=args.cache, quiet=True)
    for i, variant in enumerate(args.variants or [""]):
        spath = with_pbl(path, tmp / f"variant{i}", pbl_overrides(variant))
        times, errors, images = [], [], []
        for seed in seeds:
            render_scene(spath, tmp / "warm.exr", RenderOptions(spp=1, seed=seed, resolution=(8, 8), **opts))
            out = tmp / f"s{seed}.exr"
            s = render_scene(spath, out, RenderOptions(spp=args.spp, seed=seed,
                                                      resolution=(args.resolution, args.resolution), **opts))
            images.append(read_exr(out)[0].astype(np.float64))
            times.append(s["time_s"])
            errors.append(rel_mse(images[-1], ref) - ref_noise)
        t, e = float(np.mean(times)), float(np.mean(errors))
        print("  per seed: " + ", ".join(f"{sd} {er:.4f}" for sd, er in zip(seeds, errors)))
        print(f"{args.scene} {variant or '(scene settings)'}: {t:.2f} s per render, relMSE {e:.5f} "
              f"({min(errors):.5f}-{max(errors):.5f}), error x time {e * t:.5f}, the seeds' mean over 8 x 8 blocks "
              f"{block_rel_mse(sum(images) / len(images), ref):.6f}", flush=True)


if __name__ == "__main__":
    main()
