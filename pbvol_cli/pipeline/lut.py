"""The precompute-lut stage: multiple-scattering tables in the cache, keyed by what determines them.

One table per distinct (albedo, g, phase) of a medium's RGB channels. A cached entry is reused when its key
matches; a damaged entry (unreadable, incomplete, inconsistent) is rebuilt, not trusted.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pbvol_cli.config import LutSettings
from pbvol_cli.multiple_scattering.extent import DEFAULT_EXTENT, table_extents
from pbvol_cli.multiple_scattering.layout import Layout
from pbvol_cli.multiple_scattering.table import MSTable, TableSettings, build_table, resolve_particles
from pbvol_cli.pipeline.cache import cached_entry, key_of


@dataclass
class TableResult:
    table: MSTable
    path: Path
    reused: bool
    seconds: float


def table_settings(lut: LutSettings, particles: int | None = None, seed: int | None = None,
                   extent: float | None = None) -> TableSettings:
    """The table builder's settings from a scene's [render.lut] (particles and seed: command-line overrides;
    extent, mean free paths: the one table_groups chose, else lut.extent's number or DEFAULT_EXTENT)."""
    if extent is None:
        extent = DEFAULT_EXTENT if lut.extent == "auto" else float(lut.extent)
    return TableSettings(particles=particles or lut.particles, collision_budget=lut.collision_budget,
                         seed=lut.seed if seed is None else seed,
                         layout=Layout(extent=extent, kill_radius=2.0 * extent),
                         sh_order=lut.sh_order, merge_tol=lut.merge_tol)


def table_groups(sigma_a: np.ndarray, sigma_s: np.ndarray, g: float, side: float | None, lut: LutSettings,
                 particles: int | None = None, seed: int | None = None) -> list[tuple[float, list[int], TableSettings]]:
    """A medium's tables as (albedo, the RGB channels that read it, its settings), its extent from lut.extent and
    the body's smallest side (scene units; None: unknown) as multiple_scattering/extent.py says."""
    extents = table_extents(sigma_a, sigma_s, g, side, lut.extent)
    return [(alpha, channels, table_settings(lut, particles, seed, float(extents[channels[0]])))
            for alpha, channels in channel_tables(sigma_a, sigma_s)]


def table_path(cache: Path, alpha: float, g: float, phase_kind: int, settings: TableSettings) -> Path:
    key = key_of(kind="ms-table", alpha=round(float(alpha), 9), g=round(float(g), 9), phase=int(phase_kind),
                 **settings.key_parts())
    return Path(cache) / "lut" / f"ms_a{alpha:.4f}_g{g:+.3f}_{key}.npz"


def get_table(alpha: float, g: float, phase_kind: int, settings: TableSettings, cache: Path, force: bool = False,
              progress=None) -> TableResult:
    """The table for (alpha, g, phase), from the cache or built and stored (atomically)."""
    t0 = time.perf_counter()
    settings = resolve_particles(alpha, g, phase_kind, settings)
    path = table_path(cache, alpha, g, phase_kind, settings)
    table, reused = cached_entry(path, MSTable.REQUIRED, MSTable.from_arrays,
                                 lambda: build_table(alpha, g, phase_kind, settings, progress)[0], force)
    return TableResult(table, path, reused, time.perf_counter() - t0)


def channel_tables(sigma_a: np.ndarray, sigma_s: np.ndarray) -> list[tuple[float, list[int]]]:
    """Distinct albedos of a medium and the RGB channels that use each (channels without extinction skipped)."""
    out: dict[float, list[int]] = {}
    for c in range(3):
        st = sigma_a[c] + sigma_s[c]
        if st > 0:
            out.setdefault(round(float(sigma_s[c] / st), 12), []).append(c)
    return sorted(out.items())
