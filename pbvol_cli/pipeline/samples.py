"""The place-samples stage: light surface and volume samples of a scene, cached by what determines them."""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pbvol_cli import config as C
from pbvol_cli.errors import PbvolError
from pbvol_cli.kernel_cache import package_stamp
from pbvol_cli.pipeline.cache import cached_entry, key_of

# 2: indirect diffuse light at the surface samples; 3: boundary planes; 4: glass walls reflect; 5-7: roulette on
# weak reflections, planes beyond the boundary; 8: a light is not its own shadow blocker; 9: light guided by
# reflections inside transparent layers; 11: indirect light
# path traced (v_returned: light that scattered before it reached the sample); 12: volume samples in Morton order;
# 13: each segment's leg (v_leg); 14: v_leg in 32 bits; 15: a beam's first sample starts on the boundary, its
# power the one that crossed it
FORMAT_VERSION = 15


@dataclass
class SamplesResult:
    samples: object  # LightSamples
    path: Path
    reused: bool
    seconds: float
    count: int = 0  # the surface samples asked for (the dipole's later passes place as many)


def geometry_hash(built) -> str:
    """Hash of what light samples depend on: geometry, surfaces, media, lights (not the camera or spp)."""
    h = hashlib.sha256()
    for arr in (built.vertices, built.faces, built.tri_surface, built.tri_normals, built.spheres, built.surfaces,
                built.media, built.lights):
        h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()[:20]


# peak bytes per volume sample while a set is placed (its arrays, the beams, the octree; measured: oil sphere at
# 16k and 64k surface samples, 1.05M and 4.23M volume samples, peaks 562 and 1607 MiB)
BYTES_PER_VOLUME_SAMPLE = 350


def samples_memory(pbl: C.PblSettings) -> int:
    """An upper bound (bytes) on the memory placing the light samples takes: every surface sample's beam followed
    through every internal reflection (roulette and refraction out usually end half of them sooner)."""
    volume = pbl.surface_samples * pbl.segments_per_beam * (1 + pbl.max_internal_reflections)
    return BYTES_PER_VOLUME_SAMPLE * volume


def check_samples_memory(pbl: C.PblSettings, scene_path, available: int | None = None):
    """Refuse, before placing them, light samples that would not fit in the available memory (naming the scene
    file and its setting)."""
    from pbvol_cli.pipeline.progress import available_memory

    need = samples_memory(pbl)
    available = available_memory() if available is None else available
    if available is not None and need > available:
        raise PbvolError(f"{scene_path}: render.pbl.surface_samples = {pbl.surface_samples}: the light samples may "
                         f"need up to "
                         f"about {need / 2**30:.1f} GiB, {available / 2**30:.1f} GiB is available; lower "
                         f"surface_samples or segments_per_beam")


# light samples are stored uncompressed: zip shrank an oil-sphere entry of 181 MB of arrays only to 122 MB, and
# undoing it took 1.6 s of a 1.9-s read (0.5 s uncompressed), as long as a render's pass (docs/pbl.md, section 12)
SAMPLES_COMPRESSED = False


def samples_path(cache: Path, built, pbl: C.PblSettings, seed: int) -> Path:
    key = key_of(kind="light-samples", geometry=geometry_hash(built), surface_samples=pbl.surface_samples,
                 segments=pbl.segments_per_beam, reflections=pbl.max_internal_reflections, layers=pbl.max_layers,
                 seed=seed, version=FORMAT_VERSION)
    return Path(cache) / "samples" / f"light_samples_{key}.npz"


def get_light_samples(built, pbl: C.PblSettings, seed: int, cache: Path, threads: int, force: bool = False,
                      progress=None):
    from pbvol_cli.pointbased.light_samples import LightSamples, place_light_samples

    t0 = time.perf_counter()
    path = samples_path(cache, built, pbl, seed)

    def place():
        try:
            return place_light_samples(built, pbl.surface_samples, pbl.segments_per_beam,
                                       pbl.max_internal_reflections, pbl.max_layers, seed, threads, progress,
                                       in_space_order=True)
        except ValueError as e:
            raise PbvolError(f"place-samples: {e}") from None

    samples, reused = cached_entry(path, LightSamples.FIELDS, LightSamples.from_arrays, place, force,
                                   compress=SAMPLES_COMPRESSED)
    return SamplesResult(samples, path, reused, time.perf_counter() - t0)


# 1: the boundary's reflections of pass 0's scattered light (pointbased/passes._reflected); bump when the entry's
# arrays change (the entries are keyed by the package's sources as well)
BOUNCED_FORMAT_VERSION = 1


class BouncedEntry:
    """A medium's reflected bounced samples (a namespace of volume_samples.SAMPLE_KEYS arrays, or None: the
    boundary reflects nothing) as a cache entry."""

    def __init__(self, samples):
        self.samples = samples

    def arrays(self) -> dict:
        from pbvol_cli.pointbased.volume_samples import SAMPLE_KEYS

        if self.samples is None:
            return {"absent": np.array(1)}
        return {"absent": np.array(0), **{k: getattr(self.samples, k) for k in SAMPLE_KEYS}}

    @classmethod
    def from_arrays(cls, d: dict) -> "BouncedEntry":
        from types import SimpleNamespace

        from pbvol_cli.pointbased.volume_samples import SAMPLE_KEYS

        if int(d["absent"]):
            return cls(None)
        ns = SimpleNamespace(**{k: d[k] for k in SAMPLE_KEYS})
        if len({len(getattr(ns, k)) for k in SAMPLE_KEYS}) != 1 or ns.v_start.shape[1:] != (3,):
            raise ValueError("inconsistent bounced samples")
        return cls(ns)


def bounced_cache(cache: Path, samples: Path, pbl: C.PblSettings, table_names: dict):
    """first_bounced for pointbased/passes.render_passes: pass 0's reflected bounced samples of medium m from the
    cache, or built and stored. Keyed by the light samples' entry (geometry, lights, media, seed), the settings
    the reflections depend on, the medium's tables (table_names[m]: their entries' file names) and the package's
    sources: the reflections go through every estimator, and a change to any of them (images, kernels, the gather's
    points) left the first pass rendering a stale set while the later passes' sets were new. A set costs well under
    a pass to build again."""
    def first_bounced(m: int, build):
        key = key_of(kind="bounced-samples", samples=samples.name, medium=m, tables=table_names.get(m),
                     bounce_samples=pbl.bounce_samples, generations=pbl.bounce_generations,
                     near_sources=pbl.bounce_near_sources,
                     segments=pbl.segments_per_beam, reflections=pbl.max_internal_reflections,
                     cut_size=pbl.cut_size, clamp=pbl.clamp, beam_width=pbl.beam_width,
                     version=BOUNCED_FORMAT_VERSION, sources=package_stamp())
        entry, _ = cached_entry(Path(cache) / "samples" / f"bounced_{key}.npz", ("absent",), BouncedEntry.from_arrays,
                                lambda: BouncedEntry(build()))
        return entry.samples

    return first_bounced


# 1: per surface sample and medium, where its light entered (dipole/irradiance.py); bump when they change
IRRADIANCE_FORMAT_VERSION = 1


def get_irradiance_samples(built, scene: C.Scene, seed: int, cache: Path, threads: int, force: bool = False,
                           progress=None, note=None):
    """The dipole's irradiance samples (dipole/irradiance.py) from the cache, or placed and stored. Their count
    follows [render.dipole] spacing (at most max_samples: note(text) says so when that widens the spacing)."""
    from pbvol_cli.dipole.irradiance import IrradianceSamples, place_irradiance_samples, sample_count

    t0 = time.perf_counter()
    dip, pbl = scene.render.dipole, scene.render.pbl
    count, wanted = sample_count(built, dip.spacing, dip.min_samples, dip.max_samples)
    if count < wanted and note is not None:
        note(f"render.dipole.spacing = {dip.spacing:g} asks for {wanted} irradiance samples; placing "
             f"render.dipole.max_samples = {dip.max_samples} (spacing {dip.spacing * (wanted / count) ** 0.5:.3g} "
             f"mean free paths)")
    key = key_of(kind="irradiance-samples", geometry=geometry_hash(built), count=count,
                 reflections=pbl.max_internal_reflections, layers=pbl.max_layers, seed=seed,
                 version=IRRADIANCE_FORMAT_VERSION)
    path = Path(cache) / "samples" / f"irradiance_{key}.npz"

    def place():
        try:
            return place_irradiance_samples(built, count, pbl.max_internal_reflections, pbl.max_layers, seed,
                                            threads, progress)
        except ValueError as e:
            raise PbvolError(f"place-samples: {e}") from None

    samples, reused = cached_entry(path, IrradianceSamples.FIELDS, IrradianceSamples.from_arrays, place, force)
    return SamplesResult(samples, path, reused, time.perf_counter() - t0, count)
