"""Where in its pixel each camera sample looks (render/camera.pixel_position)."""

import numpy as np

from pbvol_cli.render.camera import pixel_position


def _points(seed, pix, first, n):
    return np.array([pixel_position(seed, pix, s) for s in range(first, first + n)])


def test_each_run_of_a_power_of_two_samples_is_stratified_in_both_axes():
    """Any 2^m samples from a multiple of 2^m (one pass's, or the next pass's) put one sample in each of the 2^m
    columns and rows of the pixel, and with 16 one in each cell of a 4 x 4 grid: a (0, 2)-sequence survives the
    per-pixel scramble."""
    for seed, pix in ((1, 0), (7, 12345)):
        for first, n in ((0, 8), (8, 8), (16, 16), (32, 32)):
            pts = _points(seed, pix, first, n)
            assert np.all((pts >= 0) & (pts < 1))
            for axis in (0, 1):
                assert np.array_equal(np.sort(np.floor(pts[:, axis] * n)), np.arange(n))
        cells = np.floor(_points(seed, pix, 16, 16) * 4).astype(int)
        assert len({(a, b) for a, b in cells}) == 16


def test_one_sample_is_uniform_over_the_pixel_across_pixels_and_seeds():
    """Sample s of a pixel, over many pixels (their scrambles independent), is uniform in [0, 1)^2: every estimate
    that averages a pixel's samples stays unbiased. Mean 1/2 and variance 1/12 per axis within 5 standard errors,
    the axes uncorrelated, and a 4 x 4 histogram flat by chi-square."""
    n = 40000
    for seed, s in ((1, 0), (2, 5), (3, 1000)):
        pts = np.array([pixel_position(seed, pix, s) for pix in range(n)])
        assert np.all(np.abs(pts.mean(0) - 0.5) < 5 * np.sqrt(1 / 12 / n))
        assert np.all(np.abs(pts.var(0) - 1 / 12) < 5 * np.sqrt(1 / 180 / n))
        assert abs(np.corrcoef(pts.T)[0, 1]) < 5 / np.sqrt(n)
        counts = np.histogram2d(pts[:, 0], pts[:, 1], bins=4, range=[[0, 1], [0, 1]])[0].ravel()
        chi2 = ((counts - n / 16) ** 2 / (n / 16)).sum()
        assert chi2 < 45  # 15 degrees of freedom: p < 1e-4


def test_pixels_and_seeds_get_their_own_scramble():
    assert not np.allclose(_points(1, 0, 0, 4), _points(1, 1, 0, 4))
    assert not np.allclose(_points(1, 0, 0, 4), _points(2, 0, 0, 4))
