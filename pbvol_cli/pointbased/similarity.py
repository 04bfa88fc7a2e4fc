"""Similarity transforms of a forward-scattering medium: its forward peak folded into the beams.

Both split a Henyey-Greenstein phase function of mean cosine g > 0 into a forward part of weight f, treated as no
scattering at all (light scattered into it goes on as if unscattered), and the rest, so the medium is replaced by
one that scatters less (sigma_s* = (1 - f) sigma_s, sigma_a unchanged) with a lobe free of the peak. The
point-based method samples a sharp peak by a few discrete beam directions per point and a few light-cut
representatives: at g = 0.9 single, double and multiple scattering each carry spikes of 10-50x a pixel's mean,
which the transforms remove (docs/pbl.md, "Forward-peaked media").

- delta-Eddington (Joseph, Wiscombe and Weinman 1976): f = g^2 and the rest a Henyey-Greenstein lobe of
  g* = (g - f) / (1 - f) = g / (1 + g). The transport coefficient sigma_a + (1 - g) sigma_s and the mean cosine
  f + (1 - f) g* are kept; the lobe's shape is not: at g = 0.9 it scatters 40 % more light sideways and half as
  much at 30 degrees as the lobe it stands for, which moves light within a body a few mean free paths across.
- truncated (Potter 1970's truncation of the peak): the lobe capped at its own value at cos = TRUNCATION_COS
  (physics/phase.py, kind hg_truncated), f the part above the cap (0.70 at g = 0.9). Beyond 26 degrees the phase
  function is the medium's own; the light deflected by less is taken as going straight. Its lobe peaks higher
  (7.6 / 4 pi against 5.3 / 4 pi for g* at g = 0.9): noisier in a first pass, less biased.
"""

import numpy as np

from pbvol_cli.geometry.scene_build import MED_G, MED_MAJORANT, MED_PHASE, MED_SIGMA_A, MED_SIGMA_S
from pbvol_cli.physics.phase import KINDS, truncated_share

TRUNCATED_MIN_G = 0.05  # below, the truncated peak holds under 0.05 % of the light (f about 1.5 g / 200)


def delta_eddington_coefficients(sigma_s: np.ndarray, g: float) -> tuple[np.ndarray, float]:
    """(sigma_s*, g*) of a Henyey-Greenstein medium of scattering coefficient sigma_s (RGB, 1/length) and mean cosine
    g > 0 (module docstring); sigma_a is unchanged."""
    f = g * g
    return np.asarray(sigma_s, float) * (1.0 - f), g / (1.0 + g)


def transformed(phase: str, g: float) -> bool:
    """Whether the transform changes a medium of this phase function (a name of physics.phase.KINDS) and g: only
    Henyey-Greenstein lobes of g > 0 (a backward lobe has no forward peak to fold into the beam)."""
    return phase == "hg" and g > 0.0


def delta_eddington(media: np.ndarray) -> np.ndarray:
    """A copy of the media table (scene_build's MED_* columns; coefficients in 1/scene units) with each
    Henyey-Greenstein medium of g > 0 transformed as in the module docstring (its majorant lowered with it: the
    point-based method takes homogeneous media only); other media are left as they are (transformed())."""
    names = {v: k for k, v in KINDS.items()}
    out = media.copy()
    for row in out:
        g = float(row[MED_G])
        if not transformed(names[int(row[MED_PHASE])], g):
            continue
        row[MED_SIGMA_S:MED_SIGMA_S + 3], row[MED_G] = delta_eddington_coefficients(row[MED_SIGMA_S:MED_SIGMA_S + 3], g)
        row[MED_MAJORANT] = float(np.max(row[MED_SIGMA_A:MED_SIGMA_A + 3] + row[MED_SIGMA_S:MED_SIGMA_S + 3]))
    return out


def truncated_coefficients(sigma_s: np.ndarray, g: float) -> np.ndarray:
    """sigma_s* of a Henyey-Greenstein medium (g > 0) whose lobe is capped (module docstring): (1 - f) sigma_s; its
    phase function is then hg_truncated of the same g."""
    return np.asarray(sigma_s, float) * truncated_share(g)


def truncated(media: np.ndarray) -> np.ndarray:
    """A copy of the media table with each Henyey-Greenstein medium of g >= TRUNCATED_MIN_G truncated as in the
    module docstring (phase kind hg_truncated, g kept, sigma_s scaled, the majorant lowered with it); other media
    are left as they are."""
    names = {v: k for k, v in KINDS.items()}
    out = media.copy()
    for row in out:
        g = float(row[MED_G])
        if not transformed(names[int(row[MED_PHASE])], g) or g < TRUNCATED_MIN_G:
            continue
        row[MED_SIGMA_S:MED_SIGMA_S + 3] = truncated_coefficients(row[MED_SIGMA_S:MED_SIGMA_S + 3], g)
        row[MED_PHASE] = KINDS["hg_truncated"]
        row[MED_MAJORANT] = float(np.max(row[MED_SIGMA_A:MED_SIGMA_A + 3] + row[MED_SIGMA_S:MED_SIGMA_S + 3]))
    return out


TRANSFORMS = {"delta-eddington": delta_eddington, "truncated": truncated}  # [render.pbl] similarity's choices
NAMES = {"delta-eddington": "delta-Eddington", "truncated": "truncated peak"}  # as messages name them
