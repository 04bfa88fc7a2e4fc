#!/usr/bin/env python3
"""The dipole against the path tracer and the point-based method, on every example scene.

    .venv/bin/python benchmarks/dipole_bench.py [--scenes marble_bunny,wax_sphere,...] [--resolution 64]
        [--ref-spp 4096] [--dipole-spp 1,4] [--pbl-spp 1] [--volpath-spp 64] [--out bench-out] [--threads 2]

For each scene (default: every configs/*.toml), every render in its own process (numba's cache warmed at 8 x 8
first; peak memory per process): a volpath reference of --ref-spp samples as two halves (cached in
.bench-cache/bench-refs; a quarter of the halves' relMSE, the reference's own noise, is subtracted from every
error), then the dipole at each --dipole-spp, pbl at each --pbl-spp and volpath at each --volpath-spp: seconds,
peak MiB, whole-image relMSE against the reference, the image mean over the reference's per channel, and for the
dipole its relMSE against pbl's image of the most passes. Writes <out>/dipole_bench.md and .json.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pbl_bench import RENDER, ROOT, _run, output_args, rel_mse, scenes_with_references  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default=",".join(sorted(p.stem for p in (ROOT / "configs").glob("*.toml"))))
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--dipole-spp", default="1,4")
    ap.add_argument("--pbl-spp", default="1")
    ap.add_argument("--volpath-spp", default="64")
    output_args(ap)
    args = ap.parse_args()
    import numpy as np

    from pbvol_cli.imageio import read_exr

    args.out.mkdir(parents=True, exist_ok=True)
    res = f"{args.resolution}x{args.resolution}"
    rows = []
    for name, scene, ref, noise in scenes_with_references(args, res):
        images = {}
        for method, spps in (("pbl", args.pbl_spp), ("dipole", args.dipole_spp), ("volpath", args.volpath_spp)):
            for spp in (int(v) for v in spps.split(",")):
                out = args.out / f"{name}_{method}_{spp}.exr"
                s = _run(RENDER, scene, out, method, spp, 1, args.threads, res, args.cache)
                img = read_exr(out)[0].astype(float)
                images[method] = img
                row = {"scene": name, "method": method, "spp": spp, "time_s": s["time_s"],
                       "peak_mb": s["peak_memory_mb"], "rel_mse": max(rel_mse(img, ref) - noise, 0.0),
                       "mean_ratio": [round(float(v), 4) for v in img.mean((0, 1)) / np.maximum(ref.mean((0, 1)),
                                                                                                 1e-30)],
                       "ref_noise": noise}
                if method == "dipole" and "pbl" in images:
                    row["rel_mse_vs_pbl"] = rel_mse(img, images["pbl"])
                rows.append(row)
                print(json.dumps(row), flush=True)
    (args.out / "dipole_bench.json").write_text(json.dumps(rows, indent=1))
    lines = ["| scene | method | spp | s | peak MiB | relMSE vs volpath ref | mean / ref (R G B) | relMSE vs pbl |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        vs_pbl = f"{r['rel_mse_vs_pbl']:.4g}" if "rel_mse_vs_pbl" in r else ""
        lines.append(f"| {r['scene']} | {r['method']} | {r['spp']} | {r['time_s']:.2f} | {r['peak_mb']:.0f} | "
                     f"{r['rel_mse']:.4g} | {' '.join(f'{v:.3f}' for v in r['mean_ratio'])} | {vs_pbl} |")
    (args.out / "dipole_bench.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
