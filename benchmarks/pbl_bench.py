#!/usr/bin/env python3
"""Benchmark of the point-based method against the reference path tracer, per example scene.

    .venv/bin/python benchmarks/pbl_bench.py [--scenes a,b] [--resolution 96] [--pbl-spp 4[,16]]
                                            [--pbl-seeds 1[,2,..]] [--volpath-spp 16] [--ref-spp 2048]
                                            [--ref-spp-for wax_sphere=32768] [--threads 2]
                                            [--cache DIR] [--memory-check]

For each scene, every stage in its own process (peak memory is per process; each process warms numba's cache
first at 8x8 so that loading compiled code is not timed):
  1. a high-spp volpath reference, rendered as two halves with different seeds (their mean is the reference; a
     quarter of the halves' relMSE against each other estimates the reference's own noise); kept in the cache
     directory and reused while the scene is unchanged;
  2. `place-samples` (time, peak memory) and the multiple-scattering tables (time);
  3. `render --method pbl` at --pbl-spp: time, peak memory, relMSE against the reference;
  4. `render --method volpath` at --volpath-spp: time, relMSE; the time volpath needs to reach pbl's error is
     t_volpath * relMSE_volpath / relMSE_pbl (relMSE of an unbiased estimator falls as 1/spp; the reference's
     own noise is subtracted from both errors first).
relMSE is `pbvol compare`'s: mean over pixels and channels of (a - b)^2 / (b^2 + 0.01); the columns `pbl med.`
and `vp med.` restrict it to the pixels where pbl's volume layers carry at least 5% of the pixel (the medium as
seen), and `speed-up med.` is the speed-up computed from those. `ceiling` is volpath's whole-image error over its
error outside those pixels: pbl path traces the surfaces as volpath does (the same estimator at about the same
cost per path), so even with an exact medium for free no such method beats volpath at equal whole-image error
by more than that.
With --memory-check, pbl also renders the first scene at 512x512, 1 spp, for its peak memory.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

RENDER = r"""
import json, sys
from pathlib import Path
from pbvol_cli.pipeline.render import RenderOptions, render_scene
scene, out, method, spp, seed, threads, res, cache = sys.argv[1:9]
res = tuple(int(v) for v in res.split("x"))
kw = dict(method=method, threads=int(threads), cache_dir=Path(cache), quiet=True)
warm = Path(out).with_name(Path(out).stem + ".warm-up.exr")  # not the output: a killed run leaves no wrong file
render_scene(Path(scene), warm, RenderOptions(spp=1, resolution=(8, 8), **kw))  # warm numba's cache
warm.unlink()
s = render_scene(Path(scene), Path(out), RenderOptions(spp=int(spp), seed=int(seed), resolution=res, **kw))
print(json.dumps(s))
"""

PLACE = r"""
import json, sys, time
from pathlib import Path
from pbvol_cli import config as C
from pbvol_cli.geometry.scene_build import build_scene
from pbvol_cli.pipeline.precompute import precompute
from pbvol_cli.pipeline.progress import peak_memory_mb, set_threads
from pbvol_cli.pipeline.samples import get_light_samples
scene_path, threads, cache = Path(sys.argv[1]), int(sys.argv[2]), Path(sys.argv[3])
scene = C.load_scene(scene_path)
set_threads(threads)
t = time.perf_counter()
precompute(scene_path, cache, None, None, False, True, lambda line: None)
t_lut = time.perf_counter() - t
built = build_scene(scene, scene_path, (8, 8))
t = time.perf_counter()
res = get_light_samples(built, scene.render.pbl, scene.render.seed, cache, threads, force=True)
t_samples = time.perf_counter() - t
print(json.dumps({"lut_s": t_lut, "samples_s": t_samples, "peak_memory_mb": peak_memory_mb(),
                  "volume_samples": int(len(res.samples.v_len)), "surface_samples": int(len(res.samples.s_pos))}))
"""


def setting_value(text: str):
    """A setting's value as written on a command line: true/false, a number, else the word."""
    if text in ("true", "false"):
        return text == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def pbl_overrides(text: str) -> dict:
    """{setting: value} of comma-separated k=v [render.pbl] overrides ("" gives {})."""
    return dict((k.strip(), setting_value(v.strip())) for k, v in (kv.split("=") for kv in text.split(",") if kv))


def files_made_absolute(data, folder: Path):
    """The scene data with every `file` field (a mesh, a density grid: relative to the scene file) made absolute
    from folder, the scene's own, so that a copy written elsewhere still finds them."""
    if isinstance(data, dict):
        return {k: (str((folder / v).resolve()) if k == "file" and isinstance(v, str) else
                    files_made_absolute(v, folder)) for k, v in data.items()}
    if isinstance(data, list):
        return [files_made_absolute(v, folder) for v in data]
    return data


def with_pbl(scene: Path, folder: Path, overrides: dict) -> Path:
    """The scene with its [render.pbl] settings overridden, written as folder/<its file name> (the same name: it
    names the cached references, which do not depend on [render.pbl]), the files it names made absolute; the
    scene itself without overrides."""
    import tomllib

    import tomli_w

    if not overrides:
        return scene
    data = files_made_absolute(tomllib.loads(scene.read_text()), scene.parent)
    data.setdefault("render", {}).setdefault("pbl", {}).update(overrides)
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / scene.name
    out.write_bytes(tomli_w.dumps(data).encode())
    return out


def _run(code: str, *args) -> dict:
    r = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, cwd=ROOT,
                       env={**os.environ, "PYTHONWARNINGS": "ignore"})
    if r.returncode != 0:
        raise SystemExit(f"failed: {args}\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def output_args(ap):
    """The options every benchmark shares: --threads, --cache (the bench caches and references), --out."""
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=ROOT / ".bench-cache")
    ap.add_argument("--out", type=Path, default=ROOT / "bench-out")


def one_scene_args(ap, resolution: int):
    """The options of a benchmark that renders one scene in its own process: --scene (a config name in configs/ or
    a scene file: scene_file), --resolution, --threads, --cache."""
    ap.add_argument("--scene", default="oil_sphere", help="a config name in configs/ or a scene file")
    ap.add_argument("--resolution", type=int, default=resolution)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=ROOT / ".bench-cache")


def scene_file(arg: str) -> Path:
    """--scene's file: a path ending in .toml, else configs/<arg>.toml."""
    return Path(arg) if arg.endswith(".toml") else ROOT / "configs" / f"{arg}.toml"


def parsed_scene(ap):
    """(ap's parsed arguments, --scene's file)."""
    args = ap.parse_args()
    return args, scene_file(args.scene)


def rel_mse(a, b) -> float:
    from pbvol_cli.pipeline.compare import image_metrics

    return image_metrics(a, b)["rel_mse"]


def block_rel_mse(a, b, block: int = 8) -> float:
    """relMSE (as compare's) of the two images averaged over block x block pixels: the part of a's error that does
    not average out over a few pixels (noise falls by block^2, a bias stays): an upper estimate of a's bias."""
    h, w = (a.shape[0] // block) * block, (a.shape[1] // block) * block

    def mean(x):
        return x[:h, :w].reshape(h // block, block, w // block, block, -1).mean(axis=(1, 3))

    return rel_mse(mean(a), mean(b))


def medium_mask(pbl_exr: Path):
    """Pixels where pbl's volume layers carry at least 5% of the pixel: the participating medium as seen."""
    import numpy as np

    from pbvol_cli.imageio import read_layers

    L = read_layers(pbl_exr)
    vol = sum(L[k].astype(np.float64) for k in ("single", "double", "multiple")).sum(axis=2)
    tot = vol + L["surface"].astype(np.float64).sum(axis=2)
    return vol > 0.05 * np.maximum(tot, 1e-30)


def rel_mse_in(a, b, mask) -> float:
    """relMSE (as compare's) over the masked pixels only."""
    if not mask.any():
        return float("nan")
    return float(((a - b) ** 2 / (b * b + 1e-2))[mask].mean())


def rel_mse_outside(a, b, mask) -> float:
    """The image's relMSE (as compare's, over all pixels) with the masked pixels' error taken as zero: what is
    left of an image's error when its medium is exact."""
    e = (a - b) ** 2 / (b * b + 1e-2)
    e[mask] = 0.0
    return float(e.mean())


def reference(scene: Path, res: str, spp: int, threads: int, cache: Path):
    """Mean of two volpath halves (seeds 101, 102) and the estimated relMSE of that mean's own noise."""
    import numpy as np

    from pbvol_cli.imageio import read_exr

    refdir = cache / "bench-refs"
    refdir.mkdir(parents=True, exist_ok=True)
    halves = []
    key = _reference_key(scene, res)
    for seed in (101, 102):
        out = refdir / f"{scene.stem}_{res}_{spp // 2}spp_seed{seed}.exr"
        key_file = out.with_suffix(".key")
        if out.exists():
            img, meta = read_exr(out)
            known = key_file.read_text() if key_file.exists() else None
            if known != key and meta.get("scene_hash") != _scene_hash(scene, res):
                out.unlink()
        if not out.exists():
            _run(RENDER, scene, out, "volpath", spp // 2, seed, threads, res, cache)
        key_file.write_text(key)
        halves.append(read_exr(out)[0].astype(np.float64))
    ref = 0.5 * (halves[0] + halves[1])
    return ref, rel_mse(halves[0], halves[1]) / 4.0


def scenes_with_references(args, res: str):
    """(name, scene file, reference image, its noise) for each of args.scenes (a comma list of configs/ stems),
    the references at args.ref_spp (reference())."""
    for name in args.scenes.split(","):
        scene = ROOT / "configs" / f"{name}.toml"
        ref, noise = reference(scene, res, args.ref_spp, args.threads, args.cache)
        yield name, scene, ref, noise


# what a volpath reference does not depend on: the run's own settings and the other methods' (a reference stays
# valid when a pbl default changes)
NOT_IN_REFERENCE = {"render": {"spp", "seed", "threads", "time_limit", "lut", "pbl", "dipole", "raymarch", "vpl"}}


def _reference_key(scene: Path, res: str) -> str:
    """Hash of what a volpath reference of scene at res depends on (the scene less NOT_IN_REFERENCE, its built
    geometry and media)."""
    import hashlib

    import numpy as np

    from pbvol_cli import config as C
    from pbvol_cli.geometry.scene_build import build_scene

    sc = C.load_scene(scene)
    built = build_scene(sc, scene, tuple(int(v) for v in res.split("x")))
    h = hashlib.sha256(sc.model_dump_json(exclude=NOT_IN_REFERENCE).encode())
    for arr in (built.surfaces, built.media, built.lights, built.spheres, built.vertices, built.faces):
        h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()[:16]


def _scene_hash(scene: Path, res: str) -> str:
    from pbvol_cli import config as C
    from pbvol_cli.geometry.scene_build import build_scene
    from pbvol_cli.pipeline.render import scene_hash

    sc = C.load_scene(scene)
    return scene_hash(sc, build_scene(sc, scene, tuple(int(v) for v in res.split("x"))))


def main():
    import numpy as np

    from pbvol_cli.imageio import read_exr

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="", help="comma list of config names (default: all in configs/)")
    ap.add_argument("--resolution", type=int, default=96)
    ap.add_argument("--pbl-spp", default="4", help="pbl's spp, or a comma list (a row for each)")
    ap.add_argument("--pbl-seeds", default="1", help="pbl's seeds, a comma list: relMSE is their mean (its range "
                    "in the last column), the time the first seed's")
    ap.add_argument("--volpath-spp", type=int, default=16)
    ap.add_argument("--ref-spp", type=int, default=2048)
    ap.add_argument("--ref-spp-for", default="", help="per-scene reference spp, e.g. wax_sphere=32768,wine_glass=16384 "
                    "(the small-light scenes, whose 2048-spp references cannot resolve pbl's error)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=ROOT / ".bench-cache")
    ap.add_argument("--memory-check", action="store_true")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    args = ap.parse_args()
    names = [s for s in args.scenes.split(",") if s] or sorted(p.stem for p in (ROOT / "configs").glob("*.toml"))
    ref_spp = {k: int(v) for k, v in (item.split("=") for item in args.ref_spp_for.split(",") if item)}
    res = f"{args.resolution}x{args.resolution}"
    tmp = args.cache / "bench-out"
    tmp.mkdir(parents=True, exist_ok=True)
    rows = []
    hdr = (f"{'scene':<15} {'spp':>4} {'samples s':>9} {'MiB':>5} {'lut s':>6} {'pbl s':>7} {'MiB':>5} {'relMSE':>8} "
           f"{'volpath s':>9} {'relMSE':>8} {'vp s @pbl err':>13} {'speed-up':>8} {'ref noise':>9} "
           f"{'pbl med.':>9} {'vp med.':>9} {'speed-up med.':>13} {'ceiling':>8}")
    print(f"{res}, pbl {args.pbl_spp} spp, volpath {args.volpath_spp} spp, reference volpath {args.ref_spp} spp"
          f"{''.join(f' ({k}: {v})' for k, v in ref_spp.items())}, "
          f"{args.threads} threads")
    print(hdr)
    pbl_spps = [int(v) for v in str(args.pbl_spp).split(",") if v]
    for name in names:
        scene = ROOT / "configs" / f"{name}.toml"
        ref, ref_noise = reference(scene, res, ref_spp.get(name, args.ref_spp), args.threads, args.cache)
        place = _run(PLACE, scene, args.threads, args.cache)
        seeds = [int(v) for v in args.pbl_seeds.split(",") if v]
        pbls = {}
        for spp in pbl_spps:
            for seed in seeds:  # the first seed's render keeps the plain name (its layers make the medium's mask)
                tag = f"{name}_pbl_{spp}" + ("" if seed == seeds[0] else f"_seed{seed}")
                r = _run(RENDER, scene, tmp / f"{tag}.exr", "pbl", spp, seed, args.threads, res, args.cache)
                pbls.setdefault(spp, r)
        vp = _run(RENDER, scene, tmp / f"{name}_vp.exr", "volpath", args.volpath_spp, 1, args.threads, res,
                  args.cache)
        vp_img = read_exr(tmp / f"{name}_vp.exr")[0].astype(np.float64)
        e_vp = rel_mse(vp_img, ref)
        mask = medium_mask(tmp / f"{name}_pbl_{max(pbl_spps)}.exr")  # the least noisy pbl render's layers
        e_vp_med = rel_mse_in(vp_img, ref, mask)
        e_vp_out = rel_mse_outside(vp_img, ref, mask)
        # both errors contain the reference's own noise: subtract it. When pbl's error is within twice that
        # noise, the reference cannot resolve it: volpath needs at least the time to reach the reference's
        # noise, and the speed-up is a lower bound (marked >=).
        e_vp_c = max(e_vp - ref_noise, 1e-12)
        # the ceiling: pbl path traces surfaces as volpath does (same estimator, same cost per path), so even with
        # an exact and free medium its image keeps volpath's error outside the medium: at equal whole-image error
        # no such method is faster than volpath by more than e_vp / e_vp(outside the medium)
        # (the reference's noise outside the medium taken as its share of the pixels; where volpath's error there
        # is within twice that, the ceiling is only known to be at least the value printed, marked >=)
        noise_out = ref_noise * (1.0 - mask.mean())
        bound_ceiling = bool(e_vp_out <= 2.0 * noise_out)
        ceiling = e_vp_c / (noise_out if bound_ceiling else e_vp_out - noise_out)
        for spp, pbl in pbls.items():
            imgs = [read_exr(tmp / (f"{name}_pbl_{spp}" + ("" if seed == seeds[0] else f"_seed{seed}") + ".exr"))[0]
                    .astype(np.float64) for seed in seeds]
            per_seed = [rel_mse(img, ref) for img in imgs]
            e_pbl = float(np.mean(per_seed))
            e_pbl_med = float(np.mean([rel_mse_in(img, ref, mask) for img in imgs]))
            bound = bool(e_pbl <= 2.0 * ref_noise)
            e_pbl_c = ref_noise if bound else e_pbl - ref_noise
            t_eq = vp["time_s"] * e_vp_c / e_pbl_c
            # the same comparison restricted to the medium's pixels (the reference's noise taken as uniform)
            e_pbl_med_c, e_vp_med_c = max(e_pbl_med - ref_noise, 1e-12), max(e_vp_med - ref_noise, 1e-12)
            bound_med = bool(e_pbl_med <= 2.0 * ref_noise)
            if bound_med:
                e_pbl_med_c = ref_noise
            speed_med = vp["time_s"] * e_vp_med_c / e_pbl_med_c / (pbl["time_s"] + place["samples_s"])
            row = {"scene": name, "resolution": res, "ref_spp": ref_spp.get(name, args.ref_spp), "pbl_spp": spp,
                   "samples_s": place["samples_s"], "samples_mib": place["peak_memory_mb"],
                   "volume_samples": place["volume_samples"], "lut_s": place["lut_s"], "pbl_s": pbl["time_s"],
                   "pbl_mib": pbl["peak_memory_mb"], "pbl_rel_mse": e_pbl, "volpath_s": vp["time_s"],
                   "volpath_rel_mse": e_vp, "volpath_s_at_pbl_error": t_eq,
                   "speed_up": t_eq / (pbl["time_s"] + place["samples_s"]), "ref_noise_rel_mse": ref_noise,
                   "lower_bound": bound, "medium_pixels": int(mask.sum()), "pbl_rel_mse_medium": e_pbl_med,
                   "volpath_rel_mse_medium": e_vp_med, "volpath_rel_mse_outside_medium": e_vp_out,
                   "speed_up_ceiling": ceiling, "lower_bound_ceiling": bound_ceiling, "speed_up_medium": speed_med,
                   "lower_bound_medium": bound_med, "pbl_seeds": seeds, "pbl_rel_mse_per_seed": per_seed}
            rows.append(row)
            mark = ">=" if bound else ""
            t_eq_s, up_s = f"{mark}{t_eq:.2f}", f"{mark}{row['speed_up']:.2f}"
            print(f"{name:<15} {spp:>4} {place['samples_s']:>9.2f} {place['peak_memory_mb']:>5.0f} "
                  f"{place['lut_s']:>6.1f} {pbl['time_s']:>7.2f} {pbl['peak_memory_mb']:>5.0f} {e_pbl:>8.4f} "
                  f"{vp['time_s']:>9.2f} {e_vp:>8.4f} {t_eq_s:>13} {up_s:>8} "
                  f"{ref_noise:>9.5f} {e_pbl_med:>9.4f} {e_vp_med:>9.4f} "
                  f"{('>=' if bound_med else '') + f'{speed_med:.2f}':>13} "
                  f"{('>=' if bound_ceiling else '') + f'{ceiling:.2f}':>8}"
                  f"{f'  seeds {min(per_seed):.4f}-{max(per_seed):.4f}' if len(seeds) > 1 else ''}", flush=True)
    print("speed-up = volpath's time to pbl's error / (place-samples + pbl render); tables are built once per "
          "material and not counted; med.: relMSE over the pixels where pbl's volume layers are >= 5% of the pixel;\n"
          "speed-up med.: the same speed-up with both errors over those pixels only; ceiling: volpath's whole-image "
          "error over its error outside those pixels, the most any method that path traces the surfaces as volpath "
          "does can gain at equal whole-image error")
    if args.memory_check:
        name = names[0]
        m = _run(RENDER, ROOT / "configs" / f"{name}.toml", tmp / f"{name}_512.exr", "pbl", 1, 1, args.threads,
                 "512x512", args.cache)
        print(f"memory check: {name} pbl 512x512, 1 spp: {m['time_s']:.1f} s, peak {m['peak_memory_mb']:.0f} MiB")
        rows.append({"scene": name, "resolution": "512x512", "pbl_s": m["time_s"], "pbl_mib": m["peak_memory_mb"]})
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
