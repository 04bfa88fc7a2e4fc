"""The multiple-scattering table: build, store, look up, scale to a real medium.

Stored (compact) form, per (alpha, g, phase):
  intensity[i_rho, i_z]  the lobe integral over directions of each cell (float32)
  leaf[i_rho, i_z]       the quadtree leaf whose lobe shape the cell uses (int32)
  leaf_kind[leaf]        0: the shape is in phi-symmetric real SH, coef[leaf_slot[leaf]] (float32, order `order`)
                         1: the shape is on the direction grid, qlobe[leaf_slot[leaf]] (8-bit logs) * qmax[...]
S(rho, z, w) = intensity(cell) * shape(leaf(cell), w), bilinearly interpolated between cell centres in warped
coordinates and, for grid shapes, between direction-bin centres (exact at the centres); zero outside the extent.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit

from pbvol_cli.multiple_scattering import lobes
from pbvol_cli.multiple_scattering.layout import Layout, warp_rho, warp_z
from pbvol_cli.multiple_scattering.simulate import simulate

FORMAT_VERSION = 1


@dataclass(frozen=True)
class TableSettings:
    """particles = None: as many as fit a budget of collisions (a 4000-particle pilot run measures the walk
    length), so that every material gets similar statistics in similar time."""

    particles: int | None = None
    collision_budget: int = 80_000_000
    seed: int = 0
    layout: Layout = Layout()
    sh_order: int = 12
    merge_tol: float = 0.05  # relative L2 difference of lobe shapes below which quadtree siblings merge
    sh_tol: float = 0.02  # a leaf is stored in SH when they reproduce its shape within this relative L2 error

    def key_parts(self) -> dict:
        return {"particles": self.particles, "seed": self.seed, "layout": self.layout.as_dict(),
                "sh_order": self.sh_order, "merge_tol": self.merge_tol, "sh_tol": self.sh_tol,
                "version": FORMAT_VERSION}


@dataclass
class MSTable:
    alpha: float
    g: float
    phase_kind: int
    params: np.ndarray  # Layout.params()
    intensity: np.ndarray
    leaf: np.ndarray
    leaf_kind: np.ndarray
    leaf_slot: np.ndarray
    coef: np.ndarray
    qlobe: np.ndarray
    qmax: np.ndarray
    order: int
    metrics: dict = field(default_factory=dict)

    FIELDS = ("params", "intensity", "leaf", "leaf_kind", "leaf_slot", "coef", "qlobe", "qmax")
    REQUIRED = ("format_version", "alpha", "g", "phase_kind", "order", "metrics") + FIELDS

    def arrays(self) -> dict:
        d = {"format_version": np.array(FORMAT_VERSION), "alpha": np.array(self.alpha), "g": np.array(self.g),
             "phase_kind": np.array(self.phase_kind), "order": np.array(self.order),
             "metrics": np.array(json.dumps(self.metrics))}
        d.update({k: getattr(self, k) for k in self.FIELDS})
        return d

    @classmethod
    def from_arrays(cls, d: dict) -> "MSTable":
        """Rebuild from stored arrays; ValueError when anything is missing or inconsistent (a damaged entry)."""
        if int(d["format_version"]) != FORMAT_VERSION:
            raise ValueError("format version")
        t = cls(float(d["alpha"]), float(d["g"]), int(d["phase_kind"]), d["params"].astype(np.float64),
                d["intensity"].astype(np.float32), d["leaf"].astype(np.int32), d["leaf_kind"].astype(np.int8),
                d["leaf_slot"].astype(np.int32), d["coef"].astype(np.float32), d["qlobe"].astype(np.uint8),
                d["qmax"].astype(np.float32), int(d["order"]), json.loads(str(d["metrics"])))
        nr, nz, nd = int(t.params[1]), int(t.params[2]), int(t.params[4] * t.params[5])
        nl = len(t.leaf_kind)
        sh = t.leaf_kind == 0
        ok = (t.intensity.shape == (nr, nz) and t.leaf.shape == (nr, nz) and t.leaf_slot.shape == (nl,)
              and t.coef.ndim == 2 and t.coef.shape[1] == lobes.sh_count(t.order) and t.qlobe.ndim == 2
              and t.qlobe.shape[1] == nd and t.qmax.shape == (len(t.qlobe),)
              and t.leaf.min() >= 0 and t.leaf.max() < nl and np.all(np.isin(t.leaf_kind, (0, 1)))
              and np.all(t.leaf_slot >= 0) and np.all(t.leaf_slot[sh] < len(t.coef))
              and np.all(t.leaf_slot[~sh] < len(t.qlobe)) and np.all(np.isfinite(t.coef))
              and np.all(np.isfinite(t.intensity)) and np.all(t.intensity >= 0) and np.all(np.isfinite(t.qmax)))
        if not ok:
            raise ValueError("inconsistent arrays")
        return t

    def kernel_args(self):
        """The arrays ms_lookup takes, in order."""
        return (self.params, self.intensity, self.leaf, self.leaf_kind, self.leaf_slot, self.coef, self.qlobe,
                self.qmax, self.order)

    def grid_lobes(self) -> np.ndarray:
        """(n_leaves, n_dirs) float32: every leaf's shape at the direction-bin centres (SH evaluated, grid
        decoded). The renderer's form: on disk the table is compact, in memory look-ups are bilinear only."""
        nt, nph = int(self.params[4]), int(self.params[5])
        te, pe = np.linspace(0, np.pi, nt + 1), np.linspace(0, np.pi, nph + 1)
        tc, pc = 0.5 * (te[1:] + te[:-1]), 0.5 * (pe[1:] + pe[:-1])
        out = np.zeros((len(self.leaf_kind), nt * nph), np.float32)
        sh = self.leaf_kind == 0
        if sh.any():
            B = lobes.sh_at(self.order, *np.meshgrid(tc, pc, indexing="ij"))
            out[sh] = np.maximum(self.coef[self.leaf_slot[sh]].astype(np.float64) @ B.T, 0.0)
        if (~sh).any():
            rows = np.flatnonzero(~sh)
            lobes.dequantise_rows(self.qlobe, self.qmax, self.leaf_slot[rows].astype(np.int64), rows, out)
        return out

    def render_args(self):
        """The arrays grid_lookup / scaled_lookup take: (params, intensity, leaf, grid lobes)."""
        return (self.params, self.intensity, self.leaf, self.grid_lobes())

    def lookup(self, rho, z, cos_t, phi):
        """S in table units at arrays of positions and local directions (vectorised convenience)."""
        rho, z, cos_t, phi = np.broadcast_arrays(*(np.asarray(a, float) for a in (rho, z, cos_t, phi)))
        out = np.empty(rho.shape)
        _lookup_many(*self.kernel_args(), rho.ravel(), z.ravel(), cos_t.ravel(), phi.ravel(), out.reshape(-1))
        return out


def empty_table() -> "MSTable":
    """A table that looks up 0 everywhere (a component switched off, or a channel without extinction)."""
    lay = Layout(n_rho=2, n_z=2, n_theta=2, n_phi=2)
    return MSTable(0.0, 0.0, 1, lay.params(), np.zeros((2, 2), np.float32), np.zeros((2, 2), np.int32),
                   np.ones(1, np.int8), np.zeros(1, np.int32), np.zeros((0, lobes.sh_count(2)), np.float32),
                   np.zeros((1, 4), np.uint8), np.zeros(1, np.float32), 2)


# ----------------------------------------------------------------------------- look-ups


@njit(inline="always", cache=True)
def _interp_index(c, n):
    """Cell-centre interpolation: continuous cell coordinate c in [0, n] -> (i0, i1, fraction)."""
    x = c - 0.5
    if x <= 0.0:
        return 0, 0, 0.0
    if x >= n - 1:
        return n - 1, n - 1, 0.0
    i0 = int(x)
    return i0, i0 + 1, x - i0


TAPER_START = 0.7  # share of the table's extent R where its window starts falling to 0 at R


@njit(inline="always", cache=True)
def domain_taper(R, rho, z):
    """The table's window: 1 within TAPER_START R of the source, falling smoothly (smoothstep) to 0 at R, on a
    sphere. The multiple term subtracts a mirror image's look-up from the source's, and the two lie in different
    frames: at the edge of a cylinder (rho < R, |z| < R, the stored cells) one of them fell outside while the
    other did not, and with a high albedo the table is far from 0 there (a non-absorbing index-matched slab,
    20 x 80 x 80 mean free paths, under a white sky: 2.09 for 1, 0.93 with the window; each source's
    difference is clamped at 0, which kept the edge's positive errors and dropped its negative ones). A
    window that depends on the distance alone gives source and image the same cut-off."""
    r2 = rho * rho + z * z
    if r2 >= R * R:
        return 0.0
    a = TAPER_START * R
    if r2 <= a * a:
        return 1.0
    u = (math.sqrt(r2) - a) / (R - a)
    return 1.0 - u * u * (3.0 - 2.0 * u)


@njit(cache=True)
def _grid_shape(p, qlobe, qmax, slot, cos_t, phi):
    """Bilinear interpolation of a quantised lobe between direction-bin centres (theta, |phi| in [0, pi])."""
    nt, nph = int(p[4]), int(p[5])
    th = math.acos(max(-1.0, min(1.0, cos_t)))
    t0, t1, ft = _interp_index(th / math.pi * nt, nt)
    f0, f1, fp = _interp_index(abs(phi) / math.pi * nph, nph)
    v00 = lobes.dequantise(qlobe[slot, t0 * nph + f0], qmax[slot])
    v01 = lobes.dequantise(qlobe[slot, t0 * nph + f1], qmax[slot])
    v10 = lobes.dequantise(qlobe[slot, t1 * nph + f0], qmax[slot])
    v11 = lobes.dequantise(qlobe[slot, t1 * nph + f1], qmax[slot])
    return (1.0 - ft) * ((1.0 - fp) * v00 + fp * v01) + ft * ((1.0 - fp) * v10 + fp * v11)


@njit(cache=True)
def ms_lookup(params, intensity, leaf, leaf_kind, leaf_slot, coef, qlobe, qmax, order, rho, z, cos_t, phi, basis):
    """S(rho, z, w) in table units; (cos_t, phi) is w in the local frame; basis is scratch of sh_count(order)."""
    taper = domain_taper(params[0], rho, z)
    if taper == 0.0:
        return 0.0
    nr, nz = intensity.shape
    i0, i1, fr = _interp_index(warp_rho(params, rho), nr)
    j0, j1, fz = _interp_index(warp_z(params, z), nz)
    have_basis = False
    total = 0.0
    last_leaf = -1
    shape = 0.0
    for c in range(4):
        i = i0 if c < 2 else i1
        j = j0 if c % 2 == 0 else j1
        w = (1.0 - fr if c < 2 else fr) * (1.0 - fz if c % 2 == 0 else fz)
        if w == 0.0:
            continue
        lf = leaf[i, j]
        if lf != last_leaf:
            slot = leaf_slot[lf]
            if leaf_kind[lf] == 0:
                if not have_basis:
                    lobes.sh_basis(order, cos_t, phi, basis)
                    have_basis = True
                shape = 0.0
                for k in range(basis.shape[0]):
                    shape += coef[slot, k] * basis[k]
                shape = max(shape, 0.0)
            else:
                shape = _grid_shape(params, qlobe, qmax, slot, cos_t, phi)
            last_leaf = lf
        total += w * intensity[i, j] * shape
    return total * taper


@njit(cache=True)
def _lookup_many(params, intensity, leaf, leaf_kind, leaf_slot, coef, qlobe, qmax, order, rho, z, cos_t, phi, out):
    basis = np.empty(coef.shape[1])
    for k in range(rho.shape[0]):
        out[k] = ms_lookup(params, intensity, leaf, leaf_kind, leaf_slot, coef, qlobe, qmax, order, rho[k], z[k],
                           cos_t[k], phi[k], basis)


@njit(inline="always", cache=True)
def grid_lookup(params, intensity, leaf, globe, rho, z, cos_t, phi):
    """ms_lookup on the expanded form (MSTable.render_args): bilinear in cells and in direction bins."""
    taper = domain_taper(params[0], rho, z)
    if taper == 0.0:
        return 0.0
    nr, nz = intensity.shape
    nt, nph = int(params[4]), int(params[5])
    i0, i1, fr = _interp_index(warp_rho(params, rho), nr)
    j0, j1, fz = _interp_index(warp_z(params, z), nz)
    th = math.acos(max(-1.0, min(1.0, cos_t)))
    t0, t1, ft = _interp_index(th / math.pi * nt, nt)
    f0, f1, fp = _interp_index(abs(phi) / math.pi * nph, nph)
    a00, a01, a10, a11 = t0 * nph + f0, t0 * nph + f1, t1 * nph + f0, t1 * nph + f1
    w00, w01, w10, w11 = (1 - ft) * (1 - fp), (1 - ft) * fp, ft * (1 - fp), ft * fp
    total = 0.0
    for c in range(4):
        i = i0 if c < 2 else i1
        j = j0 if c % 2 == 0 else j1
        w = (1.0 - fr if c < 2 else fr) * (1.0 - fz if c % 2 == 0 else fz)
        if w == 0.0:
            continue
        lf = leaf[i, j]
        shape = w00 * globe[lf, a00] + w01 * globe[lf, a01] + w10 * globe[lf, a10] + w11 * globe[lf, a11]
        total += w * intensity[i, j] * shape
    return total * taper


@njit(inline="always", cache=True)
def scaled_lookup(tab, power, sigma_t, rx, ry, rz, ax, ay, az, wx, wy, wz):
    """In-scattered radiance per unit length at offset r from a source of `power` emitting along the unit axis a,
    toward propagation direction w, in a medium of extinction sigma_t: S_real = power sigma_t^3 S(sigma_t r, w).
    tab is MSTable.render_args(). This is the one place where the table's units meet a real medium."""
    z = rx * ax + ry * ay + rz * az
    px, py, pz = rx - z * ax, ry - z * ay, rz - z * az
    rho = math.sqrt(px * px + py * py + pz * pz)
    cos_t = wx * ax + wy * ay + wz * az
    if rho > 0.0:
        ex, ey, ez = px / rho, py / rho, pz / rho
        # e_phi = a x e_rho
        fx, fy, fz = ay * ez - az * ey, az * ex - ax * ez, ax * ey - ay * ex
        phi = abs(math.atan2(wx * fx + wy * fy + wz * fz, wx * ex + wy * ey + wz * ez))
    else:
        phi = 0.0
    s = grid_lookup(tab[0], tab[1], tab[2], tab[3], sigma_t * rho, sigma_t * z, cos_t, phi)
    return power * sigma_t ** 3 * s


# ----------------------------------------------------------------------------- building


def energy_cells(cell_energy: np.ndarray, fraction: float = 0.99) -> np.ndarray:
    """Boolean mask of the most energetic cells that together hold `fraction` of the total."""
    flat = cell_energy.ravel()
    order = np.argsort(flat)[::-1]
    cum = np.cumsum(flat[order])
    n = int(np.searchsorted(cum, fraction * cum[-1]) + 1)
    mask = np.zeros(flat.shape, bool)
    mask[order[:n]] = True
    return mask.reshape(cell_energy.shape)


def relative_error(a: np.ndarray, b: np.ndarray, weights: np.ndarray, mask: np.ndarray | None = None) -> float:
    """sqrt(sum w (a - b)^2 / sum w b^2) over (cells, dirs), cells restricted to mask; 0 where both sums are 0 (a
    table that caught no light, as a coarse one of a nearly black medium: nothing to be wrong about), inf where only
    b's is."""
    if mask is not None:
        a, b, weights = a[mask], b[mask], weights[mask]
    num, den = float(np.sum(weights * (a - b) ** 2)), float(np.sum(weights * b ** 2))
    if den == 0.0:
        return 0.0 if num == 0.0 else math.inf
    return math.sqrt(num / den)


def resolve_particles(alpha: float, g: float, phase_kind: int, settings: TableSettings) -> TableSettings:
    """Settings with the particle count fixed (from the collision budget when it is None)."""
    if settings.particles is not None:
        return settings
    pilot = 4000
    _, _, collisions = simulate(alpha, phase_kind, g, settings.layout, pilot, settings.seed + 1_000_003,
                                histogram=False)
    n = settings.collision_budget / max(collisions / pilot, 1.0)
    n = int(float(f"{min(max(n, 10_000), 20_000_000):.2g}"))  # two significant digits: a readable, stable key
    return replace(settings, particles=n)


def build_table(alpha: float, g: float, phase_kind: int, settings: TableSettings, progress=None,
                first_collision: bool = False):
    """Simulate and compress. Returns (MSTable, dense S (n_rho, n_z, n_dirs) float64).

    first_collision=True scores only the particle's first collision: the double-scattering kernel, used to check
    the table's conventions against the closed form."""
    settings = resolve_particles(alpha, g, phase_kind, settings)
    lay = settings.layout
    t0 = time.perf_counter()
    H, total, collisions = simulate(alpha, phase_kind, g, lay, settings.particles, settings.seed, progress=progress,
                                    first_only=first_collision)
    t_sim = time.perf_counter() - t0
    P = lobes.phase_bin_matrix(phase_kind, g, lay)
    S = lobes.dense_table(H, P, lay)
    omega = lay.dir_solid_angles()
    I, shapes = lobes.intensity_and_shapes(S, omega)
    leaf, leaf_shapes = lobes.quadtree_merge(shapes, I, omega, settings.merge_tol)
    # compact form per leaf: SH where it reproduces the shape within sh_tol, else the quantised grid
    B = lobes.sh_matrix(settings.sh_order, lay)
    coef_all = lobes.sh_project(leaf_shapes, B, omega)
    tc, pc = lay.dir_centres()
    Bc = lobes.sh_at(settings.sh_order, *np.meshgrid(tc, pc, indexing="ij"))
    sh_shapes = np.maximum(coef_all @ Bc.T, 0.0)
    norm = np.sqrt(leaf_shapes ** 2 @ omega)
    sh_err = np.sqrt((sh_shapes - leaf_shapes) ** 2 @ omega) / np.where(norm > 0, norm, 1.0)
    use_sh = sh_err <= settings.sh_tol
    kind = np.where(use_sh, 0, 1).astype(np.int8)
    slot = np.zeros(len(leaf_shapes), np.int32)
    slot[use_sh] = np.arange(use_sh.sum())
    slot[~use_sh] = np.arange((~use_sh).sum())
    q, qmax = lobes.quantise(leaf_shapes[~use_sh])
    table = MSTable(alpha, g, phase_kind, lay.params(), I.astype(np.float32), leaf, kind, slot,
                    coef_all[use_sh].astype(np.float32), q, qmax, settings.sh_order)
    # accuracy of the compact form against the dense table, at cell centres and direction-bin centres (where
    # look-ups are exact, so this is what the renderer gets there)
    compact_shapes = np.empty_like(leaf_shapes)
    compact_shapes[use_sh] = sh_shapes[use_sh]
    compact_shapes[~use_sh] = lobes.dequantise_all(q, qmax)
    compact = I.astype(np.float32).astype(np.float64)[..., None] * compact_shapes[leaf]
    merged = I[..., None] * leaf_shapes[leaf]
    V = lay.cell_volumes()
    wts = V[..., None] * omega[None, None, :]
    mask = energy_cells(I * V)
    table.metrics = {
        "scored_power": float(np.sum(S * wts)), "simulated_power": total,
        "particles": settings.particles, "collisions": collisions, "simulate_s": t_sim,
        "build_s": time.perf_counter() - t0, "leaves": int(len(leaf_shapes)), "sh_leaves": int(use_sh.sum()),
        "cells": int(lay.n_cells),
        "err_compact_vs_dense": relative_error(compact, S, wts),
        "err_compact_vs_dense_99": relative_error(compact, S, wts, mask),
        "err_quadtree_vs_dense_99": relative_error(merged, S, wts, mask),
    }
    return table, S
