"""The truncated forward peak's small deflections, kept along the camera paths and the caustic photons.

[render.pbl] similarity = "truncated" (similarity.py) takes the part of a Henyey-Greenstein lobe above its value at
cos = TRUNCATION_COS (f of the scattered light, 0.70 at g = 0.9) as no scattering: light deflected by less than 26
degrees goes straight on. Where that bias lives was measured with volpath on the bumpy sphere (docs/pbl.md, section
2, "The peak's deflections"): with the peak's deflections kept on every path vertex up to the path's first wider
scattering, and the medium truncated after it, volpath reads the medium as given (8 x 8 blocks 0.000008, under its
own noise, against the truncation's 0.0005). Those vertices are the camera paths' and the caustic photons' own.

So a camera path or a photon inside a truncated medium is turned at rate delta = f sigma_s (1 / scene unit) by a
deflection drawn from the peak (phase.truncated_peak_cos), and between deflections goes straight with the truncated
medium's transmittance. Drawn at the peak's own rate, a deflection needs no weight: the chance of none over a length
x, e^(-delta x), is the peak's share of the medium's full transmittance e^(-(sigma_t* + delta) x). With a chromatic
sigma_s the rate is the channels' least f sigma_s (any lower rate is exact with weight 1 as well); the rest of each
channel's peak stays truncated. The camera pass gathers the medium's terms straight on to the surface ahead, as
without the deflections (camera_pass._trace_batch): on the bumpy sphere the deflections changed the light beyond the
medium (the surface layer) ten times more than the medium's terms, and gathering along every piece cost 2.4 times
the pass.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.scene_build import MED_G, MED_PHASE, MED_SIGMA_S
from pbvol_cli.physics.phase import KINDS, truncated_peak_cos, truncated_share
from pbvol_cli.physics.sampling import around, mix64, rand

DEFLECTION_STREAM = np.uint64(0xDEF1EC7)  # a ray's deflection draws: its random state mixed with this stream
MAX_TURNS = 64  # deflections one camera path or photon takes at most (then it goes straight: a dense medium's
# paths would otherwise cost a wavefront generation each per deflection)


def peak_rates(media: np.ndarray) -> np.ndarray | None:
    """Each medium's deflection rate delta (1 / scene unit): the channels' least f sigma_s in a medium whose phase
    function is hg_truncated (sigma_s* = (1 - f) sigma_s there: f sigma_s = sigma_s* f / (1 - f)), 0 in the others;
    None where no medium deflects."""
    rates = np.zeros(len(media))
    for m, row in enumerate(media):
        if int(row[MED_PHASE]) == KINDS["hg_truncated"]:
            share = truncated_share(float(row[MED_G]))
            rates[m] = float(np.min(row[MED_SIGMA_S:MED_SIGMA_S + 3])) * (1.0 - share) / share
    return rates if np.any(rates > 0.0) else None


# (numba's parallel loop calls a plain kernel per ray: tuples returned by inlined helpers inside prange trip its
# array analysis, as in caustics.py)
@njit(parallel=True, cache=True)
def _draw(dirs, tmax, medium, turns, rates, media, rng, d_out, dir_out, state_out, turned):
    for i in prange(dirs.shape[0]):
        _draw_one(i, dirs, tmax, medium, turns, rates, media, rng, d_out, dir_out, state_out, turned)


@njit(cache=True)
def _draw_one(i, dirs, tmax, medium, turns, rates, media, rng, d_out, dir_out, state_out, turned):
    turned[i] = False
    m = medium[i]
    # (a ray that meets nothing has left its medium through a crack of the mesh: it is not turned, but ends as such)
    if m < 0 or turns[i] >= MAX_TURNS or rates[m] <= 0.0 or not math.isfinite(tmax[i]):
        return
    state_out[i] = mix64(rng[i] ^ DEFLECTION_STREAM)  # (the draws advance it in place: no array a ray)
    d = -math.log(1.0 - rand(state_out, i)) / rates[m]
    if not d < tmax[i]:
        return
    cos_t = truncated_peak_cos(media[m, MED_G], rand(state_out, i))
    w = around(cos_t, 2.0 * math.pi * rand(state_out, i), dirs[i, 0], dirs[i, 1], dirs[i, 2])
    d_out[i] = d
    dir_out[i, 0], dir_out[i, 1], dir_out[i, 2] = w[0], w[1], w[2]
    turned[i] = True


def draw_deflections(rates: np.ndarray, media: np.ndarray, dirs: np.ndarray, tmax: np.ndarray, medium: np.ndarray,
                     turns: np.ndarray, rng: np.ndarray):
    """The rays (directions dirs, each in medium[i] (-1: none) with tmax[i] to the next surface or emitter, turns[i]
    deflections taken so far, random state rng[i]) that meet a deflection before tmax (finite): (their indices, the distance
    to it (scene units), their new directions, their random states advanced past the draws: the caller stores them,
    so that what a turned ray draws next, or its children, does not repeat these draws)."""
    n = len(dirs)
    d, new_dir, state, turned = np.empty(n), np.empty((n, 3)), np.empty(n, np.uint64), np.empty(n, np.bool_)
    _draw(np.ascontiguousarray(dirs, np.float64), np.ascontiguousarray(tmax, np.float64),
          np.ascontiguousarray(medium, np.int64), np.ascontiguousarray(turns, np.int64), rates, media,
          np.ascontiguousarray(rng, np.uint64), d, new_dir, state, turned)
    idx = np.flatnonzero(turned)
    return idx, d[idx], new_dir[idx], state[idx]
