#!/usr/bin/env python3
"""The point-based method's speed against the path tracer: a pass's cost, and error against time.

    .venv/bin/python benchmarks/pbl_speed.py [--scenes oil_sphere,wax_sphere,wine_glass] [--resolution 256]
        [--pbl-spp 1,2,4,8] [--volpath-spp 16,64,256,1024] [--ref-spp 16384] [--target 1e-3] [--memory-check]
        [--out bench-out] [--threads 2] [--cache DIR] [--pass-only [--repeat 3]]
        [--mitsuba PYTHON --mitsuba-spp 64,256,1024 --mitsuba-integrators volpath,volpathmis] [--reuse-curves JSON]
        [--set k=v ...]

For each scene, every render in its own process (each warms numba's cache at 8x8 first, so that compiling is not
timed; peak memory is per process):
  1. a volpath reference of --ref-spp samples as two halves (cached, like benchmarks/pbl_bench.py; a quarter of the
     halves' relMSE estimates the reference's own noise, subtracted from every error below);
  2. pass cost: pbl at 1 spp against volpath at 16 spp, the ratio of their times (warm, same run);
  3. error against time: pbl at each --pbl-spp, volpath at each --volpath-spp: (seconds, relMSE) per render, and
     the time each method needs to reach --target (log-log interpolation between renders; volpath beyond its last
     render extrapolated as relMSE ~ 1/spp, pbl not extrapolated: it is biased);
  4. with --memory-check, pbl's peak memory at 512 x 512, 1 spp;
  5. with --reuse-curves, the volpath and Mitsuba curves of an earlier run's pbl_speed.json instead (they do not
     depend on pbl's code; the reference must be the same, as it is from the cache);
  6. with --pass-only, step 2 alone (no reference), --repeat rounds of it after one not counted, their medians:
     <out>/pass_cost.md;
  6a. with --set k=v, pbl renders the scene with that [render.pbl] setting (a copy in <out>/scenes/);
  6b. pbl's time at each of its renders over the time volpath takes to the same error (a second table), and pbl's
     relMSE over 8 x 8 blocks at its longest render (an upper estimate of its bias: noise falls 64-fold there);
  7. with --mitsuba (the python of a venv with mitsuba installed), Mitsuba 3's error against time for each of
     --mitsuba-integrators on the scene as `pbvol export-mitsuba` writes it (benchmarks/mitsuba_reference.py, its
     JIT warm-up not timed), against the same reference, and pbl's speed-up to --target over the best of them
     (extrapolated like volpath's).
Writes <out>/pbl_speed.md (the table), <out>/pbl_speed.json and, where matplotlib is installed
(`pip install matplotlib`), <out>/pbl_speed_<scene>.png, the error-against-time curves.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pbl_bench import (RENDER, ROOT, _run, block_rel_mse, pbl_overrides, rel_mse,  # noqa: E402
                       scenes_with_references, with_pbl)


def time_to(points: list[tuple[float, float]], target: float, extrapolate: bool) -> float | None:
    """Seconds to reach relMSE `target` from (seconds, relMSE) points, by log-log interpolation; beyond the last
    point, and before the first, relMSE ~ 1 / time where extrapolate (an unbiased method), else None (before the
    first: its time)."""
    pts = sorted(p for p in points if p[1] > 0)
    for (t0, e0), (t1, e1) in zip(pts, pts[1:]):
        if e0 >= target >= e1:
            a = math.log(e0 / target) / math.log(e0 / e1) if e0 != e1 else 0.0
            return math.exp(math.log(t0) + a * math.log(t1 / t0))
    if pts and pts[0][1] <= target:  # (already below at its first point: an unbiased method got there sooner)
        return pts[0][0] * pts[0][1] / target if extrapolate else pts[0][0]
    if extrapolate and pts:
        t, e = pts[-1]
        return t * e / target
    return None


def render(scene: Path, method: str, spp: int, seed: int, res: str, threads: int, cache: Path, out: Path):
    from pbvol_cli.imageio import read_exr

    s = _run(RENDER, scene, out, method, spp, seed, threads, res, cache)
    return s, read_exr(out)[0].astype(float)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="oil_sphere,wax_sphere,wine_glass")
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--pbl-spp", default="1,2,4,8")
    ap.add_argument("--volpath-spp", default="16,64,256,1024")
    ap.add_argument("--ref-spp", type=int, default=16384)
    ap.add_argument("--target", type=float, default=1e-3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=ROOT / ".bench-cache")
    ap.add_argument("--out", type=Path, default=ROOT / "bench-out")
    ap.add_argument("--memory-check", action="store_true")
    ap.add_argument("--mitsuba", help="python of a venv with mitsuba installed: add Mitsuba 3's curves")
    ap.add_argument("--mitsuba-spp", default="64,256,1024")
    ap.add_argument("--mitsuba-integrators", default="volpath,volpathmis")
    ap.add_argument("--mitsuba-variant", default="llvm_ad_rgb")
    ap.add_argument("--repeat", type=int, default=3, help="with --pass-only: rounds of the two renders (medians)")
    ap.add_argument("--pass-only", action="store_true", help="only the pass cost: pbl at 1 pass against volpath at "
                    "16 spp for each scene, no reference (writes <out>/pass_cost.md)")
    ap.add_argument("--reuse-curves", type=Path, help="an earlier run's pbl_speed.json: its volpath and Mitsuba "
                    "curves of the same scene and resolution are taken as they are (pbl is rendered anew)")
    ap.add_argument("--set", action="append", default=[], dest="overrides",
                    help="k=v: a [render.pbl] setting for pbl's renders (repeatable; volpath renders the scene as is)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    args.pbl = pbl_overrides(",".join(args.overrides))
    res = f"{args.resolution}x{args.resolution}"
    if args.pass_only:
        pass_cost(args, res)
        return
    rows = []
    for name, scene, ref, ref_noise in scenes_with_references(args, res):
        curves, blocks = {}, None
        reused = reused_curves(args.reuse_curves, name, res)
        for method, spps in (("pbl", args.pbl_spp), ("volpath", args.volpath_spp)):
            if method in reused:
                curves[method] = reused[method]
                continue
            pts = []
            for spp in (int(v) for v in spps.split(",")):
                s, img = render(with_pbl(scene, args.out / "scenes", args.pbl) if method == "pbl" else scene, method,
                                spp, 1, res, args.threads, args.cache, args.out / f"{name}_{method}.exr")
                pts.append((s["time_s"], max(rel_mse(img, ref) - ref_noise, 1e-12), spp, s["peak_memory_mb"]))
                print(f"{name} {method} {spp} spp: {s['time_s']:.2f} s, relMSE {pts[-1][1]:.5f}", flush=True)
            curves[method] = pts
            if method == "pbl":  # the last (longest) render's error over 8 x 8 blocks: its bias, at most
                blocks = (pts[-1][2], block_rel_mse(img, ref))
        if args.mitsuba:
            curves.update(mitsuba_curves(args, name, scene, ref, ref_noise))
        curves.update({k: v for k, v in reused.items() if k.startswith("mitsuba") and k not in curves})
        t_pass = next(p[0] for p in curves["pbl"] if p[2] == 1) if any(p[2] == 1 for p in curves["pbl"]) else None
        t_vp16 = next((p[0] for p in curves["volpath"] if p[2] == 16), None)
        tp = time_to([p[:2] for p in curves["pbl"]], args.target, extrapolate=False)
        tv = time_to([p[:2] for p in curves["volpath"]], args.target, extrapolate=True)
        row = {"scene": name, "resolution": res, "reference_noise": ref_noise, "curves": curves,
               "pass_s": t_pass, "volpath16_s": t_vp16,
               "pass_over_volpath16": t_pass / t_vp16 if t_pass and t_vp16 else None,
               "pbl_to_target_s": tp, "volpath_to_target_s": tv,
               "speed_up_at_target": tv / tp if tp and tv else None,
               "pbl_block_rel_mse": blocks}
        mitsuba = {k: time_to([p[:2] for p in v], args.target, extrapolate=True) for k, v in curves.items()
                   if k.startswith("mitsuba")}
        if mitsuba:
            best = min(mitsuba, key=lambda k: mitsuba[k] or math.inf)
            row.update(mitsuba_best=best, mitsuba_to_target_s=mitsuba[best],
                       speed_up_over_mitsuba=mitsuba[best] / tp if tp and mitsuba[best] else None)
        if args.memory_check:
            s, _ = render(with_pbl(scene, args.out / "scenes", args.pbl), "pbl", 1, 1, "512x512", args.threads,
                          args.cache, args.out / f"{name}_512.exr")
            row["pbl_512_peak_mb"] = s["peak_memory_mb"]
        rows.append(row)
        _plot(args.out / f"pbl_speed_{name}.png", name, curves, args.target, row["reference_noise"])
    (args.out / "pbl_speed.json").write_text(json.dumps(rows, indent=1))
    lines = [f"| scene | pass s | volpath 16 spp s | pass / volpath 16 | pbl s to {args.target:g} | "
             f"volpath s to {args.target:g} | speed-up | pbl 512² MiB | Mitsuba's best s to {args.target:g} | "
             "pbl's speed-up over it |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        def f(v, fmt="{:.2f}"):
            return fmt.format(v) if v is not None else "—"
        lines.append(f"| {r['scene']} | {f(r['pass_s'])} | {f(r['volpath16_s'])} "
                     f"| {f(r['pass_over_volpath16'], '{:.1f}×')} | {f(r['pbl_to_target_s'], '{:.1f}')} "
                     f"| {f(r['volpath_to_target_s'], '{:.1f}')} "
                     f"| {f(r['speed_up_at_target'], '{:.1f}×')} | {f(r.get('pbl_512_peak_mb'), '{:.0f}')} "
                     f"| {f(r.get('mitsuba_to_target_s'), '{:.1f}')} {r.get('mitsuba_best', '')} "
                     f"| {f(r.get('speed_up_over_mitsuba'), '{:.1f}×')} |")
    table = "\n".join(lines) + "\n\n" + equal_error_table(rows)
    floors = [f"- {r['scene']}: {r['pbl_block_rel_mse'][1]:.5f} at {r['pbl_block_rel_mse'][0]} passes"
              for r in rows if r.get("pbl_block_rel_mse")]
    if floors:
        table += ("\n\npbl's relMSE over 8 x 8 blocks at its longest render (noise falls 64-fold there, a bias "
                  "stays: an upper estimate of the error it cannot average away):\n" + "\n".join(floors))
    (args.out / "pbl_speed.md").write_text(table + "\n")
    print(table)


def equal_error_table(rows: list[dict]) -> str:
    """For each scene and pbl render: pbl's time over the time volpath of the same run takes to pbl's error there
    (time_to on volpath's curve, extrapolated as 1/spp): the sky-lit targets' measure, at every pass count."""
    lines = ["| scene | pbl passes: s, relMSE | volpath s to that relMSE | pbl / volpath time |", "|---|---|---|---|"]
    for r in rows:
        for t, err, spp, *_ in sorted(r["curves"]["pbl"], key=lambda p: p[2]):
            tv = time_to([p[:2] for p in r["curves"]["volpath"]], err, extrapolate=True)
            lines.append(f"| {r['scene']} | {spp}: {t:.2f} s, {err:.5f} | {tv:.2f} | {t / tv:.2f}× |" if tv else
                         f"| {r['scene']} | {spp}: {t:.2f} s, {err:.5f} | — | — |")
    return "\n".join(lines)


def pass_cost(args, res: str):
    """Step 2 alone, for every scene of args.scenes, args.repeat rounds of the two renders one after the other (a
    16-spp volpath render's time moves by a quarter from run to run), after a round not counted: the medians, their
    ratio, the rounds' ratios and their times. Writes <out>/pass_cost.md."""
    lines = ["| scene | pass s (median) | volpath 16 spp s (median) | pass / volpath 16 | rounds' ratios "
             "| rounds' s (pass, volpath 16) |", "|---|---|---|---|---|---|"]
    for name in args.scenes.split(","):
        scene = ROOT / "configs" / f"{name}.toml"
        scenes = {"pbl": with_pbl(scene, args.out / "scenes", args.pbl), "volpath": scene}
        rounds = [{m: render(scenes[m], m, spp, 1, res, args.threads, args.cache, args.out / f"{name}_{m}.exr")[0][
            "time_s"] for m, spp in (("pbl", 1), ("volpath", 16))} for _ in range(args.repeat + 1)][1:]
        # (a first round not counted: after any change to the package's sources its first render compiles kernels)
        t = {m: statistics.median(r[m] for r in rounds) for m in ("pbl", "volpath")}
        ratios = ", ".join(f"{r['pbl'] / r['volpath']:.1f}" for r in rounds)
        times = ", ".join(f"{r['pbl']:.2f} {r['volpath']:.2f}" for r in rounds)
        lines.append(f"| {name} | {t['pbl']:.2f} | {t['volpath']:.2f} | {t['pbl'] / t['volpath']:.1f}× | {ratios} | "
                     f"{times} |")
        print(lines[-1], flush=True)
    (args.out / "pass_cost.md").write_text("\n".join(lines) + "\n")


def reused_curves(path: Path | None, name: str, res: str) -> dict:
    """The curves other than pbl's of scene `name` at `res` in an earlier pbl_speed.json (path; None: none)."""
    if path is None:
        return {}
    rows = [r for r in json.loads(path.read_text()) if r["scene"] == name and r["resolution"] == res]
    return {k: [tuple(p) for p in v] for k, v in rows[0]["curves"].items() if k != "pbl"} if rows else {}


def mitsuba_curves(args, name: str, scene: Path, ref, ref_noise: float) -> dict:
    """{"mitsuba <integrator>": [(seconds, relMSE against ref less its noise, spp, 0.0)]} at args.mitsuba_spp."""
    from pbvol_cli.imageio import read_exr
    from pbvol_cli.pipeline.export_mitsuba import export_mitsuba
    from volpath_mitsuba import mitsuba_render

    scene_json = args.out / f"{name}_mitsuba.json"
    export_mitsuba(scene, scene_json, resolution=(args.resolution, args.resolution))
    curves = {}
    for integ in args.mitsuba_integrators.split(","):
        pts = []
        for spp in (int(v) for v in args.mitsuba_spp.split(",")):
            out = args.out / f"{name}_mitsuba_{integ}.exr"
            m = mitsuba_render(args.mitsuba, scene_json, out, spp, 1, args.threads, args.mitsuba_variant, integ)
            pts.append((m["time_s"], max(rel_mse(read_exr(out)[0].astype(float), ref) - ref_noise, 1e-12), spp, 0.0))
            print(f"{name} mitsuba {integ} {spp} spp: {m['time_s']:.2f} s, relMSE {pts[-1][1]:.5f}", flush=True)
        curves[f"mitsuba {integ}"] = pts
    return curves


def _plot(path: Path, name: str, curves: dict, target: float, ref_noise: float = 0.0):
    """The curves' relMSE against seconds, log-log, the target dashed; the reference's own noise dotted, and the
    renders whose error fell below it (stored as 1e-12: not measurable against this reference) left out."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(f"(no matplotlib: {path.name} not drawn)")
        return
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for method, pts in curves.items():
        pts = [p for p in pts if p[1] > 1e-12]
        ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-", label=method)
    ax.axhline(target, color="grey", lw=0.8, ls="--")
    if ref_noise > 0:
        ax.axhline(ref_noise, color="grey", lw=0.8, ls=":", label="the reference's own noise")
    ax.set_xlabel("seconds")
    ax.set_ylabel("relMSE")
    ax.set_title(name)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main()
