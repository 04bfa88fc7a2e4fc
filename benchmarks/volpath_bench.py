#!/usr/bin/env python3
"""Benchmark of the reference path tracer: every example scene, time, samples per second, peak memory.

    .venv/bin/python benchmarks/volpath_bench.py [--spp N] [--threads N] [--scenes a,b]
                                                 [--mitsuba /path/to/mitsuba-venv/bin/python]

Each scene renders in its own process (peak memory is per process), after a 1-spp warm-up in that process so
that numba's cache loading is not timed. With --mitsuba, the wax sphere is also rendered by Mitsuba 3
(llvm_ad_rgb, volpath, benchmarks/mitsuba_reference.py) at the same size, spp and thread count, in the same run,
and the ratio of samples per second is printed, together with the two images' means (Mitsuba's reference for this
scene converges very slowly per pixel: its mean is the quantity that can be compared).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

ONE = r"""
import json, sys
from pathlib import Path
from pbvol_cli.pipeline.render import RenderOptions, render_scene
from pbvol_cli.imageio import read_exr
scene, out, spp, threads = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
render_scene(Path(scene), Path(out), RenderOptions(spp=1, threads=threads, resolution=(16, 16), quiet=True))
s = render_scene(Path(scene), Path(out), RenderOptions(spp=spp or None, threads=threads, quiet=True))
s["mean_rgb"] = [float(x) for x in read_exr(out)[0].mean(axis=(0, 1))]
print(json.dumps(s))
"""


def run_pbvol(scene: Path, spp: int, threads: int, out: Path) -> dict:
    r = subprocess.run([sys.executable, "-c", ONE, str(scene), str(out), str(spp), str(threads)],
                       capture_output=True, text=True, cwd=ROOT)
    if r.returncode != 0:
        raise SystemExit(f"{scene}: render failed:\n{r.stderr}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def run_mitsuba(python: str, spp: int, threads: int, out: Path) -> dict:
    r = subprocess.run([python, str(ROOT / "benchmarks" / "mitsuba_reference.py"), "--scene", "wax_sphere",
                        "--spp", str(spp), "--threads", str(threads), "--integrator", "volpath",
                        "--out", str(out), "--json"], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"mitsuba failed:\n{r.stderr}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", type=int, default=0, help="samples per pixel (default: each scene's own)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--scenes", default="", help="comma list of config names (default: all in configs/)")
    ap.add_argument("--mitsuba", help="python of a venv with mitsuba installed: also time Mitsuba 3 on the wax sphere")
    ap.add_argument("--mitsuba-spp", type=int, default=64)
    args = ap.parse_args()
    names = [s for s in args.scenes.split(",") if s] or sorted(p.stem for p in (ROOT / "configs").glob("*.toml"))
    tmp = Path(tempfile.mkdtemp(prefix="pbvol-bench-"))
    print(f"{'scene':<14} {'size':>9} {'spp':>5} {'time s':>8} {'M samples/s':>12} {'peak MiB':>9}")
    for name in names:
        s = run_pbvol(ROOT / "configs" / f"{name}.toml", args.spp, args.threads, tmp / f"{name}.exr")
        w, h = s["resolution"]
        print(f"{name:<14} {f'{w}x{h}':>9} {s['spp']:>5} {s['time_s']:>8.2f} {s['samples_per_second'] / 1e6:>12.3f} "
              f"{s['peak_memory_mb']:>9.0f}")
    if args.mitsuba:
        spp = args.mitsuba_spp
        ours = run_pbvol(ROOT / "configs" / "wax_sphere.toml", spp, args.threads, tmp / "wax_pbvol.exr")
        mi = run_mitsuba(args.mitsuba, spp, args.threads, tmp / "wax_mitsuba.exr")
        ratio = ours["samples_per_second"] / mi["samples_per_second"]
        print(f"\nwax sphere 256x256, {spp} spp, {args.threads} threads:")
        print(f"  pbvol volpath        {ours['time_s']:7.2f} s  {ours['samples_per_second'] / 1e6:.3f} M samples/s  "
              f"mean RGB {[round(x, 5) for x in ours['mean_rgb']]}")
        print(f"  Mitsuba 3 volpath    {mi['time_s']:7.2f} s  {mi['samples_per_second'] / 1e6:.3f} M samples/s  "
              f"mean RGB {[round(x, 5) for x in mi['mean_rgb']]}  ({mi['variant']})")
        print(f"  speed ratio pbvol / Mitsuba: {ratio:.2f}")


if __name__ == "__main__":
    main()
