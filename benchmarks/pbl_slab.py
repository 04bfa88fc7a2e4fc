#!/usr/bin/env python3
"""The point-based method's components on a flat, index-matched slab against volpath --orders.

    .venv/bin/python benchmarks/pbl_slab.py [--material wax] [--incidence 0,60] [--resolution 32] [--ref-spp 1024]

A box of the material (30 x 10 x 30 scene units, top face at y = 0) with a null boundary, lit by a sphere light
(radius 3, 30 units away) at the given incidences, seen from above at 45 degrees. The boundary is a plane, so
the multiple term's mirror-image source (pointbased/sources.py: source_terms) is placed exactly as the method of images would;
what remains is the image's distance to the boundary (on it: the table's light that the boundary would
return is subtracted too strongly where light diffuses far, e.g. wax's red). Prints, per component, the image
mean of pbl's layer over volpath's: single / order 1, double / order 2, multiple / 3+.
"""

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from conftest import build, volpath, write_scene  # noqa: E402

from pbvol_cli.imageio import read_layers  # noqa: E402
from pbvol_cli.pipeline.render import RenderOptions, render_scene  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--material", default="wax", help="material preset (materials/NAME.toml)")
    ap.add_argument("--incidence", default="0,60", help="comma list of the light's angles from the normal, degrees")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--pbl-spp", type=int, default=8)
    ap.add_argument("--ref-spp", type=int, default=1024)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="pbvol-slab-"))
    res = args.resolution
    for inc in (float(x) for x in args.incidence.split(",")):
        a = math.radians(inc)
        scene = {"unit": "scene",
                 "camera": {"position": [0.0, 12.0, 12.0], "look_at": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0],
                            "fov": 20.0, "resolution": [res, res]},
                 "render": {"spp": args.pbl_spp, "seed": 1, "max_depth": 100000},
                 "lights": [{"type": "sphere", "center": [30.0 * math.sin(a), 30.0 * math.cos(a), 0.0],
                             "radius": 3.0, "radiance": 20.0}],
                 "shapes": [{"type": "box", "center": [0.0, -5.0, 0.0], "size": [30.0, 10.0, 30.0],
                             "interface": "null", "medium": args.material}]}
        p = write_scene(tmp, scene)
        render_scene(p, tmp / "o.exr", RenderOptions(method="pbl", cache_dir=tmp, quiet=True))
        layers = read_layers(tmp / "o.exr")
        bs = build(tmp, scene)
        parts = []
        for name, order in (("single", "1"), ("double", "2"), ("multiple", "3+")):
            ref = volpath(bs, spp=args.ref_spp, seed=1, orders=order).reshape(-1, 3).mean(0)
            got = layers[name][..., :3].reshape(-1, 3).mean(0)
            parts.append(f"{name} {' '.join(f'{v:.3f}' for v in got / np.where(ref > 0, ref, np.nan))}")
        print(f"{args.material} slab, incidence {inc:g} deg (pbl / volpath order, R G B): {' | '.join(parts)}")


if __name__ == "__main__":
    main()
