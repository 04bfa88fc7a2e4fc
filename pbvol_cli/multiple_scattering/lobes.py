"""From the collision histogram to outgoing lobes, and their compression.

- phase_bin_matrix: P[in, out], the phase function averaged over an incoming and an outgoing direction bin
  (both signs of phi), rows normalised so that sum_out P[in, out] * Omega_out = 1 exactly (power conserved).
- dense_table: S[cell, out] = sum_in H[cell, in] P[in, out] / V_cell.
- quadtree_merge: bottom-up over the (rho, z) cells; four sibling leaves are merged when their normalised lobe
  shapes agree within a tolerance. Intensity (the lobe integral) stays per cell; only shapes are shared.
- The compact form of each leaf's shape: spherical harmonics symmetric in phi (Y_lm with cos(m phi), m >= 0)
  where they reproduce it within a tolerance (smooth, far-field lobes), else the lobe on the direction grid
  quantised to 8-bit logarithms (peaked lobes near the source of forward-scattering media, which low-order SH
  would ring on).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from pbvol_cli.physics.phase import phase_eval

SUB = 6  # sub-samples per bin side for the bin averages


@njit(parallel=True, cache=True)
def _phase_bins(kind, g, te, pe, P):
    nt, nph = te.shape[0] - 1, pe.shape[0] - 1
    nd = nt * nph
    for a in prange(nd):
        ta, pa = a // nph, a % nph
        for b in range(nd):
            tb, pb = b // nph, b % nph
            acc = 0.0
            wsum = 0.0
            for i in range(SUB):
                th1 = te[ta] + (i + 0.5) / SUB * (te[ta + 1] - te[ta])
                s1, c1 = math.sin(th1), math.cos(th1)
                for k in range(SUB):
                    ph1 = pe[pa] + (k + 0.5) / SUB * (pe[pa + 1] - pe[pa])
                    for i2 in range(SUB):
                        th2 = te[tb] + (i2 + 0.5) / SUB * (te[tb + 1] - te[tb])
                        s2, c2 = math.sin(th2), math.cos(th2)
                        wgt = s1 * s2
                        for k2 in range(SUB):
                            ph2 = pe[pb] + (k2 + 0.5) / SUB * (pe[pb + 1] - pe[pb])
                            # both reflections of the incoming direction (phi -> -phi)
                            cp = 0.5 * (phase_eval(kind, g, s1 * s2 * math.cos(ph1 - ph2) + c1 * c2)
                                        + phase_eval(kind, g, s1 * s2 * math.cos(ph1 + ph2) + c1 * c2))
                            acc += wgt * cp
                            wsum += wgt
            P[a, b] = acc / wsum


def phase_bin_matrix(kind: int, g: float, layout) -> np.ndarray:
    te, pe = layout.dir_edges()
    P = np.zeros((layout.n_dirs, layout.n_dirs))
    _phase_bins(kind, g, te, pe, P)
    omega = layout.dir_solid_angles()
    P /= (P @ omega)[:, None]
    return P


def dense_table(H: np.ndarray, P: np.ndarray, layout) -> np.ndarray:
    """(n_rho, n_z, n_dirs) in-scattered radiance per unit length, per unit source power."""
    S = (H @ P) / layout.cell_volumes().reshape(-1, 1)
    return S.reshape(layout.n_rho, layout.n_z, layout.n_dirs)


def intensity_and_shapes(S: np.ndarray, omega: np.ndarray):
    """I = integral of the lobe over directions; shapes = lobe / I (integrating to 1), zero where I = 0."""
    I = S @ omega
    shapes = np.where(I[..., None] > 0, S / np.where(I > 0, I, 1.0)[..., None], 0.0)
    return I, shapes


def quadtree_merge(shapes: np.ndarray, I: np.ndarray, omega: np.ndarray, tol: float):
    """Bottom-up quadtree merge of lobe shapes over the (rho, z) grid (n_rho a power of two, n_z a multiple of it:
    side-by-side quadtrees). Returns (leaf_of_cell (n_rho, n_z) int32, leaf_shapes (n_leaves, n_dirs)).

    Four sibling leaves merge when each one's shape differs from their energy-weighted mean by less than tol in
    the solid-angle-weighted relative L2 norm. Cells with no energy agree with anything.
    """
    nr, nz, nd = shapes.shape
    sq = np.sqrt(omega)
    shape, w = shapes.copy(), I.copy()
    alive = np.ones((nr, nz), bool)  # the block at this level is a leaf that may still merge
    finals = []  # (i, j, size, shape)
    size = 1
    while size < nr:
        a, b = nr // (2 * size), nz // (2 * size)
        S4 = shape.reshape(a, 2, b, 2, nd)
        W4 = w.reshape(a, 2, b, 2)
        A4 = alive.reshape(a, 2, b, 2)
        tot = W4.sum(axis=(1, 3))
        mean = (S4 * W4[..., None]).sum(axis=(1, 3)) / np.where(tot > 0, tot, 1.0)[..., None]
        nm = np.linalg.norm(mean * sq, axis=-1)
        dev = np.linalg.norm((S4 - mean[:, None, :, None, :]) * sq, axis=-1)
        close = (dev <= tol * nm[:, None, :, None]) | (W4 <= 0)
        ok = A4.all(axis=(1, 3)) & close.all(axis=(1, 3))
        # the children of groups that do not merge are final leaves
        for gi, gj in zip(*np.nonzero(~ok)):
            for di in range(2):
                for dj in range(2):
                    if A4[gi, di, gj, dj]:
                        finals.append(((2 * gi + di) * size, (2 * gj + dj) * size, size, S4[gi, di, gj, dj]))
        shape, w, alive = mean, tot, ok
        size *= 2
    for gi, gj in zip(*np.nonzero(alive)):
        finals.append((gi * size, gj * size, size, shape[gi, gj]))
    leaf_of_cell = np.full((nr, nz), -1, np.int32)
    for n, (i, j, sz, _) in enumerate(finals):
        leaf_of_cell[i:i + sz, j:j + sz] = n
    return leaf_of_cell, np.stack([f[3] for f in finals])


# --------------------------------------------------------------------------- spherical harmonics (phi-symmetric)


def sh_count(order: int) -> int:
    return (order + 1) * (order + 2) // 2


@njit(cache=True)
def sh_basis(order, cos_t, phi, out):
    """Orthonormal real SH with cos(m phi), m = 0..l, l = 0..order, at (theta, phi); out[(l, m) index]."""
    x = cos_t
    sx = math.sqrt(max(0.0, 1.0 - x * x))
    # associated Legendre P_m^m, P_{m+1}^m, ... by the standard recurrences (Condon-Shortley phase omitted)
    pmm = 1.0
    for m in range(order + 1):
        if m > 0:
            pmm *= (2 * m - 1) * sx
        # normalisation of m: sqrt((2l+1)/(4 pi) (l-m)!/(l+m)!) * (sqrt 2 if m > 0)
        cm = math.cos(m * phi) * (math.sqrt(2.0) if m > 0 else 1.0)
        p_prev = 0.0
        p_cur = pmm
        for l in range(m, order + 1):
            if l == m + 1:
                p_prev, p_cur = p_cur, x * (2 * m + 1) * pmm
            elif l > m + 1:
                p_prev, p_cur = p_cur, ((2 * l - 1) * x * p_cur - (l + m - 1) * p_prev) / (l - m)
            # factorial ratio (l-m)!/(l+m)!
            ratio = 1.0
            for q in range(l - m + 1, l + m + 1):
                ratio /= q
            idx = m * (order + 1) - m * (m - 1) // 2 + (l - m)
            out[idx] = math.sqrt((2 * l + 1) / (4.0 * math.pi) * ratio) * p_cur * cm


def sh_matrix(order: int, layout, sub: int = 4) -> np.ndarray:
    """(n_dirs, n_coef): the basis averaged over each direction bin (phi over the bin, both signs)."""
    te, pe = layout.dir_edges()
    nc = sh_count(order)
    B = np.zeros((layout.n_dirs, nc))
    tmp = np.zeros(nc)
    for a in range(layout.n_dirs):
        it, ip = divmod(a, layout.n_phi)
        acc, wsum = np.zeros(nc), 0.0
        for i in range(sub):
            th = te[it] + (i + 0.5) / sub * (te[it + 1] - te[it])
            for k in range(sub):
                ph = pe[ip] + (k + 0.5) / sub * (pe[ip + 1] - pe[ip])
                sh_basis(order, math.cos(th), ph, tmp)
                acc += math.sin(th) * tmp
                wsum += math.sin(th)
        B[a] = acc / wsum
    return B


def sh_at(order: int, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """(n, n_coef) basis at the given directions."""
    th, ph = np.ravel(theta), np.ravel(phi)
    out = np.zeros((len(th), sh_count(order)))
    for k in range(len(th)):
        sh_basis(order, math.cos(th[k]), ph[k], out[k])
    return out


def sh_project(shapes: np.ndarray, B: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Least-squares SH coefficients (weighted by solid angle) of lobes given per direction bin."""
    W = np.sqrt(omega)
    coef, *_ = np.linalg.lstsq(B * W[:, None], (shapes * W).T, rcond=None)
    return coef.T


# --------------------------------------------------------------------------- 8-bit log quantisation

Q_FLOOR = 1e-5  # values below Q_FLOOR * (lobe max) are stored as 0
_Q_STEP = -math.log(Q_FLOOR) / 254.0


def quantise(lobes_: np.ndarray):
    """(n, n_dirs) non-negative lobes -> (uint8 codes, float32 per-lobe max). Code 0 is 0; code q >= 1 is
    max * exp(-(254 - (q - 1)) * step), a relative step of 4.6% (rounding error within +-2.3%)."""
    vmax = lobes_.max(axis=1).astype(np.float32)
    rel = lobes_ / np.where(vmax > 0, vmax, 1.0)[:, None]
    q = np.zeros(lobes_.shape, np.uint8)
    pos = rel >= Q_FLOOR
    q[pos] = np.clip(np.rint(255.0 + np.log(rel[pos]) / _Q_STEP), 1, 255).astype(np.uint8)
    return q, vmax


@njit(inline="always", cache=True)
def dequantise(code, vmax):
    if code == 0:
        return 0.0
    return vmax * math.exp((code - 255.0) * _Q_STEP)


# every code's value over its lobe's max (dequantise's factor): a table's lobes decoded by look-up, not by an
# exponential per direction bin (the three tables of a render in 4 instead of 50 ms; the same values)
_Q_FACTORS = np.where(np.arange(256) == 0, 0.0, np.exp((np.arange(256) - 255.0) * _Q_STEP))


def dequantise_all(q: np.ndarray, vmax: np.ndarray) -> np.ndarray:
    """(n, n_dirs) float64 lobes from their codes q (uint8, (n, n_dirs)) and maxima vmax (n,): dequantise's."""
    return vmax[:, None].astype(np.float64) * _Q_FACTORS[q]


@njit(cache=True)
def dequantise_rows(q, vmax, slots, rows, out):
    """out[rows[k]] = lobe slots[k] of (q, vmax) decoded (dequantise_all's values, cast to out's dtype), written
    in place: no temporaries of the whole table's size."""
    for k in range(slots.shape[0]):
        s, r = slots[k], rows[k]
        v = np.float64(vmax[s])
        for j in range(q.shape[1]):
            out[r, j] = v * _Q_FACTORS[q[s, j]]
