"""Beams: crossing transparent layers, thinning."""

import math

import numpy as np
import pytest

from pbvol_cli.geometry.scene_build import (DIELECTRIC, SURF_COLS, SURF_ETA_IN, SURF_ETA_OUT, SURF_MEDIUM_IN,
                                           SURF_MEDIUM_OUT, SURF_TYPE)
from pbvol_cli.physics.fresnel import fresnel_dielectric
from pbvol_cli.pointbased.beams import cross_interface, thin_by_power


@pytest.mark.parametrize("angle", [20.0, 60.0])
def test_beams_inside_a_glass_wall_reflect_by_fresnel_choice(angle):
    """cross_interface inside a transparent layer (u >= 0): a beam leaving glass (eta 1.5) for air is reflected with
    probability F, its power unchanged (beyond the critical angle, 41.8 deg, always: light guided down a glass
    wall); transmitted otherwise, power unchanged; the first crossing (u < 0) transmits with power x (1 - F)."""
    surfaces = np.zeros((1, SURF_COLS))
    surfaces[0, [SURF_TYPE, SURF_MEDIUM_IN, SURF_MEDIUM_OUT, SURF_ETA_IN, SURF_ETA_OUT]] = [DIELECTRIC, -1, -1, 1.5, 1.0]
    a = math.radians(angle)
    F = fresnel_dielectric(math.cos(a), 1.0 / 1.5)[0]
    for u, reflected in ((-1.0, False), (0.5 * F, True), (0.999 if F >= 1.0 else 0.5 * (1 + F), F >= 1.0)):
        pos = np.zeros((1, 3))
        d = np.array([[math.sin(a), 0.0, math.cos(a)]])  # toward the surface z = 1 from inside (normal +z)
        power = np.ones((1, 3))
        medium, cosx, alive, bn = np.full(1, -1), np.zeros(1), np.ones(1, np.bool_), np.zeros((1, 3))
        ng = np.array([[0.0, 0.0, 1.0]])
        t = np.array([1.0 / math.cos(a)])
        cross_interface(surfaces, pos, d, power, medium, cosx, ng, ng.copy(), t, np.zeros(1, np.int64), 1e-6, alive, bn,
               np.array([u]))
        if u < 0 and F >= 1.0:
            assert not alive[0]  # the first crossing never reflects inward
            continue
        assert alive[0]
        if reflected:
            assert d[0, 2] == pytest.approx(-math.cos(a)) and pos[0, 2] < 1.0
            assert power[0, 0] == 1.0
        else:
            assert d[0, 2] > 0 and pos[0, 2] > 1.0
            assert power[0, 0] == pytest.approx(1.0 - F if u < 0 else 1.0)


def test_thinning_by_power_keeps_the_total_in_expectation_and_about_the_target_count():
    """thin_by_power: over many draws the kept powers sum to the total per channel (unbiased); about `target`
    beams are kept; the strong beams are always kept with their own power."""
    rng = np.random.default_rng(5)
    power = rng.pareto(1.5, (20000, 3)) * np.array([1.0, 0.5, 2.0])
    power[:5] *= 1e4  # a few strong beams
    sums, counts = [], []
    for k in range(400):
        keep, p = thin_by_power(power, 1000, np.random.default_rng(k))
        sums.append(p.sum(axis=0))
        counts.append(len(keep))
        assert set(range(5)) <= set(keep.tolist()) and np.allclose(p[:5], power[:5])
    sums = np.array(sums)
    se = sums.std(axis=0) / np.sqrt(len(sums))
    assert np.all(np.abs(sums.mean(axis=0) - power.sum(axis=0)) < 4 * se), (sums.mean(axis=0), power.sum(axis=0))
    assert abs(np.mean(counts) - 1000) < 10
    keep, p = thin_by_power(power[:10], 1000, rng)
    assert len(keep) == 10 and np.array_equal(p, power[:10])  # fewer than the target: all kept as they are
