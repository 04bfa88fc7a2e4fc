"""Irradiance samples for the dipole (Jensen & Buhler 2002, sec. 3; seed 003, "Sample points"): blue-noise points on
the translucent shapes, the light each one lets into the medium, and the area it stands for.

They are the point-based method's light surface samples (pointbased/light_samples.entering_light): Poisson-disk
points on the outer layer of every medium-holding shape, lit by every light with visibility and by path-traced
indirect light, their light refracted in through Fresnel and any transparent layer in front of the medium. A sample
keeps, per medium, the power that entered (W: the irradiance times the area times the Fresnel transmittance of each
direction, the integral the slides approximate by F_dt E) and where it entered: on a bare shape the sample's own
point; behind a glass wall the power-weighted mean of where its refracted beams met the medium.

Their spacing follows the medium (Jensen & Buhler: closer than a mean free path): `spacing` reduced mean free paths
of the densest channel, as many samples as that takes on the outer layers' area, at least `min_samples` (a small
object) and at most `max_samples`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pbvol_cli.geometry.raycast import TriangleCaster
from pbvol_cli.geometry.scene_build import SPH_RADIUS, SPH_SURFACE, BuiltScene

# dart throwing saturates with disks of diameter `spacing` covering about 0.547 of the area
# (surface_samples.poisson_disk): n = 0.547 area / (pi spacing^2 / 4)
PACKING = 0.547


@dataclass
class IrradianceSamples:
    pos: np.ndarray  # (n, 3) where the light entered the medium
    normal: np.ndarray  # (n, 3) the boundary's normal there, out of the medium
    power: np.ndarray  # (n, 3) W that entered, RGB
    area: np.ndarray  # (n,) surface each sample stands for (scene units^2)
    medium: np.ndarray  # (n,) medium ids

    FIELDS = ("pos", "normal", "power", "area", "medium")

    def arrays(self) -> dict:
        return {k: getattr(self, k) for k in self.FIELDS}

    @classmethod
    def from_arrays(cls, d: dict) -> "IrradianceSamples":
        s = cls(**{k: d[k] for k in cls.FIELDS})
        n = len(s.pos)
        if not (s.pos.shape == (n, 3) and s.normal.shape == (n, 3) and s.power.shape == (n, 3) and len(s.area) == n
                and len(s.medium) == n) or not all(np.all(np.isfinite(a)) for a in (s.pos, s.power, s.area)):
            raise ValueError("inconsistent irradiance samples")
        return s


def outer_layer_area(bs: BuiltScene) -> float:
    """The area of the outer layers the samples are placed on (scene units^2)."""
    from pbvol_cli.pointbased.light_samples import outer_layer_surfaces

    outer = outer_layer_surfaces(bs)
    tri = np.isin(bs.tri_surface, outer)
    V, F = bs.vertices, bs.faces[tri].reshape(-1, 3)
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()
    sph = bs.spheres[np.isin(bs.spheres[:, SPH_SURFACE].astype(np.int64), outer)]
    return float(area + (4 * np.pi * sph[:, SPH_RADIUS] ** 2).sum())


def shortest_mean_free_path(bs: BuiltScene) -> float:
    """1 / sigma'_t of the densest channel of any medium (scene units), inf without scattering media."""
    best = 0.0
    for m, info in enumerate(bs.medium_info):
        sig_a, sig_s = bs.medium_sigmas(m)
        best = max(best, float(np.max(sig_a + (1.0 - info.material.g) * sig_s)))
    return 1.0 / best if best > 0 else math.inf


def sample_count(bs: BuiltScene, spacing_mfp: float, min_samples: int, max_samples: int) -> tuple[int, int]:
    """(samples to place, samples the spacing asks for): `spacing_mfp` shortest reduced mean free paths apart on
    the outer layers, at least min_samples and at most max_samples."""
    spacing = spacing_mfp * shortest_mean_free_path(bs)
    wanted = min_samples
    if math.isfinite(spacing):
        wanted = max(int(min(math.ceil(PACKING * outer_layer_area(bs) / (math.pi * spacing ** 2 / 4.0)), 1e12)),
                     min_samples)
    return min(wanted, max_samples), wanted


def place_irradiance_samples(bs: BuiltScene, count: int, max_reflections: int, max_layers: int, seed: int,
                             threads: int = 2, progress=None) -> IrradianceSamples:
    """About `count` irradiance samples (see the module's docstring). progress(done, total) after each light and
    the indirect light."""
    from pbvol_cli.pointbased.light_samples import entering_light, step_counter

    steps = len(bs.lights) + 2
    advance = step_counter(progress, steps)
    caster = TriangleCaster(bs.vertices, bs.faces, threads)
    try:
        light = entering_light(caster, bs, count, max_reflections, max_layers, seed, advance)
    finally:
        caster.close()
    beams = [light.beams, light.returned]
    src = np.concatenate([light.beam_source, light.returned_source])
    med = np.concatenate([b.medium for b in beams])
    power = np.concatenate([b.power for b in beams])
    pos = np.concatenate([b.pos for b in beams])
    nrm = np.concatenate([b.normal for b in beams])
    # one irradiance sample per surface sample and medium its light reached
    keys, inv = np.unique(src * max(len(bs.medium_info), 1) + med, return_inverse=True)
    n = len(keys)
    w = power.sum(axis=1)
    wsum = np.bincount(inv, weights=w, minlength=n)
    total = np.stack([np.bincount(inv, weights=power[:, c], minlength=n) for c in range(3)], axis=1)
    where = np.stack([np.bincount(inv, weights=w * pos[:, c], minlength=n) for c in range(3)], axis=1)
    normal = np.stack([np.bincount(inv, weights=w * nrm[:, c], minlength=n) for c in range(3)], axis=1)
    lit = wsum > 0
    where, normal, total, wsum = where[lit], normal[lit], total[lit], wsum[lit]
    where /= wsum[:, None]
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    medium = (keys[lit] % max(len(bs.medium_info), 1)).astype(np.int64)
    if progress is not None:
        progress(steps, steps)
    return IrradianceSamples(where, normal, total, np.full(len(where), light.area), medium)
