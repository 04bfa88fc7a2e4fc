"""Monte Carlo of the table: particles from a point source in an infinite medium (sigma_t = 1).

Each collision scores the power it scatters, w * alpha, into a histogram of *incoming* directions of its cell;
lobes.py turns it into outgoing radiance by a matrix product with the bin-averaged phase function. This keeps the
per-collision work O(1) instead of one phase evaluation per outgoing direction.

Particles are dealt to N_CHUNKS accumulators by index (j % N_CHUNKS), each filled in increasing j: the result is
the same for any thread count and any batching.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from pbvol_cli.multiple_scattering.layout import cos_edges, local_dir_bin, warp_rho, warp_z
from pbvol_cli.physics.phase import phase_sample
from pbvol_cli.physics.sampling import rand, seed_state

N_CHUNKS = 4
# Weight window: below RR_WEIGHT a particle survives with probability w / RR_WEIGHT and continues with weight
# RR_WEIGHT (unbiased). Implicit capture above it; a low window would make high-albedo walks needlessly long.
RR_WEIGHT = 0.5


@njit(cache=True)
def _walk(j, seed, alpha, kind, g, p, tce, pce, first_only, H, tot, ncol):
    """Trace particle j; add its scores to H (cells x incoming-direction bins), tot[0] (their sum) and the
    number of collisions to ncol[0]."""
    st = np.empty(1, np.uint64)
    st[0] = seed_state(seed, 0x5CA7, j)
    R, n_rho, n_z, kill2 = p[0], int(p[1]), int(p[2]), p[6] * p[6]
    x = y = z = 0.0
    dx, dy, dz, _ = phase_sample(kind, g, 0.0, 0.0, 1.0, rand(st, 0), rand(st, 0), rand(st, 0))
    w = 1.0
    k = 0
    scored = 0.0  # local sums, written once: per-collision writes to shared arrays would false-share
    while True:
        t = -math.log(1.0 - rand(st, 0))
        x += t * dx
        y += t * dy
        z += t * dz
        k += 1
        if x * x + y * y + z * z > kill2:
            break
        if (k == 1) if first_only else (k >= 2):
            rho = math.sqrt(x * x + y * y)
            if rho < R and abs(z) < R:
                ir = min(int(warp_rho(p, rho)), n_rho - 1)
                iz = min(max(int(warp_z(p, z)), 0), n_z - 1)
                s = w * alpha
                H[ir * n_z + iz, local_dir_bin(x, y, rho, dx, dy, dz, tce, pce)] += s
                scored += s
        if first_only:
            break
        w *= alpha
        if w <= 0.0:
            break
        if w < RR_WEIGHT:
            if rand(st, 0) * RR_WEIGHT >= w:
                break
            w = RR_WEIGHT
        dx, dy, dz, _ = phase_sample(kind, g, dx, dy, dz, rand(st, 0), rand(st, 0), rand(st, 0))
    tot[0] += scored
    ncol[0] += k


@njit(parallel=True, cache=True)
def simulate_batch(first, count, seed, alpha, kind, g, p, tce, pce, first_only, H, tot, ncol):
    """Particles first .. first+count-1 into H[chunk] (N_CHUNKS, cells, dirs), tot[chunk], ncol[chunk]."""
    for c in prange(N_CHUNKS):
        # the particles of this chunk in this batch, in increasing index
        j0 = first + ((c - first) % N_CHUNKS)
        for j in range(j0, first + count, N_CHUNKS):
            _walk(j, seed, alpha, kind, g, p, tce, pce, first_only, H[c], tot[c:c + 1], ncol[c:c + 1])


def simulate(alpha: float, kind: int, g: float, layout, particles: int, seed: int, first_only: bool = False,
             progress=None, batch: int = 20000, histogram: bool = True):
    """Run the simulation. Returns (H summed over chunks (cells, dirs), total scored power, collisions), the first
    two per particle. histogram=False keeps a 1-cell layout in memory (for pilot runs and totals)."""
    p = layout.params()
    if not histogram:
        p = p.copy()
        p[1] = p[2] = 1
    tce, pce = cos_edges(layout.n_theta), cos_edges(layout.n_phi)
    H = np.zeros((N_CHUNKS, int(p[1] * p[2]), layout.n_dirs))
    tot = np.zeros(N_CHUNKS)
    ncol = np.zeros(N_CHUNKS, np.int64)
    done = 0
    while done < particles:
        n = min(batch, particles - done)
        simulate_batch(done, n, seed, alpha, kind, g, p, tce, pce, first_only, H, tot, ncol)
        done += n
        if progress is not None:
            progress(done, particles)
    Hs = H[0].copy()
    for c in range(1, N_CHUNKS):
        Hs += H[c]
    return Hs / particles, float(tot.sum()) / particles, int(ncol.sum())
