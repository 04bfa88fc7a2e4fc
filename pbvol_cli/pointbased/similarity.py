"""The delta-Eddington similarity transform of a forward-scattering medium (Joseph, Wiscombe and Weinman 1976).

A Henyey-Greenstein phase function of mean cosine g is split into a forward delta of weight f = g^2 and the rest.
Light scattered into the delta goes on as if unscattered, so the medium is replaced by one that scatters less, with
a broader lobe:

    sigma_s* = (1 - f) sigma_s,   sigma_a* = sigma_a,   g* = (g - f) / (1 - f) = g / (1 + g).

The transport coefficient sigma_a + (1 - g) sigma_s and the phase function's mean cosine f + (1 - f) g* are kept, so
diffusion, the multiple-scattering tables' far field and the light's reach are the same; what changes is the light
within a few degrees of a beam's direction (g = 0.9: half the lobe's peak lies within 5 degrees), which becomes part
of the attenuated beam. The point-based method samples that peak by a few discrete beam directions per point and a
few light-cut representatives: at g = 0.9 single, double and multiple scattering each carry spikes of 10-50x a
pixel's mean, and the transform removes them (docs/pbl.md, "Forward-peaked media").
"""

import numpy as np

from pbvol_cli.geometry.scene_build import MED_G, MED_MAJORANT, MED_PHASE, MED_SIGMA_A, MED_SIGMA_S
from pbvol_cli.physics.phase import KINDS


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
