#!/usr/bin/env python3
"""How much of a dense body's scattered light each method renders against volpath, as the body thickens.

    .venv/bin/python benchmarks/pbl_thickness.py [--thickness 15,30,60,120,240] [--eta 1.5] [--albedo 0.999] [--g 0]
        [--boxes 15,30,60,120,240 [--null]] [--scenes configs/marble_bunny.toml] [--methods pbl,dipole]
        [--resolution 32] [--spp 8] [--ref-spp 1024] [--ref-seeds 8] [--extent auto] [--set k=v,...] [--seed N]
        [--out bench-out/pbl_thickness] [--threads 2] [--cache DIR]

benchmarks/scenes/marble_sphere.toml (a sphere of radius 3 cm behind eta 1.5 over a floor, under a sphere light)
with its marble replaced by a grey medium of --albedo, --g and index --eta whose mean free path makes the sphere
each of --thickness reduced mean free paths (1/sigma'_t) across (the same geometry and light throughout; the files
are named grey_sphere_<thickness>_eta<eta>, with _albedo<a> and _g<g> where those are not 0.999 and 0), then each
of --boxes: benchmarks/scenes/thick_box.toml (a box 30 x 10 x 30 behind eta 1.5 under a sphere light) with the same
grey medium, each of --boxes reduced mean free paths thick along its short side (grey_box_<thickness>_eta<eta>, its
boundary of index --eta; with --null an index-matched boundary, grey_box_<thickness>_null), then each
of --scenes as they are (the marble bunny: 53-73 reduced mean free paths thick). Per scene: volpath at --ref-spp
with seeds 1 to --ref-seeds, averaged (one seed's 1024 samples read a sphere's scattered light within 2-5 %),
volpath with no volume scattering (--orders 0: the surfaces alone, at a quarter of --ref-spp) and each of
--methods at --spp. Prints the body's thickness and reduced albedo as `pbvol check` reads them
(check.reduced_thickness), then per method its time and the ratio to volpath (R, G, B) of the image's mean and of
the scattered light's: the image less volpath's surfaces, over the pixels where volpath's scattered light is above
5 % of its brightest. --extent sets every scene's [render.lut] extent for the methods, --set k=v,... their
[render.pbl] settings and --seed their seed (their renders are named with _extent<e>, _<k><v>, _seed<n>; the
volpath references are the same). Each render is kept in --out and reused when there.
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
SPHERE_ALBEDO = 0.999  # the grey spheres' default (marble's is 0.998-0.999)


def main():
    import numpy as np
    import tomli_w

    from pbl_bench import pbl_overrides

    from pbvol_cli import config as C
    from pbvol_cli.geometry.scene_build import build_scene
    from pbvol_cli.imageio import read_exr
    from pbvol_cli.pipeline.check import reduced_thickness
    from pbvol_cli.pipeline.render import RenderOptions, render_scene

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--eta", type=float, default=1.5, help="the grey spheres' index (marble's: 1.5)")
    ap.add_argument("--thickness", default="15,30,60,120,240",
                    help="the sphere's diameters in reduced mean free paths ('' for none)")
    ap.add_argument("--albedo", type=float, default=SPHERE_ALBEDO, help="the grey spheres' single-scattering albedo")
    ap.add_argument("--g", type=float, default=0.0, help="the grey spheres' Henyey-Greenstein g")
    ap.add_argument("--boxes", default="", help="grey boxes' short sides in reduced mean free paths ('' for none)")
    ap.add_argument("--null", action="store_true", help="the boxes behind an index-matched boundary")
    ap.add_argument("--scenes", default="configs/marble_bunny.toml", help="more scene files, comma-separated")
    ap.add_argument("--methods", default="pbl")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--ref-seeds", type=int, default=8, help="volpath renders averaged for the reference")
    ap.add_argument("--set", default="", help="comma-separated k=v [render.pbl] settings for the methods")
    ap.add_argument("--seed", type=int, default=None, help="the methods' render seed (default: the scene's)")
    ap.add_argument("--extent", default=None, help="[render.lut] extent for the methods, mean free paths (default: "
                    "each scene's own, \"auto\" unless it sets one)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "bench-out" / "pbl_thickness")
    ap.add_argument("--cache", type=Path, default=ROOT / ".bench-cache")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    scenes = []
    sphere = ROOT / "benchmarks" / "scenes" / "marble_sphere.toml"
    for across in filter(None, args.thickness.split(",")):
        doc = tomllib.loads(sphere.read_text())
        diameter = 2.0 * doc["shapes"][0]["radius"]
        reduced = 1.0 - args.g * args.albedo  # sigma'_t / sigma_t
        doc["shapes"][0]["medium"] = {"albedo": args.albedo, "g": args.g,
                                      "mean_free_path": diameter * reduced / float(across), "eta": args.eta}
        tag = (f"_albedo{args.albedo:g}" if args.albedo != SPHERE_ALBEDO else "") + (f"_g{args.g:g}" if args.g else "")
        path = args.out / f"grey_sphere_{across}{tag}_eta{args.eta:g}.toml"
        path.write_text(tomli_w.dumps(doc))
        scenes.append(path)
    box = ROOT / "benchmarks" / "scenes" / "thick_box.toml"
    for across in filter(None, args.boxes.split(",")):
        doc = tomllib.loads(box.read_text())
        shape = doc["shapes"][0]
        reduced = 1.0 - args.g * args.albedo
        shape["medium"] = {"albedo": args.albedo, "g": args.g,
                           "mean_free_path": min(shape["size"]) * reduced / float(across)}
        shape["interface"] = "null" if args.null else "dielectric"  # (a null boundary does not read its eta)
        shape["eta"] = args.eta
        tag = (f"_albedo{args.albedo:g}" if args.albedo != SPHERE_ALBEDO else "") + (f"_g{args.g:g}" if args.g else "")
        path = args.out / f"grey_box_{across}{tag}_{'null' if args.null else f'eta{args.eta:g}'}.toml"
        path.write_text(tomli_w.dumps(doc))
        scenes.append(path)
    scenes += [ROOT / s for s in filter(None, args.scenes.split(","))]
    res = (args.resolution, args.resolution)

    pbl_set = pbl_overrides(args.set)

    def render(scene: Path, method: str, spp: int, orders=None, seed=None):
        tag = ""
        if method != "volpath":  # (the references do not depend on the methods' settings)
            tag = (f"_extent{args.extent}" if args.extent else "") + "".join(
                f"_{k}{v}" for k, v in pbl_set.items()) + (f"_seed{args.seed}" if args.seed is not None else "")
            seed = args.seed
        out = args.out / (f"{scene.stem}_{method}_{spp}{'_orders' + orders if orders else ''}_{args.resolution}"
                          f"{f'_seed{seed}' if seed and method == 'volpath' else ''}{tag}.exr")
        seconds = None
        if not out.exists():
            if args.extent or pbl_set:  # the scene with the table's extent or pbl's settings set, in a folder of
                # --out (files it names by a relative path are not rewritten: for scenes without any, as the grey
                # spheres and boxes)
                doc = tomllib.loads(scene.read_text())
                if args.extent:
                    doc.setdefault("render", {}).setdefault("lut", {})["extent"] = (
                        args.extent if args.extent == "auto" else float(args.extent))
                doc.setdefault("render", {}).setdefault("pbl", {}).update(pbl_set)
                folder = args.out / "settings" / (tag[1:] or "as-given")
                folder.mkdir(parents=True, exist_ok=True)
                scene = folder / scene.name
                scene.write_text(tomli_w.dumps(doc))
            t = time.perf_counter()
            render_scene(scene, out, RenderOptions(method=method, spp=spp, resolution=res, orders=orders, seed=seed,
                                                   threads=args.threads, cache_dir=args.cache, quiet=True))
            seconds = time.perf_counter() - t
        return read_exr(out)[0], seconds

    def ratios(a):
        return " ".join(f"{v:.3f}" for v in a)

    for scene in scenes:
        sc = C.load_scene(scene)
        b = build_scene(sc, scene, (8, 8))
        thickness, albedo = reduced_thickness(b, 0)
        # seed 1 is the scene files' own (kept under the name without a seed)
        ref = np.mean([render(scene, "volpath", args.ref_spp, seed=s if s > 1 else None)[0]
                       for s in range(1, args.ref_seeds + 1)], axis=0)
        surfaces, _ = render(scene, "volpath", max(1, args.ref_spp // 4), orders="0")
        scattered = ref - surfaces
        mask = scattered.mean(axis=2) > 0.05 * scattered.mean(axis=2).max()
        print(f"{scene.stem}: {ratios(thickness).replace(' ', ', ')} reduced mean free paths thick, reduced albedo "
              f"{ratios(albedo).replace(' ', ', ')}; {int(mask.sum())} pixels of scattered light")
        for method in args.methods.split(","):
            img, seconds = render(scene, method, args.spp)
            took = f"{seconds:.1f} s" if seconds is not None else "kept"
            print(f"  {method:7s} ({took}): image {ratios(img.mean((0, 1)) / ref.mean((0, 1)))}, scattered light "
                  f"{ratios((img - surfaces)[mask].mean(0) / scattered[mask].mean(0))} of volpath's")


if __name__ == "__main__":
    main()
