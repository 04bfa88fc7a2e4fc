#!/usr/bin/env python3
"""Benchmark of precompute-lut: per material, time, on-disk size and accuracy of the multiple-scattering tables.

    .venv/bin/python benchmarks/lut_bench.py                      # every material in materials/, default settings
    .venv/bin/python benchmarks/lut_bench.py --noise wax,milk     # + noise of the default table vs a 16x larger run

Each material is built from scratch (a fresh cache directory), all its distinct channels, as `pbvol precompute-lut`
does. Columns: wall time for the material, total size of its tables on disk, and the compact form's error against
the dense table (relative L2 over the cells holding 99 % of the energy, at cell and direction-bin centres).
--noise: for the first channel of each named material, the dense default table against the dense table of a run
with 16x the particles, same metric (the default table's Monte Carlo noise), and the compact default against it.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main():
    from pbvol_cli import config as C
    from pbvol_cli.multiple_scattering import lobes
    from pbvol_cli.multiple_scattering.table import build_table, energy_cells, relative_error, resolve_particles
    from pbvol_cli.pipeline.lut import table_settings
    from pbvol_cli.physics.phase import KINDS
    from pbvol_cli.pipeline.lut import channel_tables
    from pbvol_cli.pipeline.precompute import precompute

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--materials", default="", help="comma list (default: all)")
    ap.add_argument("--noise", default="", help="comma list of materials to measure noise against a 16x run")
    args = ap.parse_args()
    names = [m for m in args.materials.split(",") if m] or C.preset_names()
    print(f"{'material':<13} {'tables':>6} {'time s':>7} {'MB':>6} {'compact err (99%)':>18}  particles per table")
    for name in names:
        cache = Path(tempfile.mkdtemp(prefix="pbvol-lut-"))
        t0 = time.perf_counter()
        recs = precompute(C.materials_dir() / f"{name}.toml", cache, None, None, True, True, lambda s: None)
        dt = time.perf_counter() - t0
        mb = sum(r["bytes"] for r in recs) / 1e6
        errs = ", ".join(f"{r['channels']} {100 * r['err_compact_vs_dense_99']:.1f}%" for r in recs)
        parts = ", ".join(f"{r['particles']}" for r in recs)
        print(f"{name:<13} {len(recs):>6} {dt:>7.1f} {mb:>6.2f} {errs:>18}  {parts}")
    for name in [m for m in args.noise.split(",") if m]:
        mat = C.load_material(C.materials_dir() / f"{name}.toml")
        sa, ss = mat.coefficients(mat.length_unit)
        alpha, chans = channel_tables(sa, ss)[0]
        kind = KINDS[mat.phase]
        base = resolve_particles(alpha, mat.g, kind, table_settings(C.LutSettings()))
        t0 = time.perf_counter()
        tab, S = build_table(alpha, mat.g, kind, base)
        t1 = time.perf_counter()
        big = replace(base, particles=16 * base.particles, seed=base.seed + 1)
        _, S16 = build_table(alpha, mat.g, kind, big)
        t2 = time.perf_counter()
        lay = base.layout
        V, om = lay.cell_volumes(), lay.dir_solid_angles()
        w = V[..., None] * om
        I16 = S16 @ om
        mask = energy_cells(I16 * V)
        tc, pc = lay.dir_centres()
        Bc = lobes.sh_at(tab.order, *np.meshgrid(tc, pc, indexing="ij"))
        shapes = np.empty((len(tab.leaf_kind), lay.n_dirs))
        sh = tab.leaf_kind == 0
        shapes[sh] = np.maximum(tab.coef[tab.leaf_slot[sh]] @ Bc.T, 0)
        shapes[~sh] = lobes.dequantise_all(tab.qlobe, tab.qmax)[tab.leaf_slot[~sh]]
        compact = tab.intensity.astype(float)[..., None] * shapes[tab.leaf]
        print(f"\nnoise {name} {''.join('RGB'[c] for c in chans)} (albedo {alpha:.4g}): default {base.particles} "
              f"particles ({t1 - t0:.1f} s) vs 16x ({t2 - t1:.1f} s): dense {100 * relative_error(S, S16, w, mask):.2f}%, "
              f"compact {100 * relative_error(compact, S16, w, mask):.2f}% (relative L2 over the cells holding 99% "
              f"of the energy, {mask.sum()} of {mask.size} cells)")


if __name__ == "__main__":
    main()
