"""Batched closest-hit queries against the scene's triangles through Embree (embreex).

Analytic spheres and area lights are intersected inside the numba kernels (see
``pbvol_cli.geometry.intersect``); this module only answers for triangles. Embree takes float32 rays and has
no per-ray entry point from numba, so callers gather the rays that need a cast, call ``closest_hit`` once
per wavefront step, and hand the arrays back to their kernels.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np


class TriangleCaster:
    """Closest hits on a fixed set of triangles; splits large batches over threads (Embree releases the GIL)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, threads: int = 1):
        self.threads = max(1, int(threads))
        self._scene = None
        if len(faces):
            from embreex import mesh_construction, rtcore_scene

            self._scene = rtcore_scene.EmbreeScene()
            mesh_construction.TriangleMesh(
                self._scene, np.ascontiguousarray(vertices, np.float32), np.ascontiguousarray(faces, np.int32)
            )
            # Commit now: geometry added after the first query would be ignored silently.
            self._scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None

    @property
    def empty(self) -> bool:
        return self._scene is None

    def _run(self, o, d):
        r = self._scene.run(o, d, output=1)
        return r["tfar"], r["primID"], r["u"], r["v"], r["Ng"]

    def closest_hit(self, origins: np.ndarray, dirs: np.ndarray):
        """(t float64 [inf = miss], prim int32 [-1 = miss], u, v float32, Ng (n,3) float32 unnormalised).

        ``dirs`` must be unit vectors (t is in units of |dir|).
        """
        n = len(origins)
        if self._scene is None or n == 0:
            return (np.full(n, np.inf), np.full(n, -1, np.int32), np.zeros(n, np.float32),
                    np.zeros(n, np.float32), np.zeros((n, 3), np.float32))
        o = np.ascontiguousarray(origins, np.float32)
        d = np.ascontiguousarray(dirs, np.float32)
        if self._pool is None or n < 4096:
            t, prim, u, v, ng = self._run(o, d)
        else:
            cuts = np.linspace(0, n, self.threads + 1).astype(int)
            parts = list(self._pool.map(lambda ab: self._run(o[ab[0]:ab[1]], d[ab[0]:ab[1]]),
                                        zip(cuts[:-1], cuts[1:])))
            t, prim, u, v, ng = (np.concatenate([p[k] for p in parts]) for k in range(5))
        t = t.astype(np.float64)
        t[prim < 0] = np.inf
        return t, prim.astype(np.int32), u, v, ng

    def close(self):
        if self._pool is not None:
            self._pool.shutdown()
