#!/usr/bin/env python3
"""Distributed rendering's efficiency: one scene rendered by one process and on local Dask clusters of 1 and 2
worker processes, timed by the command line, with the images checked equal bit for bit.

    .venv/bin/python benchmarks/dask_bench.py [--scenes oil_sphere:volpath:1024,wax_sphere:pbl:4,wax_sphere:pbl:4:8]
                                              [--resolution 128] [--workers 1,2]

A scene is config:method:spp[:surface_paths] (the last: pbl's camera paths per pixel, fixed, written into a copy
of the config under the output folder; configs with relative mesh paths cannot take it).

Every run uses all of the machine's cores (one process: threads = cores; local[N]: N processes of cores / N
threads), so efficiency = one process's time / the cluster's. Each is also timed at 1 sample (pass): that is
what starting a process (and a cluster's workers), loading the compiled kernels and the cache cost, which a
long-lived cluster pays once; the marginal efficiency is (one process's time - its 1-sample time) / (the
cluster's - its 1-sample time), the throughput once running. With pbl's automatic camera paths (the default)
the shards pick their own path counts, so the image differs from one process's (documented in README, `pbvol
merge`); the table says so. Results in bench-out/dask_bench.md and .json.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
from pbl_bench import output_args  # noqa: E402


def pbvol(*args) -> float:
    """Seconds a `pbvol render` takes, from the command line."""
    t = time.perf_counter()
    r = subprocess.run([str(ROOT / ".venv" / "bin" / "pbvol"), "render", *map(str, args), "-q"],
                       capture_output=True, text=True, cwd=ROOT)
    if r.returncode != 0:
        raise SystemExit(f"pbvol render {' '.join(map(str, args))} failed:\n{r.stderr}")
    return time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="oil_sphere:volpath:1024,wax_sphere:pbl:4,wax_sphere:pbl:4:8",
                    help="comma list of config:method:spp[:surface_paths]")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--workers", default="1,2")
    output_args(ap)
    args = ap.parse_args()
    import numpy as np

    from pbvol_cli import config as C
    from pbvol_cli.imageio import read_exr

    args.out.mkdir(parents=True, exist_ok=True)
    res = f"{args.resolution}x{args.resolution}"
    rows = []
    for item in args.scenes.split(","):
        name, method, spp, *paths = item.split(":")
        scene = ROOT / "configs" / f"{name}.toml"
        if paths:
            import tomllib

            import tomli_w

            data = tomllib.loads(scene.read_text())
            data.setdefault("render", {}).setdefault("pbl", {})["surface_paths"] = int(paths[0])
            scene = args.out / f"dask_{name}_paths{paths[0]}.toml"
            scene.write_text(tomli_w.dumps(data))
            name = f"{name}_paths{paths[0]}"
        common = [scene, "--method", method, "--resolution", res, "--cache-dir", args.cache]
        pbvol(*common, "--spp", 1, "-o", args.out / "dask_warm.exr")  # compiled kernels, cached samples
        one1 = pbvol(*common, "--spp", 1, "--threads", args.threads, "-o", args.out / "dask_warm.exr")
        one = pbvol(*common, "--spp", spp, "--threads", args.threads, "-o", args.out / f"dask_{name}_one.exr")
        auto = method == "pbl" and C.load_scene(scene).render.pbl.surface_paths == 0
        row = {"scene": name, "method": method, "spp": int(spp), "one_process_s": one, "one_process_1_s": one1,
               "auto_paths": auto}
        for n in map(int, args.workers.split(",")):
            startup = pbvol(*common, "--spp", 1, "--dask", f"local[{n}]", "-o", args.out / "dask_warm.exr")
            out = args.out / f"dask_{name}_{n}.exr"
            t = pbvol(*common, "--spp", spp, "--dask", f"local[{n}]", "-o", out)
            same = bool(np.array_equal(read_exr(out)[0], read_exr(args.out / f"dask_{name}_one.exr")[0]))
            row[f"local{n}"] = {"s": t, "startup_s": startup, "efficiency": one / t, "same_image": same,
                                "marginal_efficiency": (one - one1) / max(t - startup, 1e-9)}
            print(name, method, f"local[{n}]", f"{t:.1f} s against {one:.1f} s; at 1 sample {startup:.1f} s against "
                  f"{one1:.1f} s;", "same image" if same else "images differ", flush=True)
        rows.append(row)
    (args.out / "dask_bench.json").write_text(json.dumps(rows, indent=1))
    lines = ["| scene | method | spp | one process s (1 sample) | " + " | ".join(
        f"local[{n}] s (1 sample) | efficiency (marginal)" for n in args.workers.split(",")) + " | images |",
        "|---|---|---|---|" + "---|---|" * len(args.workers.split(",")) + "---|"]
    for r in rows:
        cells = []
        for n in args.workers.split(","):
            d = r[f"local{n}"]
            cells += [f"{d['s']:.1f} ({d['startup_s']:.1f})",
                      f"{d['efficiency']:.2f} ({d['marginal_efficiency']:.2f})"]
        same = all(r[f"local{n}"]["same_image"] for n in args.workers.split(","))
        what = "identical" if same else ("differ: auto camera paths per shard" if r["auto_paths"] else "DIFFER")
        lines.append(f"| {r['scene']} | {r['method']} | {r['spp']} | {r['one_process_s']:.1f} "
                     f"({r['one_process_1_s']:.1f}) | " + " | ".join(cells) + f" | {what} |")
    (args.out / "dask_bench.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
