"""The multiple-scattering table: energy, positivity, symmetry, exact look-ups, scaling, diffusion limit."""

import math

import numpy as np
import pytest

from pbvol_cli.multiple_scattering import lobes
from pbvol_cli.multiple_scattering.layout import Layout
from pbvol_cli.multiple_scattering.simulate import simulate
from pbvol_cli.physics.phase import phase_eval
from pbvol_cli.multiple_scattering.table import TableSettings, build_table, domain_taper, grid_lookup, scaled_lookup

HG, ISO = 1, 0
SMALL = Layout(extent=10.0, n_rho=16, n_z=32, n_theta=9, n_phi=9, kill_radius=20.0)


def _mean_and_se(alpha, kind, g, layout, particles, runs=8, first_only=False):
    """Scored power per particle from independent runs (different seeds): mean and its standard error."""
    vals = [simulate(alpha, kind, g, layout, particles, seed, first_only=first_only, histogram=False)[1]
            for seed in range(100, 100 + runs)]
    return float(np.mean(vals)), float(np.std(vals, ddof=1) / math.sqrt(runs))


@pytest.mark.parametrize("g", [0.0, 0.8])
def test_scored_power_is_alpha_squared_over_one_minus_alpha(g):
    """Unbounded medium (alpha = 0.5: the walk never reaches the 40 mfp extent): power from the second collision
    on is sum_k>=2 alpha^k = alpha^2 / (1 - alpha)."""
    lay = Layout(extent=40.0, n_rho=16, n_z=32, n_theta=9, n_phi=9, kill_radius=80.0)
    mean, se = _mean_and_se(0.5, HG, g, lay, 20000)
    assert abs(mean - 0.25 / 0.5) < 4 * se
    # and the table, integrated over cells and directions, holds exactly what was scored
    table, S = build_table(0.5, g, HG, TableSettings(particles=20000, layout=lay))
    assert table.metrics["scored_power"] == pytest.approx(table.metrics["simulated_power"], rel=1e-9)


def test_first_collision_analogue_is_alpha():
    """Scoring only the first collision: every particle collides once (inside a 40 mfp box with probability
    1 - e^-40), scattering alpha. The binned table integrates to exactly that."""
    lay = Layout(extent=40.0, n_rho=16, n_z=32, n_theta=9, n_phi=9, kill_radius=80.0)
    H, total, _ = simulate(0.7, HG, 0.6, lay, 5000, 1, first_only=True)
    assert total == pytest.approx(0.7, rel=1e-12)
    S = lobes.dense_table(H, lobes.phase_bin_matrix(HG, 0.6, lay), lay)
    assert np.sum(S * lay.cell_volumes()[..., None] * lay.dir_solid_angles()) == pytest.approx(0.7, rel=1e-9)


def _independent_truncated_power(alpha, g, extent, kill, n, seed):
    """Analog walk in numpy (absorption by survival with probability alpha), written separately from the
    kernel: power scattered at collisions >= 2 inside the box rho < extent, |z| < extent, killed beyond kill."""
    rng = np.random.default_rng(seed)

    def hg_dirs(d):
        u = rng.random(len(d))
        if abs(g) < 1e-3:
            c = 1 - 2 * u
        else:
            c = (1 + g * g - ((1 - g * g) / (1 - g + 2 * g * u)) ** 2) / (2 * g)
        phi = 2 * np.pi * rng.random(len(d))
        s = np.sqrt(np.maximum(0, 1 - c * c))
        # frame around d
        a = np.where(np.abs(d[:, [0]]) > 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
        t1 = np.cross(d, a)
        t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
        t2 = np.cross(d, t1)
        return (s * np.cos(phi))[:, None] * t1 + (s * np.sin(phi))[:, None] * t2 + c[:, None] * d

    pos = np.zeros((n, 3))
    d = hg_dirs(np.tile([0.0, 0.0, 1.0], (n, 1)))
    alive = np.ones(n, bool)
    scored = np.zeros(n)
    k = 0
    while alive.any():
        k += 1
        idx = np.flatnonzero(alive)
        pos[idx] += -np.log(1 - rng.random(len(idx)))[:, None] * d[idx]
        r2 = np.sum(pos[idx] ** 2, axis=1)
        alive[idx[r2 > kill * kill]] = False
        idx = np.flatnonzero(alive)
        if k >= 2:
            inside = (np.hypot(pos[idx, 0], pos[idx, 1]) < extent) & (np.abs(pos[idx, 2]) < extent)
            scored[idx[inside]] += alpha
        absorbed = rng.random(len(idx)) >= alpha
        alive[idx[absorbed]] = False
        idx = np.flatnonzero(alive)
        d[idx] = hg_dirs(d[idx])
    return scored.mean(), scored.std() / math.sqrt(n)


def test_truncated_power_matches_an_independent_walk():
    """High albedo in a small box: much of the alpha^2/(1-alpha) falls outside; the kernel's scored power
    agrees with an independent numpy walk that applies the same truncation."""
    lay = Layout(extent=4.0, n_rho=8, n_z=16, n_theta=6, n_phi=6, kill_radius=8.0)
    mean, se = _mean_and_se(0.95, HG, 0.5, lay, 10000)
    ref, ref_se = _independent_truncated_power(0.95, 0.5, 4.0, 8.0, 40000, 7)
    assert ref < 0.95 ** 2 / 0.05 * 0.8  # the truncation matters here
    assert abs(mean - ref) < 4 * math.hypot(se, ref_se)


@pytest.fixture(scope="module")
def small_table():
    return build_table(0.9, 0.7, HG, TableSettings(particles=40000, layout=SMALL, sh_order=8))


def test_positive_everywhere(small_table):
    table, S = small_table
    assert np.all(S >= 0) and np.all(table.intensity >= 0)
    rng = np.random.default_rng(3)
    n = 20000
    v = table.lookup(rng.uniform(0, 12, n), rng.uniform(-12, 12, n), rng.uniform(-1, 1, n), rng.uniform(-4, 4, n))
    assert np.all(v >= 0) and np.all(np.isfinite(v))
    assert np.any(v > 0)


def test_lookup_is_exact_at_cell_and_direction_centres(small_table):
    table, _ = small_table
    lay = SMALL
    rho_c, z_c = lay.cell_centres()
    tc, pc = lay.dir_centres()
    rng = np.random.default_rng(5)
    for _ in range(300):
        i, j, a, b = rng.integers(lay.n_rho), rng.integers(lay.n_z), rng.integers(lay.n_theta), rng.integers(lay.n_phi)
        got = table.lookup(rho_c[i], z_c[j], math.cos(tc[a]), pc[b])
        leaf = table.leaf[i, j]
        slot = table.leaf_slot[leaf]
        if table.leaf_kind[leaf] == 0:
            shape = max(0.0, float(lobes.sh_at(table.order, np.array([tc[a]]), np.array([pc[b]]))[0] @ table.coef[slot]))
        else:
            shape = lobes.dequantise_all(table.qlobe[slot:slot + 1], table.qmax[slot:slot + 1])[0, a * lay.n_phi + b]
        # the cells' value times the table's window (1 within TAPER_START of the extent)
        window = domain_taper(lay.extent, rho_c[i], z_c[j])
        assert got == pytest.approx(float(table.intensity[i, j]) * shape * window, rel=1e-9, abs=1e-300)
    assert table.lookup(10.5, 0.0, 1.0, 0.0) == 0.0  # outside the extent


def test_the_window_depends_on_the_distance_alone_and_is_continuous():
    """domain_taper: 1 within TAPER_START R, 0 from R on, smooth between, and the same for every (rho, z) at one
    distance (a source and its mirror image, whose frames differ, are cut off alike; the stored cylinder's corners
    rho, |z| < R beyond the sphere of radius R are not used)."""
    R = 10.0
    assert domain_taper(R, 0.0, 0.0) == 1.0 and domain_taper(R, 4.0, 5.0) == 1.0  # 6.4 < 7
    assert domain_taper(R, 8.0, 8.0) == 0.0 and domain_taper(R, 0.0, 10.0) == 0.0
    for r in (7.5, 8.5, 9.5):
        vals = [domain_taper(R, r * math.sin(a), r * math.cos(a)) for a in np.linspace(0, math.pi, 7)]
        assert 0.0 < vals[0] < 1.0 and np.allclose(vals, vals[0], rtol=1e-12)
    r = np.linspace(0.0, R, 2001)
    w = np.array([domain_taper(R, x, 0.0) for x in r])
    # monotone, and no step larger than smoothstep's steepest slope, 1.5 / (R - TAPER_START R), allows
    assert np.all(np.diff(w) <= 1e-15) and np.max(np.abs(np.diff(w))) <= 1.5 / (0.3 * R) * (r[1] - r[0]) * 1.001


def test_render_form_equals_the_compact_form_at_centres(small_table):
    """The renderer's expanded grid lobes give the compact table's values at cell and direction-bin centres."""
    table, _ = small_table
    args = table.render_args()
    rho_c, z_c = SMALL.cell_centres()
    tc, pc = SMALL.dir_centres()
    rng = np.random.default_rng(8)
    for _ in range(300):
        i, j, a, b = rng.integers(SMALL.n_rho), rng.integers(SMALL.n_z), rng.integers(SMALL.n_theta), rng.integers(SMALL.n_phi)
        want = table.lookup(rho_c[i], z_c[j], math.cos(tc[a]), pc[b])
        assert grid_lookup(*args, rho_c[i], z_c[j], math.cos(tc[a]), pc[b]) == pytest.approx(float(want), rel=1e-5,
                                                                                           abs=1e-30)


def test_lobes_decoded_by_look_up_equal_each_codes_exponential():
    """dequantise_all and dequantise_rows (the renderer's form, written in place) give, for every code and a
    spread of maxima, the exponential of each code evaluated anew (bit for bit) and dequantise's value (to
    rounding: a scalar exp), code 0 zero; dequantise_rows writes the rows asked and nothing elsewhere."""
    rng = np.random.default_rng(3)
    q = np.vstack([np.arange(256, dtype=np.uint8), rng.integers(0, 256, (5, 256)).astype(np.uint8)])
    vmax = np.array([1.0, 3.5e-7, 2.0e4, 0.0, 0.37, 1e30], np.float32)
    want = np.where(q == 0, 0.0, vmax[:, None] * np.exp((q.astype(np.float64) - 255.0) * lobes._Q_STEP))
    assert np.array_equal(lobes.dequantise_all(q, vmax), want)
    scalar = np.array([[lobes.dequantise(int(c), float(v)) for c in row] for row, v in zip(q, vmax)])
    assert np.allclose(want, scalar, rtol=1e-14, atol=0.0)
    assert np.all(want[q == 0] == 0.0) and want[0, 255] == 1.0
    out = np.full((8, 256), -1.0, np.float32)
    lobes.dequantise_rows(q, vmax, np.array([4, 0, 2], np.int64), np.array([1, 5, 6], np.int64), out)
    assert np.array_equal(out[[1, 5, 6]], want[[4, 0, 2]].astype(np.float32))
    assert np.all(out[[0, 2, 3, 4, 7]] == -1.0)


def test_compact_form_is_close_to_the_dense_table(small_table):
    table, _ = small_table
    assert table.metrics["err_compact_vs_dense_99"] < 0.05


def test_mirror_symmetry_for_an_isotropic_source():
    """Isotropic scattering: the field is symmetric under z -> -z, and the look-up under phi -> -phi."""
    table, S = build_table(0.9, 0.0, ISO, TableSettings(particles=60000, layout=SMALL, sh_order=8))
    I = table.intensity.astype(float)
    V = SMALL.cell_volumes()
    # per cell, the difference between mirrored cells against the Poisson-like noise of the cell's score
    top = I[:, SMALL.n_z // 2:], I[:, : SMALL.n_z // 2][:, ::-1]
    rel = np.abs(top[0] - top[1]) / np.maximum(top[0] + top[1], 1e-300)
    energetic = (top[0] * V[:, SMALL.n_z // 2:]) > 1e-3 * (I * V).max()
    assert np.median(rel[energetic]) < 0.05
    assert np.sum((top[0] - top[1]) * V[:, SMALL.n_z // 2:]) == pytest.approx(0.0, abs=0.02 * np.sum(I * V))
    rng = np.random.default_rng(1)
    r, z, c, p = rng.uniform(0, 9, 200), rng.uniform(-9, 9, 200), rng.uniform(-1, 1, 200), rng.uniform(0, 3, 200)
    assert np.array_equal(table.lookup(r, z, c, p), table.lookup(r, z, c, -p))


def test_scaled_lookup_is_the_single_place_of_units(small_table):
    """S_real(x, w) = Phi sigma_t^3 S(sigma_t x, w) in the source's frame, for any orientation of the axis."""
    table, _ = small_table
    rng = np.random.default_rng(2)
    for _ in range(50):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        r = rng.normal(size=3) * 2
        w = rng.normal(size=3)
        w /= np.linalg.norm(w)
        phi_pow, st = rng.uniform(0.5, 3), rng.uniform(0.3, 3)
        got = scaled_lookup(table.render_args(), phi_pow, st, *r, *axis, *w)
        z = r @ axis
        rp = r - z * axis
        rho = np.linalg.norm(rp)
        e_rho = rp / rho
        e_phi = np.cross(axis, e_rho)
        ref = phi_pow * st ** 3 * grid_lookup(*table.render_args(), st * rho, st * z, w @ axis,
                                              math.atan2(w @ e_phi, w @ e_rho))
        assert got == pytest.approx(float(ref), rel=1e-9, abs=1e-300)
        # rotating position and direction together about the axis changes nothing
        ang = rng.uniform(0, 2 * np.pi)
        K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        Rm = np.eye(3) + math.sin(ang) * K + (1 - math.cos(ang)) * K @ K
        rot = scaled_lookup(table.render_args(), phi_pow, st, *(Rm @ r), *axis, *(Rm @ w))
        assert rot == pytest.approx(got, rel=1e-6, abs=1e-300)


def test_far_field_follows_diffusion_theory():
    """alpha = 0.99, isotropic: far from the source the fluence (here the lobe integral, alpha x collision
    density) decays as exp(-sigma_tr r) / r with sigma_tr = sqrt(3 sigma_a sigma_t') = sqrt(3 (1 - alpha))."""
    lay = Layout(extent=24.0, n_rho=32, n_z=64, n_theta=6, n_phi=6, kill_radius=48.0)
    table, _ = build_table(0.99, 0.0, ISO, TableSettings(particles=100000, layout=lay, sh_order=4))
    rho_c, z_c = lay.cell_centres()
    RHO, Z = np.meshgrid(rho_c, z_c, indexing="ij")
    R = np.hypot(RHO, Z)
    # cells of reasonable volume (the near-axis cells are tiny and mostly empty) in the far field
    sel = (R > 6) & (R < 18) & (RHO > 1) & (table.intensity > 0)
    y = np.log(table.intensity.astype(float)[sel] * R[sel])
    slope = np.polyfit(R[sel], y, 1, w=np.sqrt(table.intensity[sel] * lay.cell_volumes()[sel]))[0]
    sigma_tr = math.sqrt(3 * 0.01)
    # Diffusion is an approximation: the exact asymptotic decay of transport theory, kappa with
    # alpha/(2 kappa) ln((1+kappa)/(1-kappa)) = 1, is 0.4% below sigma_tr here; the rest is Monte Carlo noise.
    assert -slope == pytest.approx(sigma_tr, rel=0.02)


def test_first_collision_table_reproduces_the_double_scattering_kernel():
    """A table scoring only the first collision is the double-scattering kernel of a point source. Looked up through
    scaled_lookup (the renderer's path for multiple scattering: frame, units, phase convention), it must match the
    closed form sigma_s p(m . w) Phi p(d . m) exp(-sigma_t r) / r^2 used for double scattering."""
    alpha, g, st = 0.7, 0.5, 2.0
    lay = Layout(extent=8.0, n_rho=32, n_z=64, n_theta=18, n_phi=18, kill_radius=16.0)
    table, _ = build_table(alpha, g, 1, TableSettings(particles=400000, layout=lay, merge_tol=0.0, sh_tol=0.0),
                           first_collision=True)
    args = table.render_args()
    rng = np.random.default_rng(12)
    axis = np.array([0.2, -0.3, 0.93])
    axis /= np.linalg.norm(axis)
    got, want = [], []
    for _ in range(400):
        r = rng.normal(size=3)
        r *= rng.uniform(0.6, 2.0) / st / np.linalg.norm(r)  # 0.6 to 2 mean free paths from the source
        w = rng.normal(size=3)
        w /= np.linalg.norm(w)
        dist = np.linalg.norm(r)
        m = r / dist
        want.append(alpha * st * phase_eval(1, g, m @ w) * 1.5 * phase_eval(1, g, axis @ m) * np.exp(-st * dist)
                    / dist ** 2)
        got.append(scaled_lookup(args, 1.5, st, *r, *axis, *w))
    got, want = np.array(got), np.array(want)
    # measured: aggregate 0.997, median point error 3.3% (90th percentile 8.8%: 10-degree direction bins and
    # cells of 0.1-0.3 mfp blur the kernel); the bounds leave room for the Monte Carlo noise of the table
    assert got.sum() / want.sum() == pytest.approx(1.0, abs=0.02)
    assert np.median(np.abs(got / want - 1)) < 0.06


def test_relative_error_of_a_table_without_light_is_zero_not_nan():
    """A coarse table of a nearly black medium may catch no light at all: its quality metrics read 0 (no warning,
    no NaN in the table's metadata); a table that misses light it should hold reads inf."""
    from pbvol_cli.multiple_scattering.table import relative_error

    zero, w = np.zeros((4, 3)), np.ones((4, 3))
    assert relative_error(zero, zero, w) == 0.0
    assert relative_error(np.ones((4, 3)), zero, w) == math.inf
    assert relative_error(np.full((4, 3), 1.1), np.ones((4, 3)), w) == pytest.approx(0.1)
