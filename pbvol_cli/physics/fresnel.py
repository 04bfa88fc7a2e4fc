"""Smooth dielectric interfaces: Fresnel reflectance, Snell refraction, mirror reflection."""

import math

from numba import njit


@njit(inline="always", cache=True)
def fresnel_dielectric(cos_i, eta):
    """Unpolarised Fresnel reflectance.

    cos_i: cosine of the incident direction with the normal on the incident side (>= 0).
    eta: eta_transmitted / eta_incident. Returns (F, cos_t); F = 1 under total internal reflection.
    """
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    if sin2_t >= 1.0:
        return 1.0, 0.0
    cos_t = math.sqrt(1.0 - sin2_t)
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp), cos_t


@njit(inline="always", cache=True)
def reflect(dx, dy, dz, nx, ny, nz):
    """Mirror direction of the propagation direction d about the normal n."""
    c = 2.0 * (dx * nx + dy * ny + dz * nz)
    return dx - c * nx, dy - c * ny, dz - c * nz


@njit(inline="always", cache=True)
def refract(dx, dy, dz, nx, ny, nz, eta, cos_i, cos_t):
    """Refracted propagation direction (Snell), n on the incident side (d . n = -cos_i < 0),
    eta = eta_t / eta_i, cos_t from fresnel_dielectric."""
    inv = 1.0 / eta
    k = inv * cos_i - cos_t
    return inv * dx + k * nx, inv * dy + k * ny, inv * dz + k * nz
