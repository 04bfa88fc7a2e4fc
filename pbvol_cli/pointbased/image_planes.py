"""How far beyond a medium's curved boundary the multiple term's mirror images lie (sources.source_terms).

The multiple term reads the infinite medium's table and takes out the light that has left by mirror images of the
source in the boundary's tangent planes, each plane moved out by k transport mean free paths 1/sigma'_t. Far from a
source under a flat boundary the image leaves light in proportion to (z_s + k)(z_P + k) (z: depths below the
plane), where diffusion theory puts k at the Milne problem's 0.7104. Over a small body, whose boundary falls away
from the tangent plane within the distance light spreads, the plane's image keeps too much: 0.25 was measured on
spheres a few mean free paths across (the furnaces, the wax and milk examples). A body many reduced mean free paths
thick and many diffusion lengths 1/sigma_tr across is flat on the scale light spreads over, and there 0.25 read low,
the more the thicker: 0.68 of volpath's scattered light 120 reduced mean free paths thick behind eta 1.5, 0.86
index-matched (benchmarks/pbl_thickness.py, docs/pbl.md section 7). So k grows from 0.25 toward 0.7104 with the body's
half-thickness in diffusion lengths, x = sigma_tr R, sigma_tr = sqrt(3 sigma_a sigma'_t):
- behind a boundary that reflects, k = 0.25 + (0.7104 - 0.25) (1 - exp(-x / REFLECTING_SCALE));
- index-matched (no bounced light), k = 0.25 + (0.7104 - 0.25) (1 - exp(-(x / MATCHED_SCALE)^2)),
both fitted on grey spheres of albedo 0.999 and 0.99 from 15 to 240 reduced mean free paths thick, and only in
bodies thicker than GATE reduced mean free paths (a smoothstep between its two ends): the examples pbl was
measured on are at most 7 thick and keep 0.25. A non-absorbing body (x = 0) keeps 0.25 at any size.

Flat faces (flat_faces.py) start from their own value, volume_samples.FLAT_FACE_EXTRAPOLATION (the slab's furnace),
and reach the Milne value within about a diffusion length of half-thickness, whatever the boundary:
k = 0.45 + (0.7104 - 0.45) (1 - exp(-x / FLAT_SCALE)), behind the same gate. A flat face does not fall away from its
plane, so the far field rules there from a smaller body than under a curved boundary: fitted on grey boxes of albedo
0.999, 15 to 60 reduced mean free paths thick, behind eta 1.5 and index-matched (docs/pbl.md section 7).
"""

from __future__ import annotations

import numpy as np

from pbvol_cli.geometry.scene_build import BuiltScene
from pbvol_cli.pointbased.sources import transport_share
from pbvol_cli.pointbased.volume_samples import (CURVED_EXTRAPOLATION, DEFAULT_IMAGE_K, FLAT_FACE_EXTRAPOLATION,
                                                 medium_params)

MILNE_EXTRAPOLATION = 0.7104  # transport mean free paths: diffusion's extrapolated flat, index-matched boundary
REFLECTING_SCALE = 4.0  # diffusion lengths of half-thickness over which k nears the Milne value (boundary reflects)
MATCHED_SCALE = 4.86  # the same behind a null or index-matched boundary (a later, steeper rise)
GATE = (8.0, 15.0)  # reduced mean free paths thick: below the first, 0.25; from the second, the whole growth
FLAT_SCALE = 1.0  # diffusion lengths of half-thickness over which k nears the Milne value under a flat face


def _half_thickness(sigma_a: np.ndarray, sigma_s: np.ndarray, share: float, size: float):
    """(thick, x) per channel (3,): a body `size` thick (scene units) in reduced mean free paths, and half of it in
    diffusion lengths (sigma_tr = sqrt(3 sigma_a sigma'_t)); share: the phase function's transport share."""
    transport = sigma_a + share * sigma_s  # sigma'_t
    return size * transport, np.sqrt(3.0 * sigma_a * transport) * 0.5 * size


def _gate(thick: np.ndarray) -> np.ndarray:
    """0 below GATE[0] reduced mean free paths thick, 1 from GATE[1], a smoothstep between."""
    t = np.clip((thick - GATE[0]) / (GATE[1] - GATE[0]), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def image_growth(sigma_a: np.ndarray, sigma_s: np.ndarray, share: float, size: float, reflects: bool) -> np.ndarray:
    """The share (3,) in [0, 1] of the way from a small body's extrapolation to the Milne value that the curved
    parts of a body `size` thick along its thinnest axis (scene units) of sigma_a, sigma_s (3,) (1/scene unit) have
    gone, its phase function's transport share `share` (sources.transport_share); reflects: whether its boundary
    reflects light back into it (BuiltScene.reflects_into)."""
    thick, x = _half_thickness(sigma_a, sigma_s, share, size)
    rise = 1.0 - (np.exp(-x / REFLECTING_SCALE) if reflects else np.exp(-(x / MATCHED_SCALE) ** 2))
    return _gate(thick) * rise


def flat_growth(sigma_a: np.ndarray, sigma_s: np.ndarray, share: float, size: float) -> np.ndarray:
    """The same share (3,) under the flat faces of that body (module docstring: FLAT_SCALE, either boundary)."""
    thick, x = _half_thickness(sigma_a, sigma_s, share, size)
    return _gate(thick) * (1.0 - np.exp(-x / FLAT_SCALE))


def curved_extrapolation(sigma_a: np.ndarray, sigma_s: np.ndarray, share: float, size: float,
                         reflects: bool) -> np.ndarray:
    """k per channel (3,) under the curved parts of the boundary of a body as image_growth takes it."""
    grown = image_growth(sigma_a, sigma_s, share, size, reflects)
    return CURVED_EXTRAPOLATION + (MILNE_EXTRAPOLATION - CURVED_EXTRAPOLATION) * grown


def flat_extrapolation(sigma_a: np.ndarray, sigma_s: np.ndarray, share: float, size: float) -> np.ndarray:
    """k per channel (3,) under the flat faces of the same body: from FLAT_FACE_EXTRAPOLATION toward the Milne
    value by flat_growth."""
    grown = flat_growth(sigma_a, sigma_s, share, size)
    return FLAT_FACE_EXTRAPOLATION + (MILNE_EXTRAPOLATION - FLAT_FACE_EXTRAPOLATION) * grown


def medium_extrapolation(bs: BuiltScene, m: int) -> np.ndarray:
    """(2, 3): curved_extrapolation (row 0, IMAGE_CURVED) and flat_extrapolation (row 1, IMAGE_FLAT) of medium m's
    body in a built scene (its bounding box's smallest side); the small bodies' values where it has no bounding
    surface."""
    side = bs.medium_side(m)
    if side is None:
        return DEFAULT_IMAGE_K.copy()
    med = medium_params(bs.media, m)
    args = (med.sigma_a, med.sigma_s, transport_share(med.phase, med.g), side)
    return np.stack([curved_extrapolation(*args, bs.reflects_into(m)), flat_extrapolation(*args)])
