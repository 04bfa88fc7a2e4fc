"""The flat faces of a medium's boundary, where the multiple term's images lie farther out (sources.source_terms).

The table's images mirror a source in the tangent plane of the boundary, moved out by an extrapolation distance.
Fitted on curved bodies (spheres a few mean free paths across, whose boundary falls away from the tangent plane),
that distance is short under a flat face: the index-matched slab's multiple term read 0.68 of order 3+, and a
glass of milk read 0.75-0.89 of it next to its free surface and base (docs/pbl.md, section 12, "The milk's bias
floor located"). A face counts as flat where coplanar triangles of flat shading (corner normals equal to the
facet's) cover a disc at least FLAT_MIN_RADIUS transport mean free paths across; a plane handed to the kernels is
on that face when it matches the face's plane (either orientation) within a few ray offsets
(sources.on_flat_face).
"""

import numpy as np

from pbvol_cli.geometry.scene_build import SURF_MEDIUM_IN, SURF_MEDIUM_OUT, BuiltScene
from pbvol_cli.pointbased.sources import transport_share
from pbvol_cli.pointbased.volume_samples import FACE_COLS, NO_FACES, medium_params

FLAT_MIN_RADIUS = 1.0  # transport mean free paths: the least radius of the disc of a face's area that counts as flat
MAX_FACES = 16  # the largest faces kept: the multiple term tests each plane against every face at every look-up


def medium_faces(bs: BuiltScene, m: int) -> np.ndarray:
    """flat_faces of medium m, with the transport mean free path of its channels' mean (scene units)."""
    med = medium_params(bs.media, m)
    share = transport_share(med.phase, med.g)
    transport_mfp = float(np.mean(1.0 / np.maximum(med.sigma_a + share * med.sigma_s, 1e-30)))
    return flat_faces(bs, m, transport_mfp)


def flat_faces(bs: BuiltScene, m: int, transport_mfp: float) -> np.ndarray:
    """(k, FACE_COLS) the flat faces bounding medium m: coplanar triangles of flat shading on surfaces with m on a
    side, grouped by plane, kept where their area's disc radius sqrt(A / pi) is at least FLAT_MIN_RADIUS
    transport_mfp (scene units), the MAX_FACES largest first. Analytic spheres have none."""
    if len(bs.faces) == 0:
        return NO_FACES
    sides = (bs.surfaces[:, SURF_MEDIUM_IN] == m) | (bs.surfaces[:, SURF_MEDIUM_OUT] == m)
    tri = np.flatnonzero(sides[bs.tri_surface])
    if len(tri) == 0:
        return NO_FACES
    v = bs.vertices[bs.faces[tri]].astype(np.float64)  # (t, 3 corners, 3)
    cross = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    ok = area2 > 0
    n = np.where(ok[:, None], cross / np.where(ok, area2, 1.0)[:, None], 0.0)
    corners = bs.tri_normals[tri].astype(np.float64)
    flat = ok & (np.abs(np.einsum("tcj,tj->tc", corners, n)) > 1.0 - 1e-5).all(axis=1)
    if not flat.any():
        return NO_FACES
    n, v0, area = n[flat], v[flat, 0], 0.5 * area2[flat]
    # one orientation per plane (the first non-zero component positive), then grouped by the rounded plane
    sign = np.sign(n[np.arange(len(n)), np.argmax(np.abs(n) > 1e-9, axis=1)])
    n = n * sign[:, None]
    q = np.einsum("ij,ij->i", n, v0)
    tol = 4.0 * bs.eps + 1e-9 * bs.extent
    key = np.column_stack([np.round(n * 1e5), np.round(q / tol)]).astype(np.int64)
    _, first, group = np.unique(key, axis=0, return_index=True, return_inverse=True)
    group = group.ravel()
    total = np.bincount(group, weights=area)
    keep = np.flatnonzero(np.sqrt(total / np.pi) >= FLAT_MIN_RADIUS * transport_mfp)
    keep = keep[np.argsort(-total[keep], kind="stable")[:MAX_FACES]]
    out = np.zeros((len(keep), FACE_COLS))
    out[:, :3] = n[first[keep]]
    out[:, 3] = np.bincount(group, weights=area * q)[keep] / total[keep]  # the area-weighted plane offset
    out[:, 4] = tol
    return out
