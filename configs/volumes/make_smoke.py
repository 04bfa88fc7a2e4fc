#!/usr/bin/env python3
"""Writes smoke.npz beside this script: a rising, curling plume of smoke on a 32^3 grid (x, y, z order; y up), a
procedural stand-in for a simulated volume, with a `heat` array for emissive use. Deterministic:

    .venv/bin/python configs/volumes/make_smoke.py
"""

from pathlib import Path

import numpy as np


def plume(n: int = 32) -> tuple[np.ndarray, np.ndarray]:
    c = (np.arange(n) + 0.5) / n
    x, y, z = np.meshgrid(c, c, c, indexing="ij")
    rng = np.random.default_rng(7)
    density = np.zeros((n, n, n))
    for k in range(40):  # puffs along a curling column, wider and thinner as they rise
        t = k / 39
        cx = 0.5 + 0.18 * np.sin(5.0 * t + 0.5) * t
        cz = 0.5 + 0.18 * np.cos(4.0 * t) * t
        cy = 0.08 + 0.84 * t
        r = 0.05 + 0.12 * t + 0.02 * rng.random()
        density += (1.2 - 0.8 * t) * np.exp(-((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2) / (2 * r * r))
    density *= 1.0 / density.max()
    heat = np.clip(1.0 - 2.5 * y, 0.0, None) * density  # hot at the bottom
    return density.astype(np.float32), heat.astype(np.float32)


if __name__ == "__main__":
    d, h = plume()
    out = Path(__file__).resolve().parent / "smoke.npz"
    np.savez_compressed(out, density=d, heat=h)
    print(f"wrote {out}: density {d.shape}, max {d.max():.3f}, mean {d.mean():.4f}")
