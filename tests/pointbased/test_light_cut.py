"""The stochastic light cut: unbiased for any cut, exact when refined to every leaf."""

from types import SimpleNamespace

import numpy as np
import pytest

from pbvol_cli.geometry.scene_build import MED_COLS, MED_G, MED_PHASE, MED_SIGMA_A, MED_SIGMA_S
from pbvol_cli.multiple_scattering.layout import Layout
from pbvol_cli.multiple_scattering.table import TableSettings, build_table, empty_table
from pbvol_cli.physics.phase import phase_eval
from pbvol_cli.pointbased.inverse_square import attenuated_inv_r2_ball
from pbvol_cli.pointbased.light_cut import double_multiple
from pbvol_cli.pointbased.octree import (LOBE_CENTRE, LOBE_EXT2, LOBE_HI, LOBE_LO, LOBE_SPREAD2, build_octree,
                                         node_lobes)
from pbvol_cli.pointbased.sources import NEAR_ALONG, Source, source_terms
from pbvol_cli.pointbased.volume_samples import NO_PLANE, Medium, Query, SampleSet, VolumeSamples, medium_params

SIG_S, SIG_A, G = np.array([0.6, 1.0, 2.0]), np.array([0.2, 0.5, 0.1]), 0.5


@pytest.mark.parametrize("spread, r_near", [(0.1, 0.0), (10.0, 0.0), (10.0, 1.2)])
def test_stochastic_light_cut_is_unbiased(spread, r_near):
    """A cut refined down to every leaf is the exhaustive sum (the formula, summed by hand); a small cut, whose
    nodes each contribute one random representative, averages to it (4 standard errors over 4000 estimates), for
    nearly parallel beams (spread 0.1) and random directions, and with the near field summed apart (r_near: 58 of
    the 400 sources within it, 2 wholly). (The deterministic cuts this replaced, node centroids with averaged
    lobes, were 10-25% low on the oil scene's g = 0.9 samples.)"""
    rng = np.random.default_rng(4)
    n = 400
    centre = rng.normal(size=(n, 3)) * 0.5
    d = np.array([0.3, -0.2, 0.9]) + spread * rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    scat = rng.random((n, 3))
    # segments of length 0 (points), so the formula below is exact for them
    length, start, rb = np.zeros(n), centre.copy(), np.full(n, 0.01)
    no_plane = np.tile([0.0, 0.0, 1.0, np.inf] * 2, (n, 1))  # no boundary (entry and exit planes at infinity)
    tree = build_octree(centre, centre - 0.01, centre + 0.01, d, scat).arrays()
    tabs = (empty_table().render_args(),) * 3
    P = np.array([1.5, 0.2, -0.3])
    w = np.array([0.0, 0.6, 0.8])
    exact = exact_double(centre, d, scat, P, w, SIG_S, SIG_A, G)
    state = np.array([7], np.uint64)
    out_d, out_m = np.zeros(3), np.zeros(3)
    n_nodes = len(tree[1])
    vs = VolumeSamples(tree, start, d, length, scat, np.zeros(n), centre, scat, rb, np.zeros(n, np.int64), no_plane,
                       tabs, r_near, node_lobes(tree))
    med, q = Medium(SIG_A, SIG_S, 1, G), Query(*P, *w, NO_PLANE)
    double_multiple(vs, med, q, n_nodes, 0.02, True, False, out_d, out_m, state, 0)
    assert out_d == pytest.approx(exact, rel=1e-9)
    runs = np.zeros((4000, 3))
    for k in range(len(runs)):
        double_multiple(vs, med, q, 4, 0.02, True, False, runs[k], out_m, state, 0)
    mean, se = runs.mean(0), runs.std(0) / np.sqrt(len(runs))
    assert np.all(runs.std(0) > 0)  # the small cut is stochastic
    assert np.all(np.abs(mean - exact) < 4 * se), (mean, exact, se)


def test_multiple_scattering_cut_is_unbiased_with_sources_around_the_point():
    """The multiple term's small cut (its representatives drawn by importance toward P, as double scattering's)
    averages to the exhaustive sum over every source (4 standard errors over 3000 estimates) for a cloud of
    sources around P, some within a tenth of a mean free path of it, where drawing by power alone made spikes. Its
    cut is the one after ms_cut refinements, however far double scattering's is refined (the same estimate, bit for
    bit, with double's cut at 8, 2 or 0)."""
    lay = Layout(extent=10.0, n_rho=16, n_z=32, n_theta=9, n_phi=9, kill_radius=20.0)
    table, _ = build_table(0.95, 0.3, 1, TableSettings(particles=20000, layout=lay, sh_order=8))
    tabs = (table.render_args(),) * 3
    sig_a, sig_s = np.full(3, 0.05), np.full(3, 0.95)
    rng = np.random.default_rng(5)
    n = 300
    P = np.array([0.2, -0.1, 0.3])
    w = np.array([0.0, 0.6, 0.8])
    centre = P + rng.normal(size=(n, 3)) * np.where(np.arange(n) < 30, 0.1, 1.5)[:, None]
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    scat = rng.random((n, 3)) + 0.1
    length, rb = np.zeros(n), np.full(n, 0.01)
    no_plane = np.tile([0.0, 0.0, 1.0, np.inf] * 2, (n, 1))
    tree = build_octree(centre, centre - 0.01, centre + 0.01, d, scat).arrays()
    med, q = Medium(sig_a, sig_s, 1, 0.3), Query(*P, *w, NO_PLANE)
    exact = np.zeros(3)
    for i in range(n):
        source_terms(Source(*centre[i], *d[i], *scat[i], 0.01), no_plane[i], med, q, 0.02, False, True, tabs, 0.0,
                     np.zeros(3), exact)
    assert np.all(exact > 0)
    state = np.array([11], np.uint64)
    runs = np.zeros((3000, 3))
    vs = VolumeSamples(tree, centre, d, length, scat, np.zeros(n), centre, scat, rb, np.zeros(n, np.int64), no_plane,
                       tabs, 0.0, node_lobes(tree))
    for k in range(len(runs)):
        double_multiple(vs, med, q, 8, 0.02, False, True, np.zeros(3), runs[k], state, 0)
    mean, se = runs.mean(0), runs.std(0) / np.sqrt(len(runs))
    assert np.all(runs.std(0) > 0)  # the cut is stochastic
    assert np.all(np.abs(mean - exact) < 4 * se), (mean, exact, se)
    # the multiple term's cut is set by ms_cut alone (8 // MULTIPLE_CUT_SHARE by default), whatever double's
    for cut, ms_cut in ((8, -1), (2, 2), (0, 2)):
        om, st = np.zeros(3), np.array([11], np.uint64)
        double_multiple(vs, med, q, cut, 0.02, True, True, np.zeros(3), om, st, 0, ms_cut)
        if cut == 8:
            reference = om
        assert np.array_equal(om, reference), (cut, ms_cut)


def test_a_long_segment_near_the_point_is_drawn_as_often_as_it_weighs():
    """A segment 6 long (a dense medium's bounced beam) passing 0.2 from P among 300 short ones 2-4 away, each of
    the same power: the cut's representatives judge a segment by its whole length (1/r^2 averaged along it), so
    the long one, a few per cent of double scattering there, is drawn about as often as it weighs. Judged at its
    centre with an extent of half its length it was drawn far too rarely: the estimate's relative spread over
    3000 cuts read 1.94, 0.91 now. Unbiased either way (4 standard errors from the cut refined to every leaf)."""
    rng = np.random.default_rng(9)
    n = 301
    P = np.array([0.0, 0.0, 0.0])
    w = np.array([0.0, 0.6, 0.8])
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    centre = u * rng.uniform(2.0, 4.0, n)[:, None]
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    length, rb = np.full(n, 0.05), np.full(n, 0.05)
    d[0], length[0] = np.array([1.0, 0.0, 0.0]), 6.0  # the long one: from (-1, 0.2, 0) to (5, 0.2, 0)
    centre[0] = np.array([2.0, 0.2, 0.0])
    start = centre - 0.5 * length[:, None] * d
    scat = np.full((n, 3), 0.5)
    no_plane = np.tile([0.0, 0.0, 1.0, np.inf] * 2, (n, 1))
    end = start + length[:, None] * d
    lo, hi = np.minimum(start, end) - rb[:, None], np.maximum(start, end) + rb[:, None]
    tree = build_octree(centre, lo, hi, d, scat).arrays()
    vs = VolumeSamples(tree, start, d, length, scat, np.pi * rb ** 2, centre, scat, rb, np.zeros(n, np.int64), no_plane,
                       (empty_table().render_args(),) * 3, 0.0, node_lobes(tree))
    med, q = Medium(SIG_A, SIG_S, 1, G), Query(*P, *w, NO_PLANE)
    state = np.array([3], np.uint64)
    exact = np.zeros(3)  # the cut refined to every leaf: every sample's terms
    double_multiple(vs, med, q, len(tree[1]), 0.02, True, False, exact, np.zeros(3), state, 0)
    runs = np.zeros((3000, 3))
    for k in range(len(runs)):
        double_multiple(vs, med, q, 4, 0.02, True, False, runs[k], np.zeros(3), state, 0)
    spread = runs.mean(1).std() / runs.mean(1).mean()
    assert spread < 1.5, spread
    assert np.all(np.abs(runs.mean(0) - exact) < 4 * runs.std(0) / np.sqrt(len(runs)))




def _cloud(rng, n, r_lo, r_hi):
    """n source centres at random directions r_lo-r_hi from the origin, and random unit directions."""
    u = rng.normal(size=(n, 3))
    centre = u / np.linalg.norm(u, axis=1, keepdims=True) * rng.uniform(r_lo, r_hi, n)[:, None]
    d = rng.normal(size=(n, 3))
    return centre, d / np.linalg.norm(d, axis=1, keepdims=True)


def _sample_set(centre, d, length, radius, sigma_a, sigma_s, g, tables, beam_width):
    """A SampleSet's kernel and Medium for segments centred at centre (unit power, beam radius `radius`, no
    boundary) in a Henyey-Greenstein medium."""
    n = len(centre)
    samples = SimpleNamespace(v_start=centre - 0.5 * length[:, None] * d, v_dir=d, v_len=length,
                              v_power=np.ones((n, 3)), v_area=np.pi * radius ** 2, v_medium=np.zeros(n, np.int64),
                              v_ends=np.zeros(n, np.int64), v_plane=np.tile([0.0, 0.0, 1.0, np.inf] * 2, (n, 1)))
    media = np.zeros((1, MED_COLS))
    media[0, MED_SIGMA_A:MED_SIGMA_A + 3], media[0, MED_SIGMA_S:MED_SIGMA_S + 3] = sigma_a, sigma_s
    media[0, MED_PHASE], media[0, MED_G] = 1, g
    return SampleSet(samples, 0, media, tables, beam_width=beam_width).kernel, medium_params(media, 0)


def _cut_spreads(vs, med, q, lobe_variants, runs, do_double):
    """The relative spread of `runs` small cuts (double scattering, else multiple) with each of lobe_variants as
    the tree's lobes; the first variant's mean must be the cut refined to every leaf's (4 standard errors)."""
    state = np.array([5], np.uint64)
    exact = np.zeros((2, 3))  # (the multiple term's cut is a quarter of the double's: refined 4x as far)
    double_multiple(vs, med, q, 4 * len(vs.tree[1]), 0.02, do_double, not do_double, exact[0], exact[1], state, 0)
    spreads = []
    for lobes in lobe_variants:
        est = np.zeros((runs, 2, 3))
        for k in range(runs):
            double_multiple(vs._replace(lobes=lobes), med, q, 4, 0.02, do_double, not do_double, est[k, 0],
                            est[k, 1], state, 0)
        est = est[:, 0 if do_double else 1]
        spreads.append(est.mean(1).std() / est.mean(1).mean())
        if len(spreads) == 1:
            assert np.all(np.abs(est.mean(0) - exact[0 if do_double else 1]) < 4 * est.std(0) / np.sqrt(runs))
    return spreads


def test_a_source_near_the_point_is_drawn_as_often_as_it_weighs_whatever_its_kernel_box():
    """A wide beam's short segment 0.25 from P, its lobe and phase toward P, among 2000 narrow ones 0.5-3 away, in a
    set whose single-scattering kernel is 8 beam radii wide (the octree's boxes hold it): the light cut judges its
    nodes by their samples' own extent (segment and beam radius), and the near source's nodes are not floored by its
    kernel's 3.2 radius. Judged by the kernel boxes (as the milk's bounced set was), the multiple term's relative
    spread over 2000 cuts read 1.9, 0.36 with its own: it must be below half that, and unbiased. The nodes' spread
    (test below) also lifts that floor: with the kernel boxes and the spread it reads 0.46, and the own boxes must
    stay below 0.9 of that."""
    lay = Layout(extent=10.0, n_rho=16, n_z=32, n_theta=9, n_phi=9, kill_radius=20.0)
    table, _ = build_table(0.95, 0.7, 1, TableSettings(particles=20000, layout=lay, sh_order=8))
    n = 2001
    centre, d = _cloud(np.random.default_rng(12), n, 0.5, 3.0)
    centre[0], d[0] = np.array([-0.25, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])  # behind P, pointing through it
    vs, med = _sample_set(centre, d, np.full(n, 0.15), np.where(np.arange(n) == 0, 0.4, 0.05), 0.05, 0.95, 0.7,
                          (table.render_args(),) * 3, 8.0)
    q = Query(0.0, 0.0, 0.0, 1.0, 0.0, 0.0, NO_PLANE)
    kernel_boxes = node_lobes(vs.tree)
    kernel_boxes[:, LOBE_SPREAD2] = vs.lobes[:, LOBE_SPREAD2]  # (the same samples: only the boxes differ)
    spreads = _cut_spreads(vs, med, q, (vs.lobes, kernel_boxes, _centroid_floor(kernel_boxes, np.zeros(3))), 2000,
                           False)
    assert spreads[0] < 0.5 * spreads[2] and spreads[0] < 0.9 * spreads[1], spreads


def test_a_node_holding_a_long_segment_by_the_point_is_judged_by_its_box():
    """A segment 4 long passing 0.2 from P among 2000 short ones 1-3 away: its node's centroid lies far from P, and
    the light cut raises the node's importance by how much nearer P lies to its box (octree LOBE_LO, LOBE_HI).
    With each node's box collapsed to its centroid (judged at the centroid alone) double scattering's relative
    spread over 3000 cuts read 1.20, 0.78 with the boxes: it must stay below 0.8 of that, and unbiased."""
    n = 2001
    centre, d = _cloud(np.random.default_rng(9), n, 1.0, 3.0)
    length = np.full(n, 0.1)
    d[0], length[0], centre[0] = np.array([1.0, 0.0, 0.0]), 4.0, np.array([1.5, 0.2, 0.0])  # from (-0.5, 0.2, 0)
    vs, med = _sample_set(centre, d, length, np.full(n, 0.05), 0.1, 0.9, 0.5, (empty_table().render_args(),) * 3,
                          2.0)
    collapsed = vs.lobes.copy()
    collapsed[:, LOBE_LO:LOBE_LO + 3] = collapsed[:, LOBE_CENTRE:LOBE_CENTRE + 3]
    collapsed[:, LOBE_HI:LOBE_HI + 3] = collapsed[:, LOBE_CENTRE:LOBE_CENTRE + 3]
    spreads = _cut_spreads(vs, med, Query(0.0, 0.0, 0.0, 0.0, 0.6, 0.8, NO_PLANE), (vs.lobes, collapsed), 3000, True)
    assert spreads[0] < 0.8 * spreads[1], spreads


def _centroid_floor(lobes, p):
    """lobes with each node's spread replaced so that the cut judges it no nearer than a quarter of its extent (the
    floor before the spread) wherever its box holds p: (r^2 + spread^2) / 4 = extent^2 / 16 at p."""
    out = lobes.copy()
    out[:, LOBE_SPREAD2] = out[:, LOBE_EXT2] / 4 - np.sum((out[:, LOBE_CENTRE:LOBE_CENTRE + 3] - p) ** 2, 1)
    return out


def test_nodes_whose_boxes_all_hold_the_point_are_told_apart_by_their_spread():
    """1000 segments 5 long (a dense medium's bounced beams) centred within 3 of P, so that nearly every node's box
    holds P, and 200 short ones 0.4-1.2 from P (g = 0.8): the cut judges a node whose box holds P no nearer than
    half the rms distance of its power from P (its spread, octree LOBE_SPREAD2) where that is nearer than a quarter
    of its extent, and finds the nodes whose power lies near P more often. The relative spread over 2000 cuts,
    against each node judged by its extent alone: double scattering 1.23 against 1.43, multiple 0.84 against 0.96
    (by the spread alone, without the extent's floor beside it: 1.19 and 0.77, but among 2000 short segments one
    1.6 long passing 0.05 from P made double scattering read 0.96 against 0.88, so the cut takes the nearer of the
    two floors). Both must stay below 0.9 of the extent's, and unbiased."""
    rng = np.random.default_rng(21)
    cl, dl = _cloud(rng, 1000, 0.0, 3.0)
    cn, dn = _cloud(rng, 200, 0.4, 1.2)
    centre, d = np.vstack([cl, cn]), np.vstack([dl, dn])
    length = np.concatenate([np.full(1000, 5.0), np.full(200, 0.3)])
    lay = Layout(extent=10.0, n_rho=16, n_z=32, n_theta=9, n_phi=9, kill_radius=20.0)
    table, _ = build_table(0.95, 0.8, 1, TableSettings(particles=20000, layout=lay, sh_order=8))
    vs, med = _sample_set(centre, d, length, np.full(len(centre), 0.05), 0.05, 0.95, 0.8,
                          (table.render_args(),) * 3, 2.0)
    q = Query(0.0, 0.0, 0.0, 0.0, 0.6, 0.8, NO_PLANE)
    for do_double in (True, False):
        spreads = _cut_spreads(vs, med, q, (vs.lobes, _centroid_floor(vs.lobes, np.zeros(3))), 2000, do_double)
        assert spreads[0] < 0.9 * spreads[1], (do_double, spreads)


def test_a_beam_through_the_point_is_summed_along_it_not_drawn():
    """Double scattering near P from a beam that passes through P (inside its own radius), its segments upstream of
    P at 1.2 to 2.8 near-field radii: the near field reaches NEAR_ALONG times farther along a beam than across it
    (sources.beam_distance), so those segments are summed (partly) exactly instead of drawn by the cut from among
    sources (a milk glass's bins read 40x their mean from such a draw). Among 20 000 brighter sources all around
    P, the estimate stays unbiased (4 standard errors over 3000 estimates) and one estimate's standard deviation
    stays under three times the exact sum."""
    rng = np.random.default_rng(8)
    n_far = 20000
    far = rng.normal(size=(n_far, 3)) * 1.5  # bright sources all around P
    far = far[np.linalg.norm(far, axis=1) > 0.5]
    n_far = len(far)
    R = 0.25
    P = np.zeros(3)
    w = np.array([0.0, 0.0, 1.0])  # toward the camera: along the beam, into its forward lobe
    beam = np.array([[0.02, 0.0, -z] for z in np.linspace(1.2 * R, 2.8 * R, 6)])  # upstream of P along +z
    assert NEAR_ALONG * R > 2.8 * R  # (all of them within the near field's reach along the beam)
    centre = np.concatenate([far, beam])
    n = len(centre)
    d = np.concatenate([rng.normal(size=(n_far, 3)), np.tile([0.0, 0.0, 1.0], (len(beam), 1))])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    scat = np.concatenate([np.full((n_far, 3), 0.1), np.full((len(beam), 3), 1e-3)])
    length, rb = np.zeros(n), np.full(n, 0.05)
    no_plane = np.tile([0.0, 0.0, 1.0, np.inf] * 2, (n, 1))
    tree = build_octree(centre, centre - 0.05, centre + 0.05, d, scat).arrays()
    tabs = (empty_table().render_args(),) * 3
    sig_s, sig_a, g = np.full(3, 0.5), np.full(3, 0.05), 0.9
    exact = exact_double(centre, d, scat, P, w, sig_s, sig_a, g)
    beam_share = 1.0 - exact_double(centre[:n_far], d, scat, P, w, sig_s, sig_a, g)[0] / exact[0]
    assert beam_share > 0.5  # the beam holds most of P's double scattering
    vs = VolumeSamples(tree, centre.copy(), d, length, scat, np.zeros(n), centre, scat, rb, np.zeros(n, np.int64),
                       no_plane, tabs, R, node_lobes(tree))
    med, q = Medium(sig_a, sig_s, 1, g), Query(*P, *w, NO_PLANE)
    state = np.array([11], np.uint64)
    runs, out_m = np.zeros((3000, 3)), np.zeros(3)
    for k in range(len(runs)):
        double_multiple(vs, med, q, 4, 0.02, True, False, runs[k], out_m, state, 0)
    mean, se = runs.mean(0), runs.std(0) / np.sqrt(len(runs))
    assert np.all(np.abs(mean - exact) < 4 * se + 1e-12 * exact), (mean, exact, se)
    # one estimate's spread: 1.7x the exact sum, 8.5x where the near field reached as far along a beam as across
    assert runs[:, 0].std() < 3.0 * exact[0], (runs[:, 0].std(), exact[0])



def exact_double(centre, d, scat, P, w, sig_s, sig_a, g):
    """Double scattering at P toward w from point sources (centre, beam direction d, scattered power scat), summed
    by hand as sources.source_terms gives it (Henyey-Greenstein g, the kernel's ball 0.02 wide), per channel."""
    exact = np.zeros(3)
    for i in range(len(centre)):
        r = P - centre[i]
        dist = np.linalg.norm(r)
        m = r / dist
        f = phase_eval(1, g, m @ w) * phase_eval(1, g, d[i] @ m)
        exact += sig_s * scat[i] * f * np.array([attenuated_inv_r2_ball(dist, 0.02, st) for st in sig_s + sig_a])
    return exact


def test_the_cuts_dim_nodes_played_by_roulette_keep_it_unbiased_and_cost_less():
    """With roulette 0.05 double scattering's cut evaluates its nodes under 5 % of its importance at P (and 25 % of
    its power) at odds in proportion to their share, weighted by the inverse: it still averages to the cut refined
    to every leaf (4 standard errors over 4000 estimates), for g = 0.9 lobes in all directions around P, where most
    nodes' lobes turn away from it, while a fifth fewer samples are evaluated. The multiple term's cut keeps every
    node (the same estimates, bit for bit), and roulette 0 is the plain cut."""
    lay = Layout(extent=10.0, n_rho=16, n_z=32, n_theta=9, n_phi=9, kill_radius=20.0)
    table, _ = build_table(0.95, 0.9, 1, TableSettings(particles=20000, layout=lay, sh_order=8))
    rng = np.random.default_rng(21)
    n = 500
    P, w = np.array([0.2, -0.1, 0.3]), np.array([0.0, 0.6, 0.8])
    offset, d = _cloud(rng, n, 0.3, 4.0)
    centre = P + offset
    length, rb = np.full(n, 0.05), np.full(n, 0.02)
    start = centre - 0.5 * length[:, None] * d
    scat = rng.random((n, 3)) + 0.1
    end = start + length[:, None] * d
    tree = build_octree(centre, np.minimum(start, end) - rb[:, None], np.maximum(start, end) + rb[:, None], d,
                        scat).arrays()
    no_plane = np.tile([0.0, 0.0, 1.0, np.inf] * 2, (n, 1))
    vs = VolumeSamples(tree, start, d, length, scat, np.pi * rb ** 2, centre, scat, rb, np.zeros(n, np.int64),
                       no_plane, (table.render_args(),) * 3, 0.0, node_lobes(tree))
    med, q = Medium(np.full(3, 0.05), np.full(3, 0.95), 1, 0.9), Query(*P, *w, NO_PLANE)
    exact = np.zeros(3)
    double_multiple(vs, med, q, 4 * len(tree[1]), 0.02, True, False, exact, np.zeros(3), np.array([1], np.uint64), 0)
    assert np.all(exact > 0)
    runs, cost = {}, {}
    for roulette in (0.0, 0.05):
        state = np.array([5], np.uint64)
        runs[roulette], cost[roulette] = np.zeros((4000, 2, 3)), np.zeros(4000)
        for j in range(4000):
            cost[roulette][j] = double_multiple(vs, med, q, 8, 0.02, True, j % 2 == 0, runs[roulette][j, 0],
                                                runs[roulette][j, 1], state, 0, -1, roulette)
        est = runs[roulette][:, 0]
        mean, se = est.mean(0), est.std(0) / np.sqrt(len(est))
        assert np.all(np.abs(mean - exact) < 4 * se), (roulette, mean, exact, se)
    assert cost[0.05].mean() < 0.8 * cost[0.0].mean(), (cost[0.05].mean(), cost[0.0].mean())
    assert not np.array_equal(runs[0.05][:, 0], runs[0.0][:, 0])
    # the multiple term alone: every node of its cut, whatever roulette
    for roulette in (None, 0.0, 0.05):
        st, om = np.array([5], np.uint64), np.zeros(3)
        args = (vs, med, q, 8, 0.02, False, True, np.zeros(3), om, st, 0)
        double_multiple(*args) if roulette is None else double_multiple(*args, -1, roulette)
        if roulette is None:
            plain, plain_state = om, st[0]
        assert np.all(om > 0) and np.array_equal(om, plain) and st[0] == plain_state
