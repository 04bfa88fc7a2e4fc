"""The hierarchical sum M_o(p) = sum_j R_d(|p_j - p|) Phi_j over the irradiance samples (Jensen & Buhler 2002,
sec. 4; seed 003, "SubsurfaceOctreeNode::Mo").

An octree over a medium's samples (pointbased/octree.py: flat arrays; per node the power-weighted position and
the summed power, here also the summed area). A node stands for its samples at p when the solid angle it subtends,
its area over its squared distance from p, is below max_error and p lies outside its box; otherwise its children
are visited, and a leaf's samples are summed one by one. max_error = 0 sums every sample.

The outgoing radiance of the diffusion term at p, just outside the boundary toward w_o:
L_o = F_t(w_o) M_o(p) / (pi (1 - F_dr,outside)) (profile.exit_normalisation).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from pbvol_cli.dipole.irradiance import IrradianceSamples
from pbvol_cli.dipole.profile import boundary_a, dipole_params, exit_normalisation, rd
from pbvol_cli.pointbased.octree import Octree, build_octree

STACK = 512  # depth-first stack of the walk (8 children a level)


@njit(cache=True)
def _node_area(order, start, end, first_child, n_children, area, out):
    for nd in range(out.shape[0] - 1, -1, -1):  # children were created after their parents
        s = 0.0
        if first_child[nd] < 0:
            for k in range(start[nd], end[nd]):
                s += area[order[k]]
        else:
            for ch in range(first_child[nd], first_child[nd] + n_children[nd]):
                s += out[ch]
        out[nd] = s


class IrradianceTree:
    """One medium's irradiance samples and their octree."""

    def __init__(self, pos, power, area, normal):
        self.pos = np.ascontiguousarray(pos, np.float64)
        self.power = np.ascontiguousarray(power, np.float64)
        self.area = np.ascontiguousarray(area, np.float64)
        self.tree: Octree = build_octree(self.pos, self.pos, self.pos, np.asarray(normal, float), self.power)
        self.node_area = np.zeros(len(self.tree.start))
        if len(self.node_area):
            _node_area(self.tree.order, self.tree.start, self.tree.end, self.tree.first_child, self.tree.n_children,
                       self.area, self.node_area)

    def mo(self, params, a, queries, max_error: float) -> np.ndarray:
        """M_o (W per scene unit^2, RGB) at the points queries (q, 3); a: the boundary's A at each (q,)."""
        out = np.zeros((len(queries), 3))
        if len(self.pos) and len(queries):
            t = self.tree
            _mo(t.order, t.lo, t.hi, t.centre, t.power, t.first_child, t.n_children, t.start, t.end, self.node_area,
                self.pos, self.power, np.ascontiguousarray(params, np.float64),
                np.ascontiguousarray(a, np.float64), np.ascontiguousarray(queries, np.float64), float(max_error), out)
        return out


@njit(parallel=True, cache=True)
def _mo(order, lo, hi, centre, npower, first_child, n_children, start, end, narea, pos, power, params, a, q,
        max_error, out):
    for i in prange(q.shape[0]):
        _mo_one(np.int64(i), order, lo, hi, centre, npower, first_child, n_children, start, end, narea, pos, power,
                params, a, q, max_error, out)


@njit(cache=True)
def _mo_one(i, order, lo, hi, centre, npower, first_child, n_children, start, end, narea, pos, power, params, a,
            q, max_error, out):
    px, py, pz = q[i, 0], q[i, 1], q[i, 2]
    stack = np.empty(STACK, np.int64)
    stack[0] = 0
    sp = 1
    r0 = r1 = r2 = 0.0
    while sp > 0:
        sp -= 1
        nd = stack[sp]
        inside = (lo[nd, 0] <= px <= hi[nd, 0] and lo[nd, 1] <= py <= hi[nd, 1] and lo[nd, 2] <= pz <= hi[nd, 2])
        d2 = (centre[nd, 0] - px) ** 2 + (centre[nd, 1] - py) ** 2 + (centre[nd, 2] - pz) ** 2
        if not inside and narea[nd] < max_error * d2:
            r0 += rd(params, 0, a[i], d2) * npower[nd, 0]
            r1 += rd(params, 1, a[i], d2) * npower[nd, 1]
            r2 += rd(params, 2, a[i], d2) * npower[nd, 2]
            continue
        if first_child[nd] < 0 or sp + n_children[nd] > STACK:
            for k in range(start[nd], end[nd]):
                j = order[k]
                e2 = (pos[j, 0] - px) ** 2 + (pos[j, 1] - py) ** 2 + (pos[j, 2] - pz) ** 2
                r0 += rd(params, 0, a[i], e2) * power[j, 0]
                r1 += rd(params, 1, a[i], e2) * power[j, 1]
                r2 += rd(params, 2, a[i], e2) * power[j, 2]
            continue
        for ch in range(first_child[nd], first_child[nd] + n_children[nd]):
            stack[sp] = ch
            sp += 1
    out[i, 0], out[i, 1], out[i, 2] = r0, r1, r2


class DiffusionTerm:
    """The dipole's diffusion term of every medium of a scene, for the camera paths: radiance(m, points, eta) is
    L_o / F_t(w_o) where camera paths entered medium m at `points` through a boundary of relative index eta (the
    medium's over the side the path came from)."""

    layer = "diffusion"

    def __init__(self, built, samples: IrradianceSamples, max_error: float):
        self.max_error = max_error
        self.trees, self.params = {}, {}
        for m, info in enumerate(built.medium_info):
            sel = samples.medium == m
            sig_a, sig_s = built.medium_sigmas(m)
            self.params[m] = dipole_params(sig_a, sig_s, info.material.g)
            if sel.any():
                self.trees[m] = IrradianceTree(samples.pos[sel], samples.power[sel], samples.area[sel],
                                               samples.normal[sel])
        self._eta_terms = {}  # relative index -> (A, exit normalisation / pi)

    def _terms(self, eta: float):
        if eta not in self._eta_terms:
            self._eta_terms[eta] = (boundary_a(eta), exit_normalisation(eta) / math.pi)
        return self._eta_terms[eta]

    def radiance(self, m: int, points, eta) -> np.ndarray:
        """(n, 3): M_o at the points times the exit normalisation over pi (W sr^-1 per scene unit^2)."""
        tree = self.trees.get(int(m))
        out = np.zeros((len(points), 3))
        if tree is None or len(points) == 0:
            return out
        eta = np.asarray(eta, float)
        a, norm = np.empty(len(points)), np.empty(len(points))
        for e in np.unique(eta):
            sel = eta == e
            a[sel], norm[sel] = self._terms(float(e))
        return tree.mo(self.params[int(m)], a, points, self.max_error) * norm[:, None]


class DiffusionPasses:
    """The diffusion term of each pass (camera_pass.render_pbl's entry): pass 0 from the given irradiance samples
    (the cached set), pass p from place(p) while p < light_sets (0: every pass; 1: the cached set only), then
    cycling through those, as the point-based method's light-sample sets do: the irradiance samples' noise (one
    direction per light and sample) averages out over passes like the camera side's."""

    layer = DiffusionTerm.layer

    def __init__(self, built, first: IrradianceSamples, place, max_error: float, light_sets: int):
        self.built, self.place, self.max_error, self.light_sets = built, place, max_error, light_sets
        self.terms = {0: DiffusionTerm(built, first, max_error)}

    def for_pass(self, p: int) -> DiffusionTerm:
        if self.light_sets == 1:
            p = 0
        elif self.light_sets > 1:
            p %= self.light_sets
        if p not in self.terms:
            if self.light_sets == 0:
                self.terms = {0: self.terms[0]}  # (a new set every pass: keep only the cached one)
            self.terms[p] = DiffusionTerm(self.built, self.place(p), self.max_error)
        return self.terms[p]
