"""Cell and direction layout of the table.

Cells: rho in [0, R], z in [-R, R] (mean free paths), with a log warp that resolves both the peak near the source
and the far tail: u(rho) = log(1 + rho/s) / log(1 + R/s), u(z) = sign(z) log(1 + |z|/s) / log(1 + R/s); cells are
uniform in u. Directions: theta in [0, pi] (from the source axis) and phi in [0, pi] (from the radial direction;
the field is symmetric under phi -> -phi, a reflection through the plane of the axis and the point).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from numba import njit


@dataclass(frozen=True)
class Layout:
    extent: float = 40.0  # R, mean free paths
    n_rho: int = 64
    n_z: int = 128
    warp: float = 0.05  # s, mean free paths: cells are ~s wide near the source
    n_theta: int = 18
    n_phi: int = 18  # over [0, pi]
    kill_radius: float = 80.0  # particles farther than this are dropped (they rarely come back)

    def params(self) -> np.ndarray:
        """Float array for the kernels: [R, n_rho, n_z, s, n_theta, n_phi, kill, log1p(R/s)]."""
        return np.array([self.extent, self.n_rho, self.n_z, self.warp, self.n_theta, self.n_phi,
                         self.kill_radius, math.log1p(self.extent / self.warp)])

    def as_dict(self) -> dict:
        return asdict(self)

    @property
    def n_cells(self) -> int:
        return self.n_rho * self.n_z

    @property
    def n_dirs(self) -> int:
        return self.n_theta * self.n_phi

    def rho_edges(self) -> np.ndarray:
        u = np.linspace(0, 1, self.n_rho + 1)
        return self.warp * np.expm1(u * math.log1p(self.extent / self.warp))

    def z_edges(self) -> np.ndarray:
        u = np.linspace(-1, 1, self.n_z + 1)
        return np.sign(u) * self.warp * np.expm1(np.abs(u) * math.log1p(self.extent / self.warp))

    def cell_volumes(self) -> np.ndarray:
        """(n_rho, n_z) volumes of the ring cells."""
        r, z = self.rho_edges(), self.z_edges()
        return np.pi * np.outer(np.diff(r ** 2), np.diff(z))

    def cell_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """rho and z at the centres of the cells in warped coordinates (where lookups are exact)."""
        u = (np.arange(self.n_rho) + 0.5) / self.n_rho
        rho = self.warp * np.expm1(u * math.log1p(self.extent / self.warp))
        uz = -1 + 2 * (np.arange(self.n_z) + 0.5) / self.n_z
        z = np.sign(uz) * self.warp * np.expm1(np.abs(uz) * math.log1p(self.extent / self.warp))
        return rho, z

    def dir_edges(self) -> tuple[np.ndarray, np.ndarray]:
        return np.linspace(0, np.pi, self.n_theta + 1), np.linspace(0, np.pi, self.n_phi + 1)

    def dir_centres(self) -> tuple[np.ndarray, np.ndarray]:
        te, pe = self.dir_edges()
        return 0.5 * (te[1:] + te[:-1]), 0.5 * (pe[1:] + pe[:-1])

    def dir_solid_angles(self) -> np.ndarray:
        """(n_theta * n_phi,) solid angle of each direction bin over the full sphere (both signs of phi)."""
        te, pe = self.dir_edges()
        band = np.cos(te[:-1]) - np.cos(te[1:])
        return (2.0 * np.outer(band, np.diff(pe))).ravel()


@njit(inline="always", cache=True)
def warp_rho(p, rho):
    """Continuous cell coordinate of rho in [0, n_rho] (beyond n_rho: outside)."""
    return math.log1p(rho / p[3]) / p[7] * p[1]


@njit(inline="always", cache=True)
def warp_z(p, z):
    """Continuous cell coordinate of z in [0, n_z]."""
    u = math.log1p(abs(z) / p[3]) / p[7]
    return (0.5 + 0.5 * (u if z >= 0.0 else -u)) * p[2]


def cos_edges(n: int) -> np.ndarray:
    """Cosines of the n + 1 uniform angle edges over [0, pi] (decreasing from 1 to -1)."""
    return np.cos(np.linspace(0.0, np.pi, n + 1))


@njit(inline="always", cache=True)
def _angle_bin(c, edges):
    """Bin of the angle whose cosine is c, given the decreasing cosines of the bin edges (binary search)."""
    lo, hi = 0, edges.shape[0] - 2
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if c <= edges[mid]:
            lo = mid
        else:
            hi = mid - 1
    return lo


@njit(inline="always", cache=True)
def local_dir_bin(x, y, rho, wx, wy, wz, theta_cos_edges, phi_cos_edges):
    """Direction bin of w in the frame of a point at (x, y, .) with radius rho: axis +z, radial (x, y).

    theta = acos(w_z); |phi| = angle between w's projection and the radial direction. No acos/atan2: the bins
    are found by comparing cosines with the edges' cosines."""
    if rho > 0.0:
        a = (wx * x + wy * y) / rho
    else:
        a = wx
    b2 = max(0.0, 1.0 - wz * wz)
    cphi = a / math.sqrt(b2) if b2 > 0.0 else 1.0
    cphi = min(1.0, max(-1.0, cphi))
    return _angle_bin(wz, theta_cos_edges) * (phi_cos_edges.shape[0] - 1) + _angle_bin(cphi, phi_cos_edges)
