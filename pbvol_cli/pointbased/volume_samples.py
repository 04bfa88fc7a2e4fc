"""A medium's volume samples as the estimators take them, and the other bundles the kernels take (Medium, Query).

A volume sample v is a segment of a beam (light_samples.py, beams.py): start s_v, unit direction d_v, length l_v,
RGB beam power Phi_v (W) at its start, cross-section A_v (scene units^2), and the boundary's tangent planes where
its beam entered and leaves (PLANE_* columns of beams.py). Prepared here (SampleSet) for the kernels:
- scattered power Phi^s_v = Phi_v sigma_s / sigma_t (1 - e^(-sigma_t l_v)) (W), the power a source emits;
- single scattering's kernel disc: area A_v x beam_width^2;
- the beam's radius rb (double scattering's smoothing), the segment's centre;
- an octree over the centres, each sample's box holding its kernel disc along the segment (continued at the
  boundary by END_EXTENSION), nodes aggregating scattered power; the light cut's node records (lobes) take the
  extent of the samples' own boxes (segment and beam radius) instead;
- double scattering's near-field radius (near_field_radius) and the medium's three multiple-scattering tables.
"""

from __future__ import annotations

import math
from collections import namedtuple
from types import SimpleNamespace

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.scene_build import MED_G, MED_PHASE, MED_SIGMA_A, MED_SIGMA_S
from pbvol_cli.pointbased.octree import aggregate_octree, node_lobes, octree_skeleton

END_EXTENSION = 3.0  # kernel radii by which segments on the boundary are continued (single scattering)

# The bundles the numba kernels take (namedtuples: numba passes them by value and reads fields by name).
NO_LEGS = (np.zeros(0, np.int64), np.zeros((0, 2)))  # leg_first, leg_span of a set without legs
VolumeSamples = namedtuple("VolumeSamples", ["tree", "start", "dir", "len", "power", "area", "centre", "scat", "rb",
                                             "ends", "plane", "tables", "r_near", "lobes", "size", "leg_first",
                                             "leg_span"],
                           defaults=(0.0, *NO_LEGS))
VolumeSamples.__doc__ = """A medium's volume samples for the kernels: tree (Octree.arrays()), per-sample start (m, 3),
dir (m, 3), len (m,), power (m, 3) at the start, area (m,) of single scattering's kernel disc, centre (m, 3), scat
(m, 3) scattered power, rb (m,) beam radius, ends (m,) (1: starts on the boundary, 2: ends there), plane (m, PLANE_COLS)
boundary planes; tables: the medium's three MSTable.render_args() (R, G, B); r_near: double scattering's
near-field radius (scene units); lobes: the tree's octree.node_lobes (the light cut's descents); size: the smallest
side of the box around the segments (the medium's size along its thinnest axis, scene units; 0: unknown);
leg_first (L,), leg_span (L, 2): each leg's first sample and the stretch of its axis that its kernel cylinder spans,
from that sample's start (leg_table; empty: the samples are not grouped in legs)."""
# a flat face of a medium's boundary (flat_faces.py): unit normal (3), q (n . x = q on it), tolerance on q
FACE_COLS = 5
NO_FACES = np.zeros((0, FACE_COLS))
CURVED_EXTRAPOLATION = 0.25  # transport mean free paths by which a curved boundary's image planes lie beyond it
FLAT_FACE_EXTRAPOLATION = 0.45  # the same under a flat face of the boundary (flat_faces.py): the slab's furnace
# read multiple / 3+ 0.81 at 0.25 and 1.04 at 0.5, and the milk glass was dark next to its faces; over six seeds
# the slab reads 0.956 at 0.4, 1.003 at 0.45, 1.049 at 0.5 (docs/pbl.md, section 7)
IMAGE_CURVED, IMAGE_FLAT = 0, 1  # image_k's rows
DEFAULT_IMAGE_K = np.array([[CURVED_EXTRAPOLATION] * 3, [FLAT_FACE_EXTRAPOLATION] * 3])
Medium = namedtuple("Medium", ["sigma_a", "sigma_s", "phase", "g", "faces", "image_k"],
                    defaults=(NO_FACES, DEFAULT_IMAGE_K))
Medium.__doc__ = """A homogeneous medium for the kernels: sigma_a, sigma_s (3,) in 1/scene unit, phase kind, g, the
flat faces of its boundary (k, FACE_COLS) (flat_faces.medium_faces; none by default), and image_k (2, 3), the
transport mean free paths by which the multiple term's image planes lie beyond its boundary per channel, where it
curves (row IMAGE_CURVED) and on a flat face (row IMAGE_FLAT) (image_planes.py, sources.source_terms)."""
Query = namedtuple("Query", ["x", "y", "z", "wx", "wy", "wz", "plane"])
Query.__doc__ = """The point P where in-scattered radiance is wanted, toward the propagation direction w (toward the
camera), and P's boundary plane (n_x, n_y, n_z, q) with n . x = q on it (q = inf: none; NO_PLANE)."""
NO_PLANE = np.array([0.0, 0.0, 1.0, np.inf])

# a boundary-plane pair (a volume sample's, a camera segment's): the plane n . x = q where the beam or segment enters
# (starts) and where it leaves (ends), each as the normal n (3, pointing out of the medium) and q (inf: no plane)
ENTRY_N, ENTRY_Q, EXIT_N, EXIT_Q = 0, 3, 4, 7
PLANE_COLS = 8

SAMPLE_KEYS = ("v_start", "v_dir", "v_len", "v_power", "v_area", "v_medium", "v_ends", "v_plane")

NEAR_FIELD_RADII = 3.0  # double scattering's near field (summed exactly): at most this many median beam radii,
NEAR_FIELD_COUNT = 16.0  # and holding about this many segments (dense samples would make it costly)
NEAR_FIELD_MIN_OPTICAL = 0.1  # no near field where R sigma_t is below this: sources within R of P then give about
# R sigma_t of double scattering, which the cut draws at the same noise, for 10-20 % less time a pass (docs/pbl.md)


@njit(inline="always", cache=True)
def nearer_plane(planes, i, px, py, pz):
    """The column (ENTRY_N or EXIT_N) of segment i's boundary plane nearer to the point (px, py, pz): the plane
    its smooth terms take (planes: segment_planes's table)."""
    exit_depth = planes[i, EXIT_Q] - (planes[i, EXIT_N] * px + planes[i, EXIT_N + 1] * py + planes[i, EXIT_N + 2] * pz)
    entry_depth = planes[i, ENTRY_Q] - (planes[i, ENTRY_N] * px + planes[i, ENTRY_N + 1] * py
                                        + planes[i, ENTRY_N + 2] * pz)
    return EXIT_N if exit_depth < entry_depth else ENTRY_N


def medium_params(media: np.ndarray, m: int, faces: np.ndarray = NO_FACES, image_k: np.ndarray | None = None) -> Medium:
    """Medium m of a built scene's media table, with the flat faces of its boundary (flat_faces.medium_faces) and
    its boundary's image extrapolations (2, 3) (image_planes.medium_extrapolation; None: DEFAULT_IMAGE_K)."""
    row = media[m]
    k = DEFAULT_IMAGE_K if image_k is None else np.asarray(image_k, np.float64)
    return Medium(row[MED_SIGMA_A:MED_SIGMA_A + 3], row[MED_SIGMA_S:MED_SIGMA_S + 3], int(row[MED_PHASE]),
                  float(row[MED_G]), faces, k)


def near_field_radius(start, dirs, length, rb, ends_box=None, sigma_t_max: float = math.inf) -> float:
    """Radius R of double scattering's exactly summed near field (light_cut.double_multiple): NEAR_FIELD_RADII
    median beam radii, smaller where the segments are so dense that more than NEAR_FIELD_COUNT would pass within R
    of a point (segments per volume n, median length l: n (pi R^2 l + 4/3 pi R^3), the volume within R of a
    segment; the volume is the samples' bounding box, an over-estimate; ends_box: that box, if known). 0 (no near
    field) where R is under NEAR_FIELD_MIN_OPTICAL mean free paths of the densest channel (sigma_t_max, 1/scene
    units): in a medium of even source density the shell at distance r gives double scattering in proportion to
    e^(-sigma_t r) dr, so the near field's share is about R sigma_t."""
    if len(length) == 0:
        return 0.0
    if ends_box is None:  # (lo, hi) of the segments' ends, when the caller has not found it already
        ends = np.concatenate([start, start + length[:, None] * dirs])
        ends_box = ends.min(axis=0), ends.max(axis=0)
    volume = float(np.prod(np.maximum(ends_box[1] - ends_box[0], 1e-9)))
    n, ell = len(length) / volume, float(np.median(length))
    roots = np.roots([4.0 / 3.0 * np.pi * n, np.pi * n * ell, 0.0, -NEAR_FIELD_COUNT])
    r_count = float(max(r.real for r in roots if abs(r.imag) < 1e-9 * max(1.0, abs(r)) and r.real > 0))
    r = min(NEAR_FIELD_RADII * float(np.median(rb)), r_count)
    return r if r * sigma_t_max >= NEAR_FIELD_MIN_OPTICAL else 0.0


def returned_samples(samples, medium: int, area_scale: float = 1.0) -> SimpleNamespace:
    """The volume samples of `medium` whose light scattered in a medium before it reached the surface samples
    (v_returned == 1: light that left and the scene sent back; the bounced layer's), as a namespace of v_*
    arrays, cross-sections scaled by area_scale."""
    sel = (samples.v_medium == medium) & (samples.v_returned == 1)
    out = SimpleNamespace(**{k: getattr(samples, k)[sel] for k in SAMPLE_KEYS})
    out.v_area = out.v_area * area_scale
    return out


@njit(cache=True)
def _octree_inputs(idx, start, dirs, length):
    """For the selected samples idx, in one pass: their segments' centres (the octree's points) and the bounding box
    (lo, hi) of their segments' ends (near_field_radius's)."""
    n = idx.shape[0]
    centre = np.empty((n, 3))
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for k in range(n):
        i = idx[k]
        for c in range(3):
            a, b = start[i, c], start[i, c] + length[i] * dirs[i, c]
            centre[k, c] = start[i, c] + 0.5 * length[i] * dirs[i, c]
            lo[c] = min(lo[c], min(a, b))
            hi[c] = max(hi[c], max(a, b))
    return centre, lo, hi


@njit(cache=True, parallel=True)
def _in_tree_order(idx, order, start, dirs, length, power, area, ends, plane, centre, beam_width, sigma_t, albedo):
    """The selected samples gathered in the octree's order (sample order[k] of the selection, idx[order[k]] of the
    set), with what the kernels derive from them: the kernel disc's area, the beam's radius, the scattered power
    Phi^s, and the box that holds the kernel disc along the segment (continued by END_EXTENSION kernel radii where
    the segment touches the boundary)."""
    n = order.shape[0]
    o_start, o_dir, o_power = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    o_centre, o_scat, o_lo, o_hi = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    o_len, o_area, o_rb = np.empty(n), np.empty(n), np.empty(n)
    o_ends = np.empty(n, ends.dtype)
    o_plane = np.empty((n, plane.shape[1]))
    for k in prange(n):  # each sample writes its own rows: the same result for any thread count
        j = order[k]
        i = idx[j]
        o_len[k] = length[i]
        o_area[k] = area[i] * beam_width ** 2
        rb = np.sqrt(o_area[k] / np.pi)  # the kernel's radius: the box must hold it
        o_rb[k] = rb / beam_width
        o_ends[k] = ends[i]
        ext = END_EXTENSION * rb
        back = ext if ends[i] & 1 else 0.0
        ahead = length[i] + (ext if ends[i] & 2 else 0.0)
        for c in range(3):
            o_start[k, c] = start[i, c]
            o_dir[k, c] = dirs[i, c]
            o_power[k, c] = power[i, c]
            o_centre[k, c] = centre[j, c]
            o_scat[k, c] = power[i, c] * albedo[c] * -np.expm1(-sigma_t[c] * length[i])
            first = start[i, c] - back * dirs[i, c]
            last = start[i, c] + ahead * dirs[i, c]
            o_lo[k, c] = min(first, last) - rb
            o_hi[k, c] = max(first, last) + rb
        for c in range(plane.shape[1]):
            o_plane[k, c] = plane[i, c]
    return o_start, o_dir, o_len, o_power, o_area, o_centre, o_scat, o_rb, o_ends, o_plane, o_lo, o_hi


@njit(cache=True)
def leg_table(v_leg, idx, order, start, dirs, length, area, ends):
    """The legs of samples stored in the octree's order (sample k is v_leg's idx[order[k]]): (leg_first (L,),
    leg_span (L, 2)).
    A leg's samples lie end to end on one line, their power falling as e^(-sigma_t t) from the first's start
    (beams._segment_beam), so that a point's share of S_1 is the same formula whichever of them holds it
    (single_scattering.beam_share): the leg is one kernel cylinder, from its first sample's start over
    leg_span = (t_lo, t_hi), continued by END_EXTENSION kernel radii at a boundary end (axial_extent's)."""
    n = order.shape[0]
    top = -1
    for k in range(n):
        top = max(top, v_leg[idx[order[k]]])
    dense = np.full(top + 1, -1, np.int64)
    count = 0
    lid = np.empty(n, np.int64)
    for k in range(n):  # the legs present, numbered in order of appearance
        leg = v_leg[idx[order[k]]]
        if dense[leg] < 0:
            dense[leg] = count
            count += 1
        lid[k] = dense[leg]
    first = np.full(count, -1, np.int64)
    s0, s1 = np.full(count, np.inf), np.full(count, -np.inf)
    flags = np.zeros(count, np.int64)
    for k in range(n):
        leg = lid[k]
        a = start[k, 0] * dirs[k, 0] + start[k, 1] * dirs[k, 1] + start[k, 2] * dirs[k, 2]  # along the line
        if a < s0[leg]:
            s0[leg], first[leg] = a, k
        s1[leg] = max(s1[leg], a + length[k])
        flags[leg] |= ends[k]
    span = np.empty((count, 2))
    for leg in range(count):
        ext = END_EXTENSION * math.sqrt(area[first[leg]] / math.pi)
        span[leg, 0] = -ext if flags[leg] & 1 else 0.0
        span[leg, 1] = s1[leg] - s0[leg] + (ext if flags[leg] & 2 else 0.0)
    return first, span


class SampleSet:
    """One medium's volume samples prepared for the kernels (see the module docstring); .kernel is the bundle."""

    def __init__(self, samples, medium: int, media: np.ndarray, tables: tuple, beam_width: float = 1.0,
                 faces: np.ndarray = NO_FACES, image_k: np.ndarray | None = None):
        """samples: LightSamples (its volume samples of light that has not scattered before reaching the surface
        samples: v_returned == 0) or a namespace of v_* arrays (all taken); media: the built scene's media table;
        tables: the medium's three tables as MSTable.render_args() (R, G, B); faces, image_k: the flat faces of
        the medium's boundary (flat_faces.medium_faces) and its curved boundary's image extrapolation
        (image_planes.medium_extrapolation), in .medium."""
        sel = samples.v_medium == medium
        returned = getattr(samples, "v_returned", None)
        if returned is not None:
            sel &= returned == 0
        idx = np.flatnonzero(sel)
        self.medium = medium_params(media, medium, faces, image_k)
        st = self.medium.sigma_a + self.medium.sigma_s
        albedo = np.where(st > 0, self.medium.sigma_s / np.where(st > 0, st, 1.0), 0.0)
        arrays = [np.ascontiguousarray(a) for a in (samples.v_start, samples.v_dir, samples.v_len,
                                                     samples.v_power, samples.v_area, samples.v_ends)]
        centre, lo, hi = _octree_inputs(idx, *arrays[:3])
        skeleton = octree_skeleton(centre)
        # the samples stored in the tree's order: a leaf's samples are then contiguous in memory, and the kernels'
        # leaf scans (i = order[k], now k) read them in sequence instead of at random (the same sums, faster)
        start, dirs, length, power, area, centre, self.scat, beam_radius, ends, plane, box_lo, box_hi = \
            _in_tree_order(idx, skeleton.order, *arrays, np.ascontiguousarray(samples.v_plane), centre,
                           float(beam_width), st, albedo)
        legs = NO_LEGS
        if getattr(samples, "v_leg", None) is not None and len(idx):
            legs = leg_table(samples.v_leg, idx, skeleton.order, start, dirs, length, area, ends)
        skeleton.order = np.arange(len(idx), dtype=np.int64)
        tree = aggregate_octree(skeleton, centre, box_lo, box_hi, dirs, self.scat)
        self.count = len(idx)
        r_near = near_field_radius(start, dirs, length, beam_radius, (lo, hi), float(np.max(st)))
        # the light cut judges a node by its samples' own box (segment and beam radius): the kernel boxes, up to
        # 3 x BOUNCED_KERNEL beam radii wider, floored the importance of nodes near P hundreds of times low (a
        # one-sample leaf of the milk's bounced set 3.6 in half-diagonal for a segment 0.4 wide; docs/pbl.md)
        end = start + length[:, None] * dirs
        own_lo = np.minimum(start, end) - beam_radius[:, None]
        own_hi = np.maximum(start, end) + beam_radius[:, None]
        self.kernel = VolumeSamples(tree.arrays(), start, dirs, length, power, area, centre, self.scat, beam_radius,
                                    ends, plane, tuple(tables), r_near,
                                    node_lobes(tree.arrays(), own_lo, own_hi, (centre, length, self.scat)),
                                    float(np.min(hi - lo)) if len(idx) else 0.0, *legs)


def scattered_share(base: SampleSet, other: SampleSet) -> float:
    """other's scattered power relative to base's (all channels together)."""
    a = float(base.scat.sum())
    return float(other.scat.sum()) / a if a > 0 else 0.0
