"""Pinhole camera: primary rays for a batch of (pixel, sample) pairs."""

import math

import numpy as np
from numba import njit, prange

from pbvol_cli.geometry.scene_build import CAM_FORWARD, CAM_HEIGHT, CAM_POS, CAM_RIGHT, CAM_UP, CAM_WIDTH
from pbvol_cli.physics.sampling import seed_state

PIXEL_SHIFT_INDEX = 1 << 62  # the random stream of a pixel's scramble: beyond any sample index
_TWO_POW_M32 = 1.0 / 4294967296.0


@njit(inline="always", cache=True)
def _sobol_pair(i):
    """Point i of the first two dimensions of Sobol's sequence as 32-bit integers: van der Corput's radical inverse in
    base 2 and the second dimension (direction numbers of x + 1). Every run of 2^m points from a multiple of 2^m
    puts one point in each elementary interval of area 2^-m: a (0, 2)-sequence."""
    x, y = np.uint64(0), np.uint64(0)
    vx, vy = np.uint64(1 << 31), np.uint64(1 << 31)
    i = np.uint64(i)
    while i:
        if i & np.uint64(1):
            x ^= vx
            y ^= vy
        i >>= np.uint64(1)
        vx >>= np.uint64(1)
        vy ^= vy >> np.uint64(1)
    return x, y


@njit(inline="always", cache=True)
def pixel_position(seed, pix, s):
    """Where in pixel pix sample s looks, in [0, 1)^2: point s of the two-dimensional Sobol sequence, its bits
    XOR-scrambled by a random 64-bit value of the pixel (a random digital shift). Each sample is uniform over the
    pixel (on a 2^-32 grid), so every estimate stays unbiased, and a pixel's samples are stratified at any count and
    across passes: a light's mirror image covering part of a pixel converges about as 1 / N instead of
    1 / sqrt(N) under independent jitter."""
    shift = seed_state(seed, pix, PIXEL_SHIFT_INDEX)
    x, y = _sobol_pair(s)
    x ^= shift & np.uint64(0xFFFFFFFF)
    y ^= shift >> np.uint64(32)
    return x * _TWO_POW_M32, y * _TWO_POW_M32


@njit(inline="always", cache=True)
def _camera_ray(cam, seed, pix, s, k, pos, dirs, rng):
    """Sample s of pixel pix into slot k: its position in the pixel (pixel_position), its random stream seeded from
    (seed, pixel, sample) alone."""
    W, H = int(cam[CAM_WIDTH]), int(cam[CAM_HEIGHT])
    rng[k] = seed_state(seed, pix, s)
    px, py = pix % W, pix // W
    u, v = pixel_position(seed, pix, s)
    sx = 2.0 * (px + u) / W - 1.0
    sy = 1.0 - 2.0 * (py + v) / H
    dx = cam[CAM_FORWARD] + sx * cam[CAM_RIGHT] + sy * cam[CAM_UP]
    dy = cam[CAM_FORWARD + 1] + sx * cam[CAM_RIGHT + 1] + sy * cam[CAM_UP + 1]
    dz = cam[CAM_FORWARD + 2] + sx * cam[CAM_RIGHT + 2] + sy * cam[CAM_UP + 2]
    inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
    pos[k, 0], pos[k, 1], pos[k, 2] = cam[CAM_POS], cam[CAM_POS + 1], cam[CAM_POS + 2]
    dirs[k, 0], dirs[k, 1], dirs[k, 2] = dx * inv, dy * inv, dz * inv


@njit(parallel=True, cache=True)
def generate_camera_rays(cam, seed, first_path, n, pos, dirs, pixel, rng):
    """Fill the first n slots with the paths first_path .. first_path + n - 1.

    Path p is sample p // (W*H) of pixel p % (W*H); pixels run row by row from the top left.
    Its random stream depends only on (seed, pixel, sample).
    """
    npix = int(cam[CAM_WIDTH]) * int(cam[CAM_HEIGHT])
    for k in prange(n):
        p = first_path + k
        pix = p % npix
        _camera_ray(cam, seed, pix, p // npix, k, pos, dirs, rng)
        pixel[k] = pix


@njit(parallel=True, cache=True)
def camera_rays_for(cam, seed, pixels, samples, pos, dirs, rng):
    """Slot k: sample samples[k] of pixel pixels[k] (the same ray as generate_camera_rays gives that pair)."""
    for k in prange(pixels.shape[0]):
        _camera_ray(cam, seed, pixels[k], samples[k], k, pos, dirs, rng)
