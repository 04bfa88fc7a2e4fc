#!/usr/bin/env python3
"""The marching methods (the ray marcher, the VPLs) against the path tracer on the heterogeneous and emissive
examples.

    .venv/bin/python benchmarks/marching_bench.py [--scenes smoke_glass,fog_table,candle_flame] [--resolution 128]
        [--ref-spp 1024] [--raymarch-spp 1,4,16] [--vpl-spp 1,4,16] [--volpath-spp 4,16,64] [--pbl-spp ""]
        [--out bench-out] [--threads 2]

Per scene, every render in its own process (kernels warmed at 8 x 8 first; peak memory per process): two volpath
references of --ref-spp samples each (seeds 101, 102), one of all the light and one restricted to `--orders 0,1`
(what the ray marcher models: no multiple scattering), cached in .bench-cache/bench-refs; then raymarch, vpl,
volpath and (given --pbl-spp, on homogeneous scenes) pbl at each count: seconds, peak MiB, whole-image relMSE
against both references. Writes <out>/marching_bench.md and .json and, where matplotlib is installed,
<out>/marching_<scene>.png (relMSE against time).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pbl_bench import ROOT, _run, _scene_hash, output_args, rel_mse  # noqa: E402
from pbl_speed import _plot  # noqa: E402

RENDER = r"""
import json, sys
from pathlib import Path
from pbvol_cli.pipeline.render import RenderOptions, render_scene
scene, out, method, spp, seed, threads, res, cache, orders = sys.argv[1:10]
res = tuple(int(v) for v in res.split("x"))
kw = dict(method=method, threads=int(threads), cache_dir=Path(cache), quiet=True, orders=orders or None)
warm = Path(out).with_name(Path(out).stem + ".warm-up.exr")
render_scene(Path(scene), warm, RenderOptions(spp=1, resolution=(8, 8), **kw))  # warm numba's cache
warm.unlink()
s = render_scene(Path(scene), Path(out), RenderOptions(spp=int(spp), seed=int(seed), resolution=res, **kw))
print(json.dumps(s))
"""


def reference(scene: Path, res: str, spp: int, orders: str, threads: int, cache: Path):
    """volpath at spp samples (seed 101; restricted to orders, "" for all), cached by the scene's hash."""
    from pbvol_cli.imageio import read_exr

    refdir = cache / "bench-refs"
    refdir.mkdir(parents=True, exist_ok=True)
    out = refdir / f"{scene.stem}_{res}_{spp}spp_orders{orders.replace(',', '') or 'all'}.exr"
    if out.exists() and read_exr(out)[1].get("scene_hash") != _scene_hash(scene, res):
        out.unlink()
    if not out.exists():
        _run(RENDER, scene, out, "volpath", spp, 101, threads, res, cache, orders)
    return read_exr(out)[0].astype(float)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="smoke_glass,fog_table,candle_flame")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--raymarch-spp", default="1,4,16")
    ap.add_argument("--vpl-spp", default="1,4,16")
    ap.add_argument("--volpath-spp", default="4,16,64")
    ap.add_argument("--pbl-spp", default="")
    output_args(ap)
    args = ap.parse_args()
    from pbvol_cli.imageio import read_exr

    args.out.mkdir(parents=True, exist_ok=True)
    res = f"{args.resolution}x{args.resolution}"
    rows = []
    for name in args.scenes.split(","):
        scene = ROOT / "configs" / f"{name}.toml"
        full = reference(scene, res, args.ref_spp, "", args.threads, args.cache)
        single = reference(scene, res, args.ref_spp, "0,1", args.threads, args.cache)
        curves = {}
        for method, spps in (("raymarch", args.raymarch_spp), ("vpl", args.vpl_spp), ("volpath", args.volpath_spp),
                             ("pbl", args.pbl_spp)):
            for spp in (int(v) for v in spps.split(",") if v):
                out = args.out / f"{name}_{method}_{spp}.exr"
                s = _run(RENDER, scene, out, method, spp, 1, args.threads, res, args.cache, "")
                img = read_exr(out)[0].astype(float)
                rows.append({"scene": name, "method": method, "spp": spp, "time_s": round(s["time_s"], 3),
                             "peak_mb": round(s["peak_memory_mb"]), "rel_mse": rel_mse(img, full),
                             "rel_mse_orders01": rel_mse(img, single),
                             "mean_ratio": round(float(img.mean() / full.mean()), 4)})
                curves.setdefault(method, []).append((rows[-1]["time_s"], rows[-1]["rel_mse"], spp))
                print(json.dumps(rows[-1]), flush=True)
        _plot(args.out / f"marching_{name}.png", name, curves, 1e-2)
    (args.out / "marching_bench.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = [f"{res}, references volpath {args.ref_spp} spp (all light; `--orders 0,1`), {args.threads} threads", "",
             "| scene | method | spp | time (s) | peak MiB | relMSE vs all | relMSE vs orders 0,1 | mean / ref |",
             "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['scene']} | {r['method']} | {r['spp']} | {r['time_s']:.2f} | {r['peak_mb']} | "
              f"{r['rel_mse']:.4g} | {r['rel_mse_orders01']:.4g} | {r['mean_ratio']:.3f} |" for r in rows]
    (args.out / "marching_bench.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
