"""Pinhole camera: primary rays for a batch of (pixel, sample) pairs."""

import math

from numba import njit, prange

from pbvol_cli.geometry.scene_build import CAM_FORWARD, CAM_HEIGHT, CAM_POS, CAM_RIGHT, CAM_UP, CAM_WIDTH
from pbvol_cli.physics.sampling import rand, seed_state


@njit(parallel=True, cache=True)
def generate_camera_rays(cam, seed, first_path, n, pos, dirs, pixel, rng):
    """Fill the first n slots with the paths first_path .. first_path + n - 1.

    Path p is sample p // (W*H) of pixel p % (W*H); pixels run row by row from the top left.
    Its random stream depends only on (seed, pixel, sample).
    """
    W, H = int(cam[CAM_WIDTH]), int(cam[CAM_HEIGHT])
    npix = W * H
    for k in prange(n):
        p = first_path + k
        pix = p % npix
        s = p // npix
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
        pixel[k] = pix
