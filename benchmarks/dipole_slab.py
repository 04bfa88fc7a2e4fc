#!/usr/bin/env python3
"""Where diffusion holds: the dipole's layers against volpath --orders on a thick slab under a white sky and on a
large sphere under a sphere light.

    .venv/bin/python benchmarks/dipole_slab.py [--albedo 0.99,0.9] [--eta 1.0,1.5] [--mfp 0.05] [--spp 4]
        [--ref-spp 512]

slab: a box 1 thick and 4 wide (20 x 80 x 80 mean free paths at 0.05) seen from above, every pixel on its top
face; sphere: radius 1 (20 mean free paths), lit by a sphere light of radius 1 at distance 5.2 and a sky of 0.1,
the pixels where volpath's orders 2 and 3+ exceed 0.02. Prints the means of the dipole's diffusion, single and
surface layers against volpath's orders 2 and 3+, 1 and 0, and the diffusion's ratio.
"""

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from conftest import build, camera, volpath, write_scene  # noqa: E402

from pbvol_cli.imageio import read_layers  # noqa: E402
from pbvol_cli.pipeline.render import RenderOptions, render_scene  # noqa: E402


def scene_of(shape_kind: str, albedo: float, eta: float, mfp: float, spp: int) -> dict:
    medium = {"albedo": albedo, "mean_free_path": mfp, "g": 0.0}
    base = {"interface": "null" if eta == 1.0 else "dielectric", "medium": medium}
    if eta != 1.0:
        base["eta"] = eta
    if shape_kind == "slab":
        return {"camera": camera((16, 16), position=(0.0, 3.0, 0.3), fov=8), "render": {"spp": spp},
                "lights": [{"type": "environment", "radiance": 1.0}],
                "shapes": [{"type": "box", "size": [4.0, 1.0, 4.0], **base}]}
    return {"camera": camera((24, 24), position=(0.0, 0.0, 4.0), fov=35), "render": {"spp": spp},
            "lights": [{"type": "sphere", "center": [3.0, 3.0, 3.0], "radius": 1.0, "radiance": 2.0},
                       {"type": "environment", "radiance": 0.1}],
            "shapes": [{"type": "sphere", "radius": 1.0, **base}]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--shapes", default="slab,sphere")
    ap.add_argument("--albedo", default="0.99,0.9")
    ap.add_argument("--eta", default="1.0,1.5")
    ap.add_argument("--mfp", type=float, default=0.05)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--ref-spp", type=int, default=512)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="pbvol-dipole-"))
    for kind in args.shapes.split(","):
        for albedo in (float(v) for v in args.albedo.split(",")):
            for eta in (float(v) for v in args.eta.split(",")):
                scene = scene_of(kind, albedo, eta, args.mfp, args.spp)
                path = write_scene(tmp, scene)
                t = time.perf_counter()
                render_scene(path, tmp / "d.exr", RenderOptions(method="dipole", cache_dir=tmp, quiet=True))
                t_dipole = time.perf_counter() - t
                layers = read_layers(tmp / "d.exr")
                bs = build(tmp, scene)
                t = time.perf_counter()
                ref = {o: volpath(bs, spp=args.ref_spp, seed=1, orders=o) for o in ("0", "1", "2,3+")}
                t_ref = time.perf_counter() - t
                seen = ref["2,3+"].mean(-1) > 0.02
                mean = {k: float(v[seen].mean()) for k, v in layers.items()}
                rmean = {k: float(v[seen].mean()) for k, v in ref.items()}
                print(f"{kind} albedo {albedo} eta {eta}: diffusion {mean['diffusion']:.4f} / orders 2,3+ "
                      f"{rmean['2,3+']:.4f} = {mean['diffusion'] / rmean['2,3+']:.3f}; single {mean['single']:.4f} / "
                      f"order 1 {rmean['1']:.4f}; surface {mean['surface']:.4f} / order 0 {rmean['0']:.4f}; "
                      f"whole {sum(mean.values()) / sum(rmean.values()):.3f} (dipole {t_dipole:.1f} s, volpath "
                      f"{3 * args.ref_spp} spp {t_ref:.1f} s)", flush=True)


if __name__ == "__main__":
    main()
