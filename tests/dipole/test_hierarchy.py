"""The hierarchical sum M_o against the brute-force sum over every irradiance sample."""

import numpy as np

from pbvol_cli.dipole.hierarchy import IrradianceTree
from pbvol_cli.dipole.profile import boundary_a, dipole_params


def brute_mo(pos, power, params, a, q):
    """sum_j R_d(|p_j - q|) Phi_j, written with numpy (R_d as in Jensen et al. 2001)."""
    out = np.zeros((len(q), 3))
    for c in range(3):
        alpha, s, zr, d = params[c]
        zv = zr + 4 * a * d
        r2 = ((pos[None, :, :] - q[:, None, :]) ** 2).sum(-1)
        dr, dv = np.sqrt(r2 + zr ** 2), np.sqrt(r2 + zv ** 2)
        rd = alpha / (4 * np.pi) * (zr * (s * dr + 1) * np.exp(-s * dr) / dr ** 3
                                    + zv * (s * dv + 1) * np.exp(-s * dv) / dv ** 3)
        out[:, c] = rd @ power[:, c]
    return out


def sphere_samples(n=6000, radius=1.0, seed=1):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    lit = np.clip(d @ np.array([0.3, 0.8, 0.5]), 0, None)  # a light from one side, its cosine
    power = lit[:, None] * np.array([1.0, 0.8, 0.5]) * (4 * np.pi * radius ** 2 / n)
    return radius * d, power, np.full(n, 4 * np.pi * radius ** 2 / n), d


def test_zero_error_is_the_brute_force_sum():
    pos, power, area, nrm = sphere_samples()
    params = dipole_params([0.02, 0.05, 0.1], [8.0, 10.0, 12.0], 0.0)
    a = boundary_a(1.4)
    q = pos[::97] * (1 - 1e-6)
    tree = IrradianceTree(pos, power, area, nrm)
    got = tree.mo(params, np.full(len(q), a), q, 0.0)
    np.testing.assert_allclose(got, brute_mo(pos, power, params, a, q), rtol=1e-10)


def test_error_within_max_error():
    """Over points all around the sphere (lit and unlit sides), the relative error of M_o stays below max_error
    (measured 2e-3 at 0.05 and 1.5e-2 at 0.2) and falls with it."""
    pos, power, area, nrm = sphere_samples(n=20000, radius=5.0)
    params = dipole_params([0.02, 0.04, 0.07], [2.19, 2.62, 3.0], 0.0)
    a = boundary_a(1.5)
    q = pos[::50] * (1 - 1e-6)
    ref = brute_mo(pos, power, params, a, q)
    tree = IrradianceTree(pos, power, area, nrm)
    errors = []
    for max_error in (0.01, 0.05, 0.2):
        got = tree.mo(params, np.full(len(q), a), q, max_error)
        lit = ref > 1e-6 * ref.max()
        rel = np.abs(got[lit] / ref[lit] - 1).max()
        assert rel < max_error, (max_error, rel)
        errors.append(rel)
    assert errors[0] < errors[1] < errors[2]


def test_a_node_holding_the_point_is_opened():
    """With any error allowed, the root stands for all samples seen from outside its box, never from inside it."""
    pos, power, area, nrm = sphere_samples(n=2000)
    params = dipole_params([0.05] * 3, [5.0] * 3, 0.0)
    a = boundary_a(1.3)
    tree = IrradianceTree(pos, power, area, nrm)
    centroid = (pos * power.sum(1)[:, None]).sum(0) / power.sum()
    outside = np.array([[0.0, 0.0, 3.0]])
    root = brute_mo(centroid[None], power.sum(0, keepdims=True), params, a, outside)
    np.testing.assert_allclose(tree.mo(params, np.full(1, a), outside, 1e30), root, rtol=1e-12)
    inside = pos[:1] * (1 - 1e-6)
    got = tree.mo(params, np.full(1, a), inside, 1e30)
    exact = brute_mo(pos, power, params, a, inside)
    as_root = brute_mo(centroid[None], power.sum(0, keepdims=True), params, a, inside)
    # the samples close to the point are summed one by one: near the exact value, far from the root's
    # (measured: 5 % off the exact sum, where the root alone would be 79 % off)
    assert np.all(np.abs(got / exact - 1) < 0.1) and np.all(np.abs(as_root / exact - 1) > 0.5)


def test_empty_tree():
    tree = IrradianceTree(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
    assert np.all(tree.mo(dipole_params([0.1] * 3, [1.0] * 3, 0.0), np.ones(2), np.zeros((2, 3)), 0.05) == 0)


def test_uniform_plane_gives_total_reflectance():
    """Equal power on a fine grid over a plane 60 diffusion lengths wide: M_o at its centre is R_d,total times the
    irradiance, and the diffusion radiance (DiffusionTerm: exit normalisation over pi) R_d,total E / (pi (1 -
    F_dr,out)): a Lambertian exitance of R_d,total E spread by F_t."""
    from types import SimpleNamespace

    from pbvol_cli.dipole.hierarchy import DiffusionTerm
    from pbvol_cli.dipole.irradiance import IrradianceSamples
    from pbvol_cli.dipole.profile import diffuse_fresnel, total_diffuse_reflectance

    sigma_a, sigma_s = np.array([0.01, 0.02, 0.05]), np.array([1.0, 1.2, 1.5])
    h = 0.1  # a tenth of a mean free path apart
    g = np.arange(-200, 201) * h
    X, Z = np.meshgrid(g, g)
    pos = np.stack([X.ravel(), np.zeros(X.size), Z.ravel()], 1)
    E = 2.0
    samples = IrradianceSamples(pos, np.tile([0.0, 1.0, 0.0], (len(pos), 1)), np.full((len(pos), 3), E * h * h),
                                np.full(len(pos), h * h), np.zeros(len(pos), np.int64))
    material = SimpleNamespace(g=0.0)
    built = SimpleNamespace(medium_info=[SimpleNamespace(material=material)],
                            medium_sigmas=lambda m: (sigma_a, sigma_s))
    term = DiffusionTerm(built, samples, 0.05)
    q = np.array([[0.03, -1e-4, 0.07]])
    got = term.radiance(0, q, np.array([1.3]))
    expected = total_diffuse_reflectance(dipole_params(sigma_a, sigma_s, 0.0), boundary_a(1.3)) * E / (
        np.pi * (1 - diffuse_fresnel(1.3)))
    np.testing.assert_allclose(got[0], expected, rtol=0.01)
