"""The dipole diffusion profile R_d (Jensen, Marschner, Levoy, Hanrahan 2001; seed 003, "Dipole diffusion
approximation").

A collimated beam of power Phi entering a semi-infinite medium at the origin is replaced by two point sources on
the normal: a real one at depth z_r = 1/sigma'_t below the surface and a negative virtual one at height z_v =
z_r + 4 A D above it, so that the fluence vanishes on the extrapolated boundary 2 A D above the surface. The
radiant exitance (W per area) that crosses the boundary out at distance r from the entry point is R_d(r) Phi:

    R_d(r) = alpha' / (4 pi) [z_r (sigma_tr d_r + 1) e^(-sigma_tr d_r) / d_r^3
                              + z_v (sigma_tr d_v + 1) e^(-sigma_tr d_v) / d_v^3],
    d_r = sqrt(r^2 + z_r^2), d_v = sqrt(r^2 + z_v^2),

with sigma'_s = (1 - g) sigma_s, sigma'_t = sigma_a + sigma'_s, alpha' = sigma'_s / sigma'_t, sigma_tr =
sqrt(3 sigma_a sigma'_t), D = 1 / (3 sigma'_t) and A = (1 + F_dr) / (1 - F_dr), F_dr the boundary's diffuse
reflectance seen from inside. (The slides' version drops alpha' and writes the virtual source's height as a
negative z: garbled; the form above integrates to the closed-form total below.)

Its integral over the plane, by d dd = r dr and d/dd (-e^(-s d) / d) = (s d + 1) e^(-s d) / d^2, is

    R_d,total = alpha' / 2 (e^(-sigma_tr z_r) + e^(-sigma_tr z_v))
              = alpha' / 2 (1 + e^(-4/3 A sqrt(3 (1 - alpha')))) e^(-sqrt(3 (1 - alpha'))),

the diffuse reflectance of Jensen et al.'s table. Lengths in scene units, coefficients per scene unit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pbvol_cli.physics.fresnel import fresnel_dielectric

# columns of a medium's dipole parameters, one row per RGB channel (dipole_params)
P_ALPHA, P_SIGMA_TR, P_Z_R, P_D = 0, 1, 2, 3
PARAM_COLS = 4
DIFFUSE_FRESNEL_STEPS = 4096  # midpoint rule over cos theta (the total-internal-reflection kink costs 1e-4)


def diffuse_fresnel(eta: float, steps: int = DIFFUSE_FRESNEL_STEPS) -> float:
    """F_dr: the hemispherical, cosine-weighted Fresnel reflectance of a smooth interface, (1/pi) int F(w) cos dw
    = 2 int_0^1 F(mu) mu dmu, for light arriving from the side of index 1 at a side of relative index eta
    (eta_far / eta_near). Seen from inside a medium of index 1.5 in air: eta = 1/1.5, F_dr = 0.596 (Jensen's fit
    -1.440/eta'^2 + 0.710/eta' + 0.668 + 0.0636 eta' of eta' = 1.5 reads 0.597); from outside: eta = 1.5,
    0.092. Exact, by the midpoint rule."""
    if eta == 1.0:
        return 0.0
    mu = (np.arange(steps) + 0.5) / steps
    return float(2.0 * np.mean(_fresnel_all(mu, float(eta)) * mu))


@njit(cache=True)
def _fresnel_all(mu, eta):
    out = np.empty(mu.shape[0])
    for k in range(mu.shape[0]):
        out[k] = fresnel_dielectric(mu[k], eta)[0]
    return out


def boundary_a(eta: float) -> float:
    """A = (1 + F_dr) / (1 - F_dr): how much farther than 2 D the fluence reaches past the boundary, for a medium of
    relative index eta (its own over the outside's), F_dr its internal diffuse reflectance."""
    f = diffuse_fresnel(1.0 / eta)
    return (1.0 + f) / (1.0 - f)


def exit_normalisation(eta: float) -> float:
    """1 / (1 - F_dr,outside(eta)): the exitance R_d Phi leaves as radiance L(w) = F_t(w) R_d Phi / (pi c), c = (1/pi)
    int F_t(w) cos dw over the outside, so that it carries the whole exitance. (Inside, near the boundary, the
    diffuse light is close to isotropic; what crosses is weighted by the Fresnel transmittance; c = 1 - F_dr seen
    from outside, 0.908 at eta 1.5. The slides' L_o = (1/pi) F_t F_dt M_o leaves c out, 9 % less light at 1.5.)"""
    return 1.0 / (1.0 - diffuse_fresnel(eta))


def dipole_params(sigma_a, sigma_s, g: float) -> np.ndarray:
    """(3, PARAM_COLS) per RGB channel: alpha', sigma_tr, z_r, D (scene units). A channel without scattering
    (sigma'_t = 0 or alpha' = 0) gets alpha' = 0: no diffusion."""
    sigma_a = np.asarray(sigma_a, float)
    sigma_sp = (1.0 - g) * np.asarray(sigma_s, float)
    sigma_tp = sigma_a + sigma_sp
    out = np.zeros((3, PARAM_COLS))
    ok = sigma_tp > 0
    out[ok, P_ALPHA] = sigma_sp[ok] / sigma_tp[ok]
    out[ok, P_SIGMA_TR] = np.sqrt(3.0 * sigma_a[ok] * sigma_tp[ok])
    out[ok, P_Z_R] = 1.0 / sigma_tp[ok]
    out[ok, P_D] = 1.0 / (3.0 * sigma_tp[ok])
    return out


@njit(inline="always", cache=True)
def rd(params, c, a, r2):
    """R_d (per scene unit^2) of channel c at squared distance r2 from the entry point; a: the boundary's A."""
    alpha = params[c, P_ALPHA]
    if alpha <= 0.0:
        return 0.0
    s, zr = params[c, P_SIGMA_TR], params[c, P_Z_R]
    zv = zr + 4.0 * a * params[c, P_D]
    dr = math.sqrt(r2 + zr * zr)
    dv = math.sqrt(r2 + zv * zv)
    return alpha / (4.0 * math.pi) * (zr * (s * dr + 1.0) * math.exp(-s * dr) / (dr * dr * dr)
                                      + zv * (s * dv + 1.0) * math.exp(-s * dv) / (dv * dv * dv))


@njit(cache=True)
def rd_profile(params, a, r, out):
    """R_d at the distances r (n,) for the three channels into out (n, 3)."""
    for k in range(r.shape[0]):
        for c in range(3):
            out[k, c] = rd(params, c, a, r[k] * r[k])


def total_diffuse_reflectance(params: np.ndarray, a: float) -> np.ndarray:
    """R_d integrated over the plane, RGB: alpha' / 2 (e^(-sigma_tr z_r) + e^(-sigma_tr z_v))."""
    alpha, s, zr, d = (params[:, k] for k in (P_ALPHA, P_SIGMA_TR, P_Z_R, P_D))
    return alpha / 2.0 * (np.exp(-s * zr) + np.exp(-s * (zr + 4.0 * a * d)))
