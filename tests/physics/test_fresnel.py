"""Fresnel reflectance and Snell refraction against closed forms."""

import math

import numpy as np
import pytest

from pbvol_cli.physics.fresnel import fresnel_dielectric, reflect, refract


@pytest.mark.parametrize("eta", [1.33, 1.5, 1 / 1.5])
def test_normal_incidence(eta):
    F, cos_t = fresnel_dielectric(1.0, eta)
    assert F == pytest.approx(((eta - 1) / (eta + 1)) ** 2, rel=1e-12)
    assert cos_t == pytest.approx(1.0)


def test_grazing_incidence_reflects_everything():
    F, _ = fresnel_dielectric(1e-9, 1.5)
    assert F == pytest.approx(1.0, abs=1e-6)


def test_brewster_angle_zeroes_p_polarisation():
    eta = 1.5
    theta_b = math.atan(eta)
    F, cos_t = fresnel_dielectric(math.cos(theta_b), eta)
    # at Brewster's angle only the s component reflects: F = rs^2 / 2
    rs = (math.cos(theta_b) - eta * cos_t) / (math.cos(theta_b) + eta * cos_t)
    assert F == pytest.approx(0.5 * rs * rs, rel=1e-12)


def test_total_internal_reflection_beyond_critical_angle():
    eta = 1 / 1.5  # glass -> air
    crit = math.asin(eta)
    assert fresnel_dielectric(math.cos(crit + 0.01), eta)[0] == 1.0
    F_below, _ = fresnel_dielectric(math.cos(crit - 0.01), eta)
    assert F_below < 1.0


def test_energy_symmetry_of_reciprocal_interfaces():
    # F(theta_i, eta) == F(theta_t, 1/eta): the same interface seen from both sides
    for th in np.linspace(0.0, 1.4, 15):
        F, cos_t = fresnel_dielectric(math.cos(th), 1.5)
        F2, _ = fresnel_dielectric(cos_t, 1 / 1.5)
        assert F == pytest.approx(F2, rel=1e-10)


@pytest.mark.parametrize("theta", [0.0, 0.3, 0.8, 1.2])
def test_refraction_obeys_snell(theta):
    eta = 1.5
    n = np.array([0.0, 0.0, 1.0])  # incident side
    d = np.array([math.sin(theta), 0.0, -math.cos(theta)])
    F, cos_t = fresnel_dielectric(math.cos(theta), eta)
    w = np.array(refract(*d, *n, eta, math.cos(theta), cos_t))
    assert np.linalg.norm(w) == pytest.approx(1.0)
    sin_t = math.hypot(w[0], w[1])
    assert math.sin(theta) == pytest.approx(eta * sin_t, rel=1e-12, abs=1e-15)
    assert w[2] < 0  # continues through the surface
    r = np.array(reflect(*d, *n))
    assert r == pytest.approx([d[0], d[1], -d[2]])
