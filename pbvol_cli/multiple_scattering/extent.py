"""How far the multiple-scattering table must reach for a body: its half-size R in mean free paths.

Light that diffuses past the table's R (less its taper, table.TAPER_START) is lost to pbl's multiple term. In a body
thick in diffusion lengths 1/sigma_tr, sigma_tr = sqrt(3 sigma_a sigma'_t), light spreads over about TABLE_REACH
diffusion lengths, no farther than the body's smallest side. In mean free paths that is
L = min(TABLE_REACH / sigma_tr, side) sigma_t: for g = 0 and albedo 0.999 about 36, for g = 0.8 and albedo 0.9998
about 180 (the transport mean free path is 5 mean free paths there). `[render.lut] extent = "auto"` takes
max(DEFAULT_EXTENT, L) rounded up to EXTENT_STEP, at most AUTO_EXTENT_MAX; a number is taken as given.
"""

from __future__ import annotations

import math

import numpy as np

DEFAULT_EXTENT = 40.0  # mean free paths: the table of a body without a size (a material file), and the least
TABLE_REACH = 2.0  # diffusion lengths that light spreads over: a grey sphere of g 0.8, 150 mean free paths across,
# read 0.68 of volpath's scattered light with a table of 40 and 0.94 with 160 (docs/pbl.md, section 7)
EXTENT_STEP = 40.0  # auto extents are rounded up to a multiple: bodies of nearly one size share a table
AUTO_EXTENT_MAX = 320.0  # a wider table spends its collision budget on few particles (particles that wander as far)


def light_spread(sigma_a: np.ndarray, sigma_s: np.ndarray, g: float, side: float) -> np.ndarray:
    """Per channel, the mean free paths over which light spreads in a body whose smallest side is `side` (scene
    units; sigma_a, sigma_s per scene unit): the smaller of TABLE_REACH diffusion lengths and the side. 0 for a
    channel without extinction; the side for one without absorption."""
    sigma_a, sigma_s = np.asarray(sigma_a, float), np.asarray(sigma_s, float)
    st = sigma_a + sigma_s
    transport = sigma_a + (1.0 - g) * sigma_s
    with np.errstate(divide="ignore", invalid="ignore"):
        diffusion = np.where(sigma_a > 0, TABLE_REACH / np.sqrt(3.0 * sigma_a * transport), np.inf)
    return np.where(st > 0, np.minimum(diffusion, side) * st, 0.0)


def auto_extent(spread: float) -> float:
    """The table's half-size (mean free paths) that holds light spreading over `spread` mean free paths: at least
    DEFAULT_EXTENT, a multiple of EXTENT_STEP, at most AUTO_EXTENT_MAX."""
    return min(max(DEFAULT_EXTENT, EXTENT_STEP * math.ceil(spread / EXTENT_STEP - 1e-9)), AUTO_EXTENT_MAX)


def table_extents(sigma_a: np.ndarray, sigma_s: np.ndarray, g: float, side: float | None,
                  extent: float | str) -> np.ndarray:
    """Per channel, the extent of the table it reads: `extent` when it is a number, else (\"auto\") auto_extent of
    the largest light_spread among the channels of its albedo (they share a table); DEFAULT_EXTENT without a side
    (side: the body's smallest side, scene units, None when unknown)."""
    if extent != "auto":
        return np.full(3, float(extent))
    if side is None:
        return np.full(3, DEFAULT_EXTENT)
    spread = light_spread(sigma_a, sigma_s, g, side)
    st = np.asarray(sigma_a, float) + np.asarray(sigma_s, float)
    albedo = np.round(np.where(st > 0, np.asarray(sigma_s, float) / np.maximum(st, 1e-300), 0.0), 12)
    return np.array([auto_extent(float(np.max(spread[albedo == albedo[c]]))) for c in range(3)])
