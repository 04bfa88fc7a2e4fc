"""Sampling helpers: the stratified depths along a camera segment."""

import math

import numpy as np

from pbvol_cli.physics.sampling import stratified_depth


def test_stratified_depths_follow_the_truncated_exponential():
    """n stratified points of one segment: depths within it, each pdf the truncated exponential's density there,
    and the mean of 1 / pdf over the strata (one random offset) the segment's length, as an integral of 1 wants."""
    s, dmax = 1.3, 2.0
    frac = -math.expm1(-s * dmax)
    for xi in (0.0, 0.37, 0.999):
        d, pdf = zip(*(stratified_depth(k, 8, xi, s, dmax, frac) for k in range(8)))
        d, pdf = np.array(d), np.array(pdf)
        assert np.all((d >= 0) & (d <= dmax)) and np.all(np.diff(d) > 0)
        np.testing.assert_allclose(pdf, s * np.exp(-s * d) / frac, rtol=1e-12)
    d, pdf = zip(*(stratified_depth(k, 4000, 0.5, s, dmax, frac) for k in range(4000)))
    assert abs(np.mean(1.0 / np.array(pdf)) - dmax) < 1e-3 * dmax


def test_a_segment_of_no_length_weighs_nothing():
    """A camera ray that meets a surface where it starts (t = 0 from Embree) has a segment of no length: its points
    lie at its start with an infinite pdf (weight zero), in a medium that extinguishes and in one that does not
    (the render stopped on a division by zero there)."""
    for s, frac in ((1.5, -math.expm1(-1.5 * 0.0)), (0.0, 1.0)):
        for k in range(3):
            d, pdf = stratified_depth(k, 3, 0.7, s, 0.0, frac)
            assert d == 0.0 and pdf == np.inf
