#!/usr/bin/env python3
"""`volpath` against Mitsuba 3 at equal error: time per sample, variance per sample, and their product.

    .venv/bin/python benchmarks/volpath_mitsuba.py --mitsuba /path/to/mitsuba-venv/bin/python
        [--scenes oil_large,wax_large] [--resolution 256] [--spp 64] [--threads 2] [--variant llvm_ad_rgb]
        [--integrators volpath,volpathmis]

The scenes: a radius-5 sphere of the paper's oil (or wax) behind eta 1.5, lit by a
radius-3 sphere light 17 units away (the radiance of configs/oil_sphere.toml's radius-0.5 light scaled to the same
power) and a dim sky. Each is written as a pbvol scene, exported with `pbvol export-mitsuba` (JSON) and rendered
by both renderers twice, with two seeds, after a warm-up render (JIT, kernel cache) that is not timed.

Variance per sample, v: the relMSE between the two seeds' images (pbvol compare's, each against the other) / 2 x
spp; two independent renders differ by twice one's variance. The time to a given error is proportional to
t x v (t: seconds per sample per pixel), so the speed-up at equal error is (t v)_Mitsuba / (t v)_pbvol, against
Mitsuba's best integrator. The two means are printed as a check that both render the same scene. Peak memory:
pbvol's `volpath` at 512 x 512. Results in bench-out/volpath_mitsuba.md and .json.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
from pbl_bench import output_args  # noqa: E402

LIGHT_RADIUS = 3.0


def scene_data(name: str) -> dict:
    """The scene from configs/oil_sphere.toml (or wax_sphere.toml): the light grown to radius 3, its power kept,
    the boundary's eta 1.5."""
    import tomllib

    base = {"oil_large": "oil_sphere", "wax_large": "wax_sphere"}[name]
    data = tomllib.loads((ROOT / "configs" / f"{base}.toml").read_text())
    for light in data["lights"]:
        if light["type"] == "sphere":
            light["radiance"] = light["radiance"] * (light["radius"] / LIGHT_RADIUS) ** 2
            light["radius"] = LIGHT_RADIUS
    for shape in data["shapes"]:
        if shape.get("interface") == "dielectric":
            shape["eta"] = 1.5
    if not any(light["type"] == "environment" for light in data["lights"]):
        data["lights"].append({"type": "environment", "radiance": 0.02})
    return data


def pbvol_render(scene: Path, out: Path, spp: int, seed: int, threads: int, resolution: int) -> dict:
    r = subprocess.run([str(ROOT / ".venv" / "bin" / "pbvol"), "render", str(scene), "-o", str(out), "--spp",
                        str(spp), "--seed", str(seed), "--threads", str(threads), "--resolution",
                        f"{resolution}x{resolution}", "--json", "-q"], capture_output=True, text=True, cwd=ROOT)
    if r.returncode != 0:
        raise SystemExit(f"pbvol render {scene} failed:\n{r.stderr}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def mitsuba_render(python: str, scene_json: Path, out: Path, spp: int, seed: int, threads: int, variant: str,
                   integrator: str) -> dict:
    r = subprocess.run([python, str(ROOT / "benchmarks" / "mitsuba_reference.py"), "--scene-json", str(scene_json),
                        "--spp", str(spp), "--seed", str(seed), "--threads", str(threads), "--variant", variant,
                        "--integrator", integrator, "--out", str(out), "--json"], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"mitsuba failed:\n{r.stderr}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def per_sample(a: Path, b: Path, spp: int) -> tuple[float, list]:
    """(variance per sample as relMSE, the two images' mean RGB)."""
    import numpy as np

    from pbvol_cli.imageio import read_exr
    from pbvol_cli.pipeline.compare import image_metrics

    x, y = read_exr(a)[0], read_exr(b)[0]
    rel = 0.5 * (image_metrics(x, y)["rel_mse"] + image_metrics(y, x)["rel_mse"])
    mean = ((x.astype(np.float64) + y) / 2).reshape(-1, 3).mean(axis=0)
    return rel / 2 * spp, [round(float(c), 5) for c in mean]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mitsuba", required=True, help="python of a venv with mitsuba installed")
    ap.add_argument("--scenes", default="oil_large,wax_large")
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--integrators", default="volpath,volpathmis")
    output_args(ap)
    args = ap.parse_args()
    import tomli_w

    from pbvol_cli.pipeline.export_mitsuba import export_mitsuba

    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in args.scenes.split(","):
        scene = args.out / f"vm_{name}.toml"
        scene.write_text(tomli_w.dumps(scene_data(name)))
        scene_json = args.out / f"vm_{name}.json"
        export_mitsuba(scene, scene_json, resolution=(args.resolution, args.resolution))
        row = {"scene": name, "spp": args.spp, "resolution": args.resolution}
        pbvol_render(scene, args.out / "vm_warm.exr", 1, 9, args.threads, 16)
        times = []
        for seed in (1, 2):
            s = pbvol_render(scene, args.out / f"vm_{name}_pbvol_{seed}.exr", args.spp, seed, args.threads,
                             args.resolution)
            times.append(s["time_s"] / args.spp)
        v, mean = per_sample(*(args.out / f"vm_{name}_pbvol_{s}.exr" for s in (1, 2)), args.spp)
        row["pbvol"] = {"s_per_spp": sum(times) / 2, "var_per_sample": v, "mean": mean}
        for integ in args.integrators.split(","):
            times = []
            for seed in (1, 2):
                m = mitsuba_render(args.mitsuba, scene_json, args.out / f"vm_{name}_{integ}_{seed}.exr", args.spp,
                                   seed, args.threads, args.variant, integ)
                times.append(m["time_s"] / args.spp)
            v, mean = per_sample(*(args.out / f"vm_{name}_{integ}_{s}.exr" for s in (1, 2)), args.spp)
            row[integ] = {"s_per_spp": sum(times) / 2, "var_per_sample": v, "mean": mean}
        best = min(args.integrators.split(","), key=lambda k: row[k]["s_per_spp"] * row[k]["var_per_sample"])
        ours = row["pbvol"]["s_per_spp"] * row["pbvol"]["var_per_sample"]
        row["best_mitsuba"] = best
        row["speedup_at_equal_error"] = row[best]["s_per_spp"] * row[best]["var_per_sample"] / ours
        peak = pbvol_render(scene, args.out / "vm_512.exr", 4, 1, args.threads, 512)["peak_memory_mb"]
        row["pbvol_peak_mb_512"] = peak
        rows.append(row)
        print(json.dumps(row), flush=True)
    (args.out / "volpath_mitsuba.json").write_text(json.dumps(rows, indent=1))
    integs = args.integrators.split(",")
    lines = ["| scene | renderer | ms per spp | variance per sample (relMSE) | t × v | mean R G B |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        for k in ("pbvol", *integs):
            d = r[k]
            label = "pbvol volpath" if k == "pbvol" else f"Mitsuba {k} ({args.variant})"
            lines.append(f"| {r['scene']} | {label} | {1000 * d['s_per_spp']:.1f} | {d['var_per_sample']:.4g} | "
                         f"{d['s_per_spp'] * d['var_per_sample']:.4g} | {' '.join(map(str, d['mean']))} |")
        lines.append(f"| {r['scene']} | **speed-up at equal error against {r['best_mitsuba']}** | | | "
                     f"**{r['speedup_at_equal_error']:.2f}×** | pbvol peak at 512²: {r['pbvol_peak_mb_512']:.0f} MiB |")
    (args.out / "volpath_mitsuba.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
