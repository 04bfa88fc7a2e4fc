"""Pinhole camera: primary rays for a batch of (pixel, sample) pairs."""

import math

import numpy as np
from numba import njit, prange

from pbvol_cli.physics.sampling import rand, seed_state


@njit(parallel=True, cache=True)
def generate_camera_rays(cam, seed, first_path, n, pos, dirs, pixel, rng):
    """Fill the first n slots with the paths first_path .. first_path + n - 1.

    Path p is sample p // (W*H) of pixel p % (W*H); pixels run row by row from the top left.
    Its random stream depends only on (seed, pixel, sample).
    """
    W, H = int(cam[12]), int(cam[13])
    npix = W * H
    for k in prange(n):
        p = first_path + k
        pix = p % npix
        s = p // npix
        rng[k] = seed_state(seed, pix, s)
        px, py = pix % W, pix // W
        sx = 2.0 * (px + rand(rng, k)) / W - 1.0
        sy = 1.0 - 2.0 * (py + rand(rng, k)) / H
        dx = cam[3] + sx * cam[6] + sy * cam[9]
        dy = cam[4] + sx * cam[7] + sy * cam[10]
        dz = cam[5] + sx * cam[8] + sy * cam[11]
        inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
        pos[k, 0], pos[k, 1], pos[k, 2] = cam[0], cam[1], cam[2]
        dirs[k, 0], dirs[k, 1], dirs[k, 2] = dx * inv, dy * inv, dz * inv
        pixel[k] = pix
