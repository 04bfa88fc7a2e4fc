"""A volume sample as a source of multiple scattering: the boundary's mirror images."""

import numpy as np
import pytest

from pbvol_cli.multiple_scattering.layout import Layout
from pbvol_cli.multiple_scattering.table import TableSettings, build_table, scaled_lookup
from pbvol_cli.physics.phase import phase_eval
from pbvol_cli.pointbased.inverse_square import attenuated_inv_r2_ball
from pbvol_cli.pointbased.sources import (NEAR_READ_TRANSPORT, Source, on_flat_face,
                                          source_terms)
from pbvol_cli.pointbased.volume_samples import (CURVED_EXTRAPOLATION, FACE_COLS, FLAT_FACE_EXTRAPOLATION, NO_PLANE,
                                                 Medium, Query)


def test_multiple_term_of_a_source_with_its_image_is_never_negative():
    """The multiple term of one source is the table's value less its mirror image's (method of images): where the
    image's mirrored lobe sends more toward P than the source's own, or P lies beyond the source's boundary plane
    (a concave boundary), the difference is negative, an artefact (the half-space's response to a source is never
    negative); it is taken as 0 (bumpy sphere: 712 of 9216 pixels of the multiple layer were negative at 1 spp,
    a sum of -62 against +226). Where the difference is positive it is kept as it is."""
    lay = Layout(extent=10.0, n_rho=16, n_z=32, n_theta=9, n_phi=9, kill_radius=20.0)
    table, _ = build_table(0.9, 0.7, 1, TableSettings(particles=40000, layout=lay, sh_order=8))
    tab = table.render_args()
    tabs = (tab, tab, tab)
    sig_a, sig_s = np.full(3, 0.1), np.full(3, 0.9)
    rng = np.random.default_rng(3)
    n_neg = n_pos = 0
    for _ in range(400):
        # source 0.1-1 below the boundary plane z = 0 (the medium is z < 0), heading anywhere
        x = np.array([0.0, 0.0, -rng.uniform(0.1, 1.0)])
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        p = rng.uniform(-1.5, 1.5, 3)
        p[2] = rng.uniform(-2.0, 0.5)  # some points beyond the plane
        w = rng.normal(size=3)
        w /= np.linalg.norm(w)
        out_d, out_m = np.zeros(3), np.zeros(3)
        # the plane n . y = q, n = +z (outward, from the source to the plane), q = 0: the image is at x + 2 (q - n.x) n
        source_terms(Source(*x, *d, 1.0, 1.0, 1.0, 0.05), np.array([0.0, 0.0, 1.0, 0.0] * 2),
                     Medium(sig_a, sig_s, 1, 0.7), Query(*p, *w, NO_PLANE), 0.02, False, True, tabs, 0.0, out_d, out_m)
        r = p - x
        h = 2.0 * (0.0 - x[2] + CURVED_EXTRAPOLATION / (0.1 + 0.3 * 0.9))  # the plane moved out by z_b
        e = np.array([d[0], d[1], -d[2]])
        plain = (scaled_lookup(tab, 1.0, 1.0, r[0], r[1], r[2], d[0], d[1], d[2], w[0], w[1], w[2])
                 - scaled_lookup(tab, 1.0, 1.0, r[0], r[1], r[2] - h, e[0], e[1], e[2], w[0], w[1], w[2]))
        assert np.all(out_m >= 0.0)
        if plain > 0:
            n_pos += 1
            assert out_m[0] == pytest.approx(plain, rel=1e-9)
        else:
            n_neg += 1
            assert out_m[0] == 0.0
    assert n_neg > 10 and n_pos > 10  # both cases met


def test_each_source_point_takes_the_nearer_of_its_beams_two_boundary_planes():
    """A segment stores the tangent planes where its beam entered and left; each of its source points is mirrored
    in the nearer one (the segment's centre decided before: a long last segment's points near the entry were
    mirrored in the far exit plane and kept nearly all of the table's light). Here the planes z = 0 (normal +z)
    and z = -10 (normal -z): a source 0.3 below the first is mirrored in it, whichever order the two come in."""
    lay = Layout(extent=10.0, n_rho=16, n_z=32, n_theta=9, n_phi=9, kill_radius=20.0)
    table, _ = build_table(0.95, 0.0, 1, TableSettings(particles=20000, layout=lay, sh_order=8))
    tabs = (table.render_args(),) * 3
    sig_a, sig_s = np.full(3, 0.05), np.full(3, 0.95)
    top, bottom = (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, -1.0, 10.0)

    def multiple(x, p, first, second):
        out_d, out_m = np.zeros(3), np.zeros(3)
        source_terms(Source(*x, 0.0, 0.6, -0.8, 1.0, 1.0, 1.0, 0.05), np.array([*first, *second]),
                     Medium(sig_a, sig_s, 1, 0.0), Query(*p, 0.0, 0.0, 1.0, NO_PLANE), 0.02, False, True, tabs, 0.0,
                     out_d, out_m)
        return out_m[0]

    x, p = (0.0, 0.0, -0.3), (0.4, 0.2, -0.5)
    near = multiple(x, p, top, top)
    far = multiple(x, p, bottom, bottom)
    assert near > 0 and far > 1.05 * near  # the far plane's image takes less away
    assert multiple(x, p, top, bottom) == near and multiple(x, p, bottom, top) == near
    x2, p2 = (0.0, 0.0, -9.6), (0.4, 0.2, -9.3)  # now nearer the bottom
    assert multiple(x2, p2, top, bottom) == multiple(x2, p2, bottom, bottom) > 0
    assert multiple(x2, p2, top, top) > 1.05 * multiple(x2, p2, bottom, bottom)


def test_multiple_term_mirrors_the_source_in_the_camera_points_plane_too():
    """The multiple term's second image, behind P's own boundary plane: under the source's plane (the same
    plane) it changes nothing; across a slab (P under the far face, n_P = -n) the factor 1 - image / table of
    each plane multiplies the table's value, both planes moved out by CURVED_EXTRAPOLATION transport mean free
    paths. (Mirrored in its own plane alone, a source lit on a thick body's far side reached P as if the body
    were the half-space behind that plane: 3.9x volpath's 3+ behind an index-matched sphere lit from the back.)"""
    lay = Layout(extent=10.0, n_rho=16, n_z=32, n_theta=9, n_phi=9, kill_radius=20.0)
    table, _ = build_table(0.95, 0.0, 1, TableSettings(particles=20000, layout=lay, sh_order=8))
    tab = table.render_args()
    tabs = (tab,) * 3
    sig_a, sig_s = np.full(3, 0.05), np.full(3, 0.95)
    top, bottom = np.array([0.0, 0.0, 1.0, 0.0]), np.array([0.0, 0.0, -1.0, 3.0])  # the slab -3 < z < 0
    d = np.array([0.0, 0.6, -0.8])

    def multiple(x, p, pplane):
        out_m = np.zeros(3)
        source_terms(Source(*x, *d, 1.0, 1.0, 1.0, 0.05), np.array([*top, *top]), Medium(sig_a, sig_s, 1, 0.0),
                     Query(*p, 0.0, 0.0, 1.0, pplane), 0.02, False, True, tabs, 0.0, np.zeros(3), out_m)
        return out_m[0]

    x = np.array([0.0, 0.0, -0.3])
    p_near = np.array([0.4, 0.2, -0.5])
    assert multiple(x, p_near, top) == multiple(x, p_near, NO_PLANE) > 0
    p_far = np.array([0.4, 0.6, -2.6])  # 0.4 above the bottom face
    zb = CURVED_EXTRAPOLATION / (0.05 + 0.95)
    r = p_far - x

    def look(rr, dd):
        return scaled_lookup(tab, 1.0, 1.0, *rr, *dd, 0.0, 0.0, 1.0)

    v = look(r, d)
    v_top = look(r - np.array([0.0, 0.0, 2 * (0.3 + zb)]), d * [1, 1, -1])  # image above z = 0
    v_bottom = look(r + np.array([0.0, 0.0, 2 * (2.7 + zb)]), d * [1, 1, -1])  # image below z = -3
    expect = v * (1 - v_top / v) * (1 - v_bottom / v)
    assert 0 < expect < 0.9 * (v - v_top)
    assert multiple(x, p_far, bottom) == pytest.approx(expect, rel=1e-9)
    assert multiple(x, p_far, NO_PLANE) == pytest.approx(v - v_top, rel=1e-9)


def test_multiple_term_reads_the_table_no_nearer_than_the_sources_extent():
    """A source stands for light spread over its extent: the multiple term of a point 0.01 from a source of extent
    0.13 reads the table 0.13 away in the same direction (as double scattering's ball; the table a hundredth of a
    mean free path from its source spiked to hundreds of times the mean on the milk), and a point beyond the extent
    reads it where it lies."""
    lay = Layout(extent=10.0, n_rho=16, n_z=32, n_theta=9, n_phi=9, kill_radius=20.0)
    table, _ = build_table(0.9, 0.7, 1, TableSettings(particles=40000, layout=lay, sh_order=8))
    tab = table.render_args()
    med = Medium(np.full(3, 0.1), np.full(3, 0.9), 1, 0.7)  # sigma_t 1
    d, w = np.array([0.0, 0.6, 0.8]), np.array([0.6, 0.0, 0.8])
    u = np.array([2.0, -1.0, 2.0]) / 3.0
    no_plane = np.array([0.0, 0.0, 1.0, np.inf] * 2)
    for dist, read in ((0.01, 0.13), (0.2, 0.2), (0.0, None)):
        out_m = np.zeros(3)
        source_terms(Source(0.0, 0.0, 0.0, *d, 1.0, 1.0, 1.0, 0.13), no_plane, med, Query(*(dist * u), *w, NO_PLANE),
                     0.02, False, True, (tab,) * 3, 0.0, np.zeros(3), out_m)
        r = read * u if read is not None else 0.13 * d  # (at the source itself: its extent ahead along its beam)
        expected = scaled_lookup(tab, 1.0, 1.0, *r, *d, *w)
        assert expected > 0 and np.all(out_m == pytest.approx(expected, rel=1e-12)), (dist, out_m, expected)


def test_a_wide_source_is_read_no_farther_than_a_transport_mean_free_path():
    """A source much wider than a transport mean free path (a beam 40 mean free paths wide in a dense body) is read
    no farther out than NEAR_READ_TRANSPORT transport mean free paths of the densest channel, and its double
    scattering averaged over a ball no wider: at its extent the light that diffuses within it was lost and the
    ball poked out of the body (a box 1000 mean free paths thick: multiple 0.02 of volpath's 3+, double 0.15 of
    order 2)."""
    lay = Layout(extent=10.0, n_rho=16, n_z=32, n_theta=9, n_phi=9, kill_radius=20.0)
    table, _ = build_table(0.9, 0.7, 1, TableSettings(particles=40000, layout=lay, sh_order=8))
    tab = table.render_args()
    med = Medium(np.full(3, 0.1), np.array([0.9, 1.9, 2.9]), 1, 0.7)  # sigma_t' 0.37, 0.67, 0.97
    cap = NEAR_READ_TRANSPORT / (0.1 + 0.3 * 2.9)
    assert 0.5 < cap < 5.0
    d, w = np.array([0.0, 0.6, 0.8]), np.array([0.6, 0.0, 0.8])
    u = np.array([2.0, -1.0, 2.0]) / 3.0
    no_plane = np.array([0.0, 0.0, 1.0, np.inf] * 2)
    out_d, out_m = np.zeros(3), np.zeros(3)
    source_terms(Source(0.0, 0.0, 0.0, *d, 1.0, 1.0, 1.0, 10.0), no_plane, med, Query(*(0.1 * u), *w, NO_PLANE),
                 0.02, True, True, (tab,) * 3, 0.0, out_d, out_m)
    phases = phase_eval(1, 0.7, float(u @ w)) * phase_eval(1, 0.7, float(u @ d))
    for c, st in enumerate(0.1 + med.sigma_s):
        expected = scaled_lookup(tab, 1.0, st, *(cap * u), *d, *w)
        assert expected > 0 and out_m[c] == pytest.approx(expected, rel=1e-12), (c, out_m, expected)
        double = med.sigma_s[c] * phases * attenuated_inv_r2_ball(0.1, cap, st)
        assert out_d[c] == pytest.approx(double, rel=1e-12), (c, out_d, double)


def test_images_in_a_flat_face_lie_farther_out():
    """Both images (the source's plane and P's) move out by FLAT_FACE_EXTRAPOLATION transport mean free paths where the
    plane is one of the medium's flat faces (either orientation, within the face's tolerance), by
    CURVED_EXTRAPOLATION elsewhere (the rows of the medium's image_k): the same value as the formula with each
    distance, and more light under the face (an index-matched slab read 0.75 of volpath with the curved bodies'
    distance under its faces)."""
    lay = Layout(extent=10.0, n_rho=16, n_z=32, n_theta=9, n_phi=9, kill_radius=20.0)
    table, _ = build_table(0.95, 0.0, 1, TableSettings(particles=20000, layout=lay, sh_order=8))
    tab = table.render_args()
    sig_a, sig_s = np.full(3, 0.05), np.full(3, 0.95)
    top = np.array([0.0, 0.0, 1.0, 0.0])  # the face z = 0, the medium below
    d = np.array([0.0, 0.6, -0.8])
    x, p = np.array([0.0, 0.0, -0.3]), np.array([0.4, 0.2, -0.5])

    def multiple(faces, *image_k):
        out_m = np.zeros(3)
        source_terms(Source(*x, *d, 1.0, 1.0, 1.0, 0.05), np.array([*top, *top]),
                     Medium(sig_a, sig_s, 1, 0.0, faces, *image_k), Query(*p, 0.0, 0.0, 1.0, top), 0.02, False, True,
                     (tab,) * 3, 0.0, np.zeros(3), out_m)
        return out_m[0]

    def expected(k):
        r = p - x
        v = scaled_lookup(tab, 1.0, 1.0, *r, *d, 0.0, 0.0, 1.0)
        vi = scaled_lookup(tab, 1.0, 1.0, *(r - np.array([0.0, 0.0, 2 * (0.3 + k)])), *(d * [1, 1, -1]), 0.0, 0.0,
                           1.0)
        return v * (1 - vi / v)

    face = np.array([[0.0, 0.0, -1.0, -0.0, 1e-3]])  # the same plane, the other orientation
    elsewhere = np.array([[0.0, 0.0, 1.0, 0.01, 1e-3],  # parallel, 10x its tolerance away
                          [1.0, 0.0, 0.0, 0.0, 1e-3]])  # tilted
    assert face.shape[1] == elsewhere.shape[1] == FACE_COLS
    assert multiple(elsewhere) == multiple(np.zeros((0, FACE_COLS)))
    assert multiple(elsewhere) == pytest.approx(expected(CURVED_EXTRAPOLATION), rel=1e-9)
    assert multiple(face) == pytest.approx(expected(FLAT_FACE_EXTRAPOLATION), rel=1e-9)
    assert multiple(face) > 1.05 * multiple(elsewhere) > 0  # (the farther image takes less away)
    # a thick body's grown distances (image_planes.py): the curved row elsewhere, the flat row on the face
    grown = np.array([[0.3] * 3, [0.6] * 3])
    assert multiple(elsewhere, grown) == pytest.approx(expected(0.3), rel=1e-9)
    assert multiple(face, grown) == pytest.approx(expected(0.6), rel=1e-9)


def test_a_plane_is_on_a_flat_face_in_either_orientation_within_its_tolerance():
    faces = np.array([[0.0, 1.0, 0.0, 2.0, 0.01]])
    assert on_flat_face(faces, 0.0, 1.0, 0.0, 2.005)
    assert on_flat_face(faces, 0.0, -1.0, 0.0, -2.0)
    assert not on_flat_face(faces, 0.0, 1.0, 0.0, 2.02)
    assert not on_flat_face(faces, 0.0, 0.6, 0.8, 2.0)
    assert not on_flat_face(np.zeros((0, FACE_COLS)), 0.0, 1.0, 0.0, 2.0)
