"""A ray meeting a surface, the same in every integrator: from which side it comes, the normals on that side, the
indices and media on either side, Fresnel at a smooth dielectric, and the length of a shadow ray.

Surface rows are the built scene's (geometry/scene_build.py, columns SURF_*); normals are given pointing to the
surface's exterior, as the scene stores them; directions are unit propagation directions.
"""

from numba import njit

from pbvol_cli.geometry.scene_build import SURF_ETA_IN, SURF_ETA_OUT, SURF_MEDIUM_IN, SURF_MEDIUM_OUT
from pbvol_cli.physics.fresnel import fresnel_dielectric, reflect, refract

MIN_COS = 1e-9  # cosines of grazing incidence are clamped to this (Fresnel and refraction stay finite)


@njit(inline="always", cache=True)
def incident_side(dx, dy, dz, gx, gy, gz, nx, ny, nz):
    """(entering, geometric normal, shading normal), both normals turned to the side the ray comes from: entering
    is True when the ray comes from the exterior. A shading normal that ends up below the geometric surface
    (interpolated normals near a silhouette) is replaced by the geometric one."""
    entering = dx * gx + dy * gy + dz * gz < 0.0
    sg = 1.0 if entering else -1.0
    fgx, fgy, fgz = sg * gx, sg * gy, sg * gz
    fnx, fny, fnz = sg * nx, sg * ny, sg * nz
    if fnx * fgx + fny * fgy + fnz * fgz <= 0.0:
        fnx, fny, fnz = fgx, fgy, fgz
    return entering, fgx, fgy, fgz, fnx, fny, fnz


@njit(inline="always", cache=True)
def indices(surfaces, s, entering):
    """(eta_i, eta_t): the refractive index on the side the ray comes from and on the far side of surface s."""
    if entering:
        return surfaces[s, SURF_ETA_OUT], surfaces[s, SURF_ETA_IN]
    return surfaces[s, SURF_ETA_IN], surfaces[s, SURF_ETA_OUT]


@njit(inline="always", cache=True)
def medium_beyond(surfaces, s, entering):
    """The medium on the far side of surface s (-1: vacuum)."""
    return int(surfaces[s, SURF_MEDIUM_IN]) if entering else int(surfaces[s, SURF_MEDIUM_OUT])


@njit(inline="always", cache=True)
def dielectric_fresnel(eta_i, eta_t, dx, dy, dz, nx, ny, nz):
    """(cos_i, F, cos_t) of a ray of direction d meeting a smooth dielectric whose normal n faces it; F = 1 under
    total internal reflection."""
    cos_i = max(-(dx * nx + dy * ny + dz * nz), MIN_COS)
    F, cos_t = fresnel_dielectric(cos_i, eta_t / eta_i)
    return cos_i, F, cos_t


@njit(inline="always", cache=True)
def dielectric_choice(surfaces, s, entering, dx, dy, dz, nx, ny, nz, u):
    """A ray of direction d meeting smooth dielectric s (normal n facing it) reflects with the Fresnel probability
    (u uniform in [0, 1)) and refracts otherwise. Returns (wx, wy, wz, refracted, eta_i, eta_t)."""
    eta_i, eta_t = indices(surfaces, s, entering)
    cos_i, F, cos_t = dielectric_fresnel(eta_i, eta_t, dx, dy, dz, nx, ny, nz)
    if u < F:
        wx, wy, wz = reflect(dx, dy, dz, nx, ny, nz)
        return wx, wy, wz, False, eta_i, eta_t
    wx, wy, wz = refract(dx, dy, dz, nx, ny, nz, eta_t / eta_i, cos_i, cos_t)
    return wx, wy, wz, True, eta_i, eta_t


@njit(inline="always", cache=True)
def shadow_ray_length(dist, eps):
    """How far a shadow ray toward a point at distance dist goes (from an origin offset by eps): short of the point,
    so that it does not hit the light it aims at; an infinite distance stays infinite. Scalars or arrays."""
    return dist * (1.0 - 1e-7) - 2.0 * eps
