#!/usr/bin/env python3
"""Each point-based component against the path tracer restricted to the same number of scattering events.

    .venv/bin/python benchmarks/pbl_components.py [--scenes a,b] [--resolution 48] [--pbl-spp 8]
                                                 [--ref-spp 1024] [--bands 0] [--as-rendered] [--threads 2]
                                                 [--cache DIR]

For each scene: one pbl render (its layers single, double, multiple, bounced) and volpath --orders 1, 2 and 3+,
each as two halves with different seeds (kept in the cache). Printed per component and channel: the ratio of image means pbl / volpath (the
bias that survives averaging) and the relMSE of pbl against the volpath mean, next to the relMSE of the
reference's own noise (a quarter of its halves' relMSE against each other) and the ratio of the halves' means
(a reference whose halves differ by more than a few % is not converged: its order's paths are heavy-tailed).
With --bands N, the same ratios for single, double, multiple (alone and with bounced) and bounced over N bands of image
rows, where order 3+ is at least 5 % of its brightest pixel: where in the image a bias sits (a boundary, a face).
With --as-rendered, pbl renders the scene with its own [render.pbl] similarity transform (section 2 of docs/pbl.md;
the peak's deflections off) and volpath renders the media after that same transform, so that a truncated peak is no
scattering for both: pbl's own bias by order, apart from the transform's (without it pbl renders the media as given,
similarity "none", whose layers are the true orders).
A scene is a config name in configs/ or a scene file (benchmarks/scenes/ holds scenes that isolate one effect).
Light that scattered in the medium, left it and came back from the scene (a table) is in pbl's bounced layer (the
light samples' v_returned part): of order 2 and above, like the rest of that layer.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pbl_bench import ROOT, RENDER, _run, rel_mse, with_pbl  # noqa: E402

ORDERS_RENDER = RENDER.replace("RenderOptions(spp=int(spp), seed=int(seed), resolution=res, **kw)",
                               "RenderOptions(spp=int(spp), seed=int(seed), resolution=res, orders=sys.argv[9], **kw)")
# the same, the scene's media put through the similarity transform named by $PBVOL_BENCH_SIMILARITY (--as-rendered)
TRANSFORMED_ORDERS_RENDER = r"""
import os
from dataclasses import replace
import pbvol_cli.geometry.scene_build as scene_build
from pbvol_cli.pointbased.similarity import TRANSFORMS
_build = scene_build.build_scene
def _transformed(*a, **k):
    built = _build(*a, **k)
    return replace(built, media=TRANSFORMS[os.environ["PBVOL_BENCH_SIMILARITY"]](built.media))
scene_build.build_scene = _transformed
""" + ORDERS_RENDER


def main():
    import numpy as np

    from pbvol_cli.imageio import read_exr, read_layers

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="bumpy_sphere,oil_glass,wax_sphere,wax_sphere_soft,milk_glass,wine_glass,wine_glass_soft")
    ap.add_argument("--resolution", type=int, default=48)
    ap.add_argument("--pbl-spp", type=int, default=8)
    ap.add_argument("--pbl-seed", type=int, default=1, help="pbl's seed (the references' are fixed)")
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--bands", type=int, default=0, help="also print the ratios over this many bands of rows")
    ap.add_argument("--as-rendered", action="store_true", help="pbl with the scene's similarity transform, volpath "
                    "on the transformed media")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=ROOT / ".bench-cache")
    args = ap.parse_args()
    res = f"{args.resolution}x{args.resolution}"
    out = args.cache / "components"
    out.mkdir(parents=True, exist_ok=True)
    print(f"{res}, pbl {args.pbl_spp} spp, volpath --orders at {args.ref_spp} spp (two halves), {args.threads} threads")
    print(f"{'scene':<14} {'component':<12} {'mean ratio pbl/vp (R G B)':<29} {'relMSE':>8} {'ref noise':>9} "
          f"{'halves R G B':>14}")
    for name in [s for s in args.scenes.split(",") if s]:
        scene = Path(name) if name.endswith(".toml") else ROOT / "configs" / f"{name}.toml"
        name = scene.stem
        similarity = "none"
        if args.as_rendered:
            import tomllib

            similarity = tomllib.loads(scene.read_text()).get("render", {}).get("pbl", {}).get("similarity", "none")
        tag = "" if similarity == "none" else f"_{similarity}"
        pbl_out = out / f"{name}{tag}_pbl.exr"
        # the media as given (a similarity transform's layers are not the scattering orders), or both methods on the
        # transformed media (--as-rendered)
        as_pbl = with_pbl(scene, out / ("as_rendered" if tag else "as_given"),
                          {"similarity": similarity, "peak_deflections": False})
        _run(RENDER, as_pbl, pbl_out, "pbl", args.pbl_spp, args.pbl_seed, args.threads, res, args.cache)
        os.environ["PBVOL_BENCH_SIMILARITY"] = similarity
        layers = {k: v.astype(np.float64) for k, v in read_layers(pbl_out).items()}
        refs = {}
        for orders in ("1", "2", "3+"):
            halves = []
            for seed in (201, 202):
                # references are kept (keyed by scene, size, spp, order, seed): delete them after changing a scene
                o = out / f"{name}{tag}_{res}_{args.ref_spp}spp_vp_{orders.replace('+', 'p')}_{seed}.exr"
                if not o.exists():
                    _run(TRANSFORMED_ORDERS_RENDER if tag else ORDERS_RENDER, scene, o, "volpath",
                         args.ref_spp // 2, seed, args.threads, res, args.cache, orders)
                halves.append(read_exr(o)[0].astype(np.float64))
            refs[orders] = halves
        zero = np.zeros_like(layers["single"])
        # bounced light has scattered at least once before a reflection and once after: order 2 and above, so it
        # is compared with multiple against 3+ (the pairing; its order-2 part makes that a little high)
        # and with double and multiple against 2 + 3+ (exact pairing)
        rows = [("single", layers["single"], ("1",)), ("double", layers["double"], ("2",)),
                ("multiple", layers["multiple"], ("3+",)),
                ("mult+bounced", layers["multiple"] + layers.get("bounced", zero), ("3+",)),
                ("2+ all", layers["double"] + layers["multiple"] + layers.get("bounced", zero), ("2", "3+"))]
        for comp, mine, orders in rows:
            h0, h1 = (sum(refs[o][k] for o in orders) for k in (0, 1))
            ref = 0.5 * (h0 + h1)
            noise = rel_mse(h0, h1) / 4.0
            ratio = mine.mean((0, 1)) / np.maximum(ref.mean((0, 1)), 1e-30)
            # the halves' means apart by more than a few % say the reference is not converged (heavy tails)
            halves = h0.mean((0, 1)) / np.maximum(h1.mean((0, 1)), 1e-30)
            print(f"{name:<14} {comp:<12} {' '.join(f'{r:.3f}' for r in ratio):<29} "
                  f"{rel_mse(mine, ref):>8.4f} {noise:>9.5f} {' '.join(f'{h:.2f}' for h in halves):>14}", flush=True)
        if args.bands:
            print_bands(layers, {o: 0.5 * (h[0] + h[1]) for o, h in refs.items()}, args.bands)


def print_bands(layers, refs, bands: int):
    """pbl / volpath per band of rows (channels summed) over the pixels where order 3+ is at least 5 % of its
    brightest pixel; each band's share of 3+ says how much of the image it weighs."""
    import numpy as np

    sky = refs["3+"].sum(axis=2)
    mask = sky > 0.05 * sky.max()
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0:
        return
    bounced = layers.get("bounced", np.zeros_like(layers["single"]))
    pairs = [("single / 1", layers["single"], "1"), ("double / 2", layers["double"], "2"),
             ("multiple / 3+", layers["multiple"], "3+"),
             ("bounced / 3+", bounced, "3+"), ("mult+bounced / 3+", layers["multiple"] + bounced, "3+"),
             ("2+ all / 2, 3+", layers["double"] + layers["multiple"] + bounced, ("2", "3+"))]
    print(f"  {'rows':<9} {'share of 3+':>11} " + " ".join(f"{p[0]:>17}" for p in pairs))
    total = sky[mask].sum()
    for band in np.array_split(np.arange(rows[0], rows[-1] + 1), min(bands, rows[-1] + 1 - rows[0])):
        m = np.zeros_like(mask)
        m[band] = mask[band]
        if not m.any():
            continue
        cells = [mine.sum(axis=2)[m].sum() / max(sum(refs[k] for k in (o if isinstance(o, tuple) else (o,)))
                                                 .sum(axis=2)[m].sum(), 1e-30) for _, mine, o in pairs]
        print(f"  {f'{band[0]}-{band[-1]}':<9} {sky[m].sum() / total:>11.3f} " + " ".join(f"{c:>17.3f}" for c in cells))


if __name__ == "__main__":
    main()
