#!/usr/bin/env python3
"""Furnace check of the point-based method: a non-absorbing sphere (radius 1) under a white sky must render 1.

    .venv/bin/python benchmarks/pbl_furnace.py

Prints the mean over the central pixels and each layer, for an index-matched boundary and for eta = 1.5, at mean
free paths 0.5 and 2 (--shape slab: a thick slab seen from above instead). The multiple term corrects the table's
infinite medium by mirror-image sources behind the boundary planes nearest each source point and each camera point
(docs/pbl.md), and the bounced layer adds what a dielectric boundary reflects; both are approximations, and the
numbers measure them. volpath passes it exactly (tests/render/test_volpath.py).
"""

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from conftest import camera, write_scene  # noqa: E402

from pbvol_cli.imageio import read_exr, read_layers  # noqa: E402
from pbvol_cli.pipeline.render import RenderOptions, render_scene  # noqa: E402


LIGHTS = {"sky": {"type": "environment", "radiance": 1.0},
          "front": {"type": "directional", "direction": [0.0, 0.0, -1.0], "irradiance": 1.0},
          "back": {"type": "directional", "direction": [0.0, 0.0, 1.0], "irradiance": 1.0},
          "side": {"type": "directional", "direction": [1.0, 0.0, 0.0], "irradiance": 1.0}}


def main():
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--eta", default="1.0,1.5", help="comma list of boundary indices (1: index-matched)")
    ap.add_argument("--mfp", default="0.5,2.0", help="comma list of mean free paths (the sphere's radius is 1)")
    ap.add_argument("--g", type=float, default=0.0, help="Henyey-Greenstein mean cosine")
    ap.add_argument("--albedo", type=float, default=1.0, help="single-scattering albedo (below 1 the centre is not "
                    "1: compare with --orders)")
    ap.add_argument("--orders", action="store_true", help="also volpath --orders 0, 1, 2, 3+ (256 spp), for the "
                    "layers surface, single, double, multiple (+ bounced)")
    ap.add_argument("--shape", choices=("sphere", "slab"), default="sphere", help="sphere: radius 1, seen whole; "
                    "slab: a box 1 thick and 4 wide (20 x 80 x 80 mean free paths at 0.05), seen from above at its "
                    "centre (a half-space's boundary under a sky, and light from the far faces)")
    ap.add_argument("--light", default="sky", help="sky: the white "
                    "environment (the furnace); front, back, side: a directional light of irradiance 1 from the "
                    "camera's side, from behind the body or from the side (compare with --orders: light diffusing "
                    "under the near boundary, through the body from its far side, around it); or the direction "
                    "the light travels as x,y,z (e.g. 0,-1,0: onto the slab from above)")
    ap.add_argument("--pbl", default="{}", help='[render.pbl] settings as JSON, e.g. \'{"clamp": 0.005}\'')
    args = ap.parse_args()
    import json

    if args.light in LIGHTS:
        light = LIGHTS[args.light]
    else:
        try:
            light = {"type": "directional", "direction": [float(x) for x in args.light.split(",")], "irradiance": 1.0}
            assert len(light["direction"]) == 3
        except (ValueError, AssertionError):
            ap.error(f"--light: expected one of {', '.join(LIGHTS)} or x,y,z, got {args.light!r}")
    tmp = Path(tempfile.mkdtemp(prefix="pbvol-furnace-"))
    for eta in (float(x) for x in args.eta.split(",")):
        for mfp in (float(x) for x in args.mfp.split(",")):
            shape = {"type": "sphere", "radius": 1.0, "interface": "null" if eta == 1.0 else "dielectric",
                     "medium": {"albedo": args.albedo, "mean_free_path": mfp, "g": args.g}}
            cam = camera((16, 16), position=(0, 0, 3.0), fov=30)
            if args.shape == "slab":
                shape = {**shape, "type": "box", "size": [4.0, 1.0, 4.0]}
                del shape["radius"]
                cam = camera((16, 16), position=(0.0, 3.0, 0.3), fov=8)
            if eta != 1.0:
                shape["eta"] = eta
            scene = {"camera": cam, "render": {"spp": 8, "pbl": json.loads(args.pbl)},
                     "lights": [light], "shapes": [shape]}
            p = write_scene(tmp, scene)
            render_scene(p, tmp / "o.exr", RenderOptions(method="pbl", cache_dir=tmp, quiet=True))
            layers, img = read_layers(tmp / "o.exr"), read_exr(tmp / "o.exr")[0]
            c = slice(5, 11)
            parts = ", ".join(f"{k} {float(v[c, c].mean()):.3f}" for k, v in layers.items())
            print(f"{args.shape} ({args.light}) eta {eta} mean free path {mfp} g {args.g} albedo {args.albedo}: centre {img[c, c].mean():.3f} ({parts})")
            if args.orders:
                from conftest import build, volpath

                bs = build(tmp, scene)
                parts = ", ".join(f"{o} {float(volpath(bs, spp=256, seed=1, orders=o)[c, c].mean()):.3f}"
                                  for o in ("0", "1", "2", "3+"))
                print(f"    volpath --orders: {parts}")


if __name__ == "__main__":
    main()
