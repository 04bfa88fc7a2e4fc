"""A conservative lower bound on the distance to the nearest triangle, stored on a voxel grid.

Free-flight sampling inside a dense medium would cost one ray cast per scattering event. If the sampled
distance is shorter than a lower bound on the distance to any surface, the event is inside the medium for
certain and no cast is needed. Cells overlapped by a triangle's bounding box are marked; each cell stores
its Chebyshev distance k (in cells) to the nearest marked cell. Any point of that cell is then at least
(k - 1) * h from every triangle. The grid's border layer is marked too, so triangles outside the grid are
accounted for.

Layout of ``params`` (columns GRID_*): the grid's origin (3), its cell size h, its cell counts (3) and a state:
GRID_READY, a grid; GRID_NO_TRIANGLES, the bound is +inf; GRID_NONE, triangles but no grid (no medium region to
cover), the bound is 0.
"""

import math

import numpy as np
from numba import njit

MAX_CELLS = 128
GRID_ORIGIN, GRID_CELL, GRID_COUNTS, GRID_STATE = 0, 3, 4, 7
GRID_READY, GRID_NO_TRIANGLES, GRID_NONE = 1.0, 0.0, -1.0


@njit(cache=True)
def _mark(V, F, ox, oy, oz, h, nx, ny, nz, pad, dist):
    big = 32000
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                border = i == 0 or j == 0 or k == 0 or i == nx - 1 or j == ny - 1 or k == nz - 1
                dist[i, j, k] = 0 if border else big
    for f in range(F.shape[0]):
        lo = np.empty(3)
        hi = np.empty(3)
        for a in range(3):
            v0, v1, v2 = V[F[f, 0], a], V[F[f, 1], a], V[F[f, 2], a]
            lo[a] = min(v0, min(v1, v2)) - pad
            hi[a] = max(v0, max(v1, v2)) + pad
        i0 = max(0, int(math.floor((lo[0] - ox) / h)))
        i1 = min(nx - 1, int(math.floor((hi[0] - ox) / h)))
        j0 = max(0, int(math.floor((lo[1] - oy) / h)))
        j1 = min(ny - 1, int(math.floor((hi[1] - oy) / h)))
        k0 = max(0, int(math.floor((lo[2] - oz) / h)))
        k1 = min(nz - 1, int(math.floor((hi[2] - oz) / h)))
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                for k in range(k0, k1 + 1):
                    dist[i, j, k] = 0


@njit(cache=True)
def _chebyshev_transform(dist):
    """Exact chessboard distance transform by a forward and a backward chamfer pass."""
    nx, ny, nz = dist.shape
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                d = dist[i, j, k]
                for di in range(-1, 1):
                    for dj in range(-1, 2):
                        for dk in range(-1, 2):
                            if di == 0 and (dj > 0 or (dj == 0 and dk >= 0)):
                                continue
                            a, b, c = i + di, j + dj, k + dk
                            if 0 <= a < nx and 0 <= b < ny and 0 <= c < nz:
                                d = min(d, dist[a, b, c] + 1)
                dist[i, j, k] = d
    for i in range(nx - 1, -1, -1):
        for j in range(ny - 1, -1, -1):
            for k in range(nz - 1, -1, -1):
                d = dist[i, j, k]
                for di in range(0, 2):
                    for dj in range(-1, 2):
                        for dk in range(-1, 2):
                            if di == 0 and (dj < 0 or (dj == 0 and dk <= 0)):
                                continue
                            a, b, c = i + di, j + dj, k + dk
                            if 0 <= a < nx and 0 <= b < ny and 0 <= c < nz:
                                d = min(d, dist[a, b, c] + 1)
                dist[i, j, k] = d


def build_distance_grid(V: np.ndarray, F: np.ndarray, lo: np.ndarray, hi: np.ndarray, eps: float):
    """Grid over the box [lo, hi] (where media are) for the triangles (V, F). Returns (params, cells)."""
    if F.shape[0] == 0:
        return np.array([0, 0, 0, 1, 0, 0, 0, GRID_NO_TRIANGLES]), np.zeros((1, 1, 1), np.int16)
    if np.any(hi <= lo):
        return np.array([0, 0, 0, 1, 0, 0, 0, GRID_NONE]), np.zeros((1, 1, 1), np.int16)
    ext = hi - lo
    h = float(ext.max()) / (MAX_CELLS - 4)
    n = np.maximum(np.ceil(ext / h).astype(int) + 4, 3)
    origin = lo - 2 * h
    cells = np.empty(tuple(n), np.int16)
    _mark(V.astype(np.float64), F.astype(np.int64), origin[0], origin[1], origin[2], h,
          n[0], n[1], n[2], 4 * eps, cells)
    _chebyshev_transform(cells)
    params = np.array([origin[0], origin[1], origin[2], h, n[0], n[1], n[2], GRID_READY])
    return params, cells


@njit(inline="always", cache=True)
def mesh_distance_bound(params, cells, x, y, z):
    """Lower bound on the distance from (x, y, z) to every triangle (0 outside the grid)."""
    if params[GRID_STATE] == GRID_NO_TRIANGLES:
        return np.inf
    if params[GRID_STATE] == GRID_NONE:
        return 0.0
    h = params[GRID_CELL]
    i = int(math.floor((x - params[GRID_ORIGIN]) / h))
    j = int(math.floor((y - params[GRID_ORIGIN + 1]) / h))
    k = int(math.floor((z - params[GRID_ORIGIN + 2]) / h))
    if i < 0 or j < 0 or k < 0 or i >= cells.shape[0] or j >= cells.shape[1] or k >= cells.shape[2]:
        return 0.0
    return max(0.0, (cells[i, j, k] - 1) * h)
