"""Pinhole camera: primary rays for a batch of (pixel, sample) pairs."""

import math

from numba import njit, prange

from pbvol_cli.geometry.scene_build import CAM_FORWARD, CAM_HEIGHT, CAM_POS, CAM_RIGHT, CAM_UP, CAM_WIDTH
from pbvol_cli.physics.sampling import rand, seed_state


@njit(inline="always", cache=True)
def _camera_ray(cam, seed, pix, s, k, pos, dirs, rng):
    """Sample s of pixel pix into slot k: a jittered position in the pixel, its random stream seeded from
    (seed, pixel, sample) alone."""
    W, H = int(cam[CAM_WIDTH]), int(cam[CAM_HEIGHT])
    rng[k] = seed_state(seed, pix, s)
    px, py = pix % W, pix // W
    sx = 2.0 * (px + rand(rng, k)) / W - 1.0
    sy = 1.0 - 2.0 * (py + rand(rng, k)) / H
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
