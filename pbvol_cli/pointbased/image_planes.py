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
measured on are at most 7 thick and keep 0.25. A non-absorbing body (x = 0) keeps 0.25 at any size. Flat faces
(flat_faces.py) start from their own value, volume_samples.FLAT_FACE_EXTRAPOLATION (the slab's furnace), and grow by the
same law toward the same limit: a thick body is flat on the scale light spreads over whatever its faces' shape.
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


def image_growth(sigma_a: np.ndarray, sigma_s: np.ndarray, share: float, size: float, reflects: bool) -> np.ndarray:
    """The share (3,) in [0, 1] of the way from a small body's extrapolation to the Milne value that a body `size`
    thick along its thinnest axis (scene units) of sigma_a, sigma_s (3,) (1/scene unit) has gone, its phase
    function's transport share `share` (sources.transport_share); reflects: whether its boundary reflects light
    back into it (BuiltScene.reflects_into)."""
    transport = sigma_a + share * sigma_s  # sigma'_t
    thick = size * transport  # reduced mean free paths
    x = np.sqrt(3.0 * sigma_a * transport) * 0.5 * size  # half the thickness in diffusion lengths
    t = np.clip((thick - GATE[0]) / (GATE[1] - GATE[0]), 0.0, 1.0)
    gate = t * t * (3.0 - 2.0 * t)
    rise = 1.0 - (np.exp(-x / REFLECTING_SCALE) if reflects else np.exp(-(x / MATCHED_SCALE) ** 2))
    return gate * rise


def curved_extrapolation(sigma_a: np.ndarray, sigma_s: np.ndarray, share: float, size: float,
                         reflects: bool) -> np.ndarray:
    """k per channel (3,) under the curved parts of the boundary of a body as image_growth takes it."""
    grown = image_growth(sigma_a, sigma_s, share, size, reflects)
    return CURVED_EXTRAPOLATION + (MILNE_EXTRAPOLATION - CURVED_EXTRAPOLATION) * grown


def flat_extrapolation(sigma_a: np.ndarray, sigma_s: np.ndarray, share: float, size: float,
                       reflects: bool) -> np.ndarray:
    """k per channel (3,) under the flat faces of the same body: from FLAT_FACE_EXTRAPOLATION toward the Milne
    value, by the same growth."""
    grown = image_growth(sigma_a, sigma_s, share, size, reflects)
    return FLAT_FACE_EXTRAPOLATION + (MILNE_EXTRAPOLATION - FLAT_FACE_EXTRAPOLATION) * grown


def medium_extrapolation(bs: BuiltScene, m: int) -> np.ndarray:
    """(2, 3): curved_extrapolation (row 0, IMAGE_CURVED) and flat_extrapolation (row 1, IMAGE_FLAT) of medium m's
    body in a built scene (its bounding box's smallest side); the small bodies' values where it has no bounding
    surface."""
    side = bs.medium_side(m)
    if side is None:
        return DEFAULT_IMAGE_K.copy()
    med = medium_params(bs.media, m)
    args = (med.sigma_a, med.sigma_s, transport_share(med.phase, med.g), side, bs.reflects_into(m))
    return np.stack([curved_extrapolation(*args), flat_extrapolation(*args)])
