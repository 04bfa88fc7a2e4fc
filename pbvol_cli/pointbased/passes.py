"""The point-based method's passes: each pass's light-sample set and bounced light, then the camera paths.

Pass 0 uses the cached light samples (pipeline/samples.py); every later pass draws a fresh set (seed + pass, not
cached; `light_sets` bounds them), so that the light side's sampling noise (single beams visible as streaks)
averages out over passes like the camera side's. The bounced light (bounced.py) is built from the light samples of
every `bounced_passes`-th pass (seed + that pass) and serves the passes up to the next.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from types import SimpleNamespace

import numpy as np

from pbvol_cli.geometry.raycast import TriangleCaster
from pbvol_cli.geometry.scene_build import BuiltScene
from pbvol_cli.multiple_scattering.table import empty_table
from pbvol_cli.pointbased.bounced import BOUNCED_KERNEL, bounced_samples
from pbvol_cli.pointbased.camera_pass import render_pbl
from pbvol_cli.pointbased.flat_faces import medium_faces
from pbvol_cli.pointbased.image_planes import medium_extrapolation
from pbvol_cli.pointbased.gather import GatherSettings
from pbvol_cli.pointbased.light_samples import place_light_samples
from pbvol_cli.pointbased.volume_samples import SAMPLE_KEYS, SampleSet, returned_samples

TABLE_COMPONENTS = ("multiple", "bounced")  # the components that look the multiple-scattering table up


def kernel_tables(tables: list) -> tuple:
    """A medium's tables (MSTable or None per RGB channel) expanded for the kernels (MSTable.render_args), once for
    every pass: a channel without a table takes another channel's (its extinction is 0: nothing looks it up) or
    an empty one."""
    filler = next((t for t in tables if t is not None), None) or empty_table()
    return tuple((t or filler).render_args() for t in tables)


def render_passes(built: BuiltScene, samples, tables: dict, pbl, seed: int, spp: int, threads: int, progress=None,
                  time_limit: float | None = None, first_bounced=None, entry=None, first_pass: int = 0):
    """Renders spp passes of the point-based method (no pass starts after time_limit seconds). samples: the cached
    LightSamples of pass 0 (None: no medium); tables: {medium: [MSTable or None] x 3}; pbl: config.PblSettings
    (its components included); first_bounced(m, build): pass 0's bounced samples of medium m, from a cache or
    build() (None: always built); entry: camera_pass.render_pbl's (the dipole's diffusion term); samples may come
    as a one-item list, which is emptied: they are then dropped after pass 0 when no later pass reuses them
    (light_sets 0), their memory freed unless the caller keeps another reference; first_pass: the
    first pass's index in the scene's sequence (render --samples; pass p's light samples are seeded by p).
    Returns (image, layers, stats, timings): render_pbl's, and the seconds spent on the later passes' light
    samples and on the bounced samples."""
    expanded = {m: kernel_tables(t) for m, t in tables.items()}
    timings = {"pass_samples_s": 0.0, "bounced_s": 0.0}
    if isinstance(samples, list):  # [LightSamples]: taken out, so that no caller's reference keeps them alive
        samples = samples.pop()
    has_medium = samples is not None

    def light_samples(p: int):
        """Pass p's LightSamples: the cached set, or one placed with seed + its set's index (light_sets)."""
        k = 0 if pbl.light_sets == 1 else (p % pbl.light_sets if pbl.light_sets > 1 else p)
        if k == 0:
            return samples
        t = time.perf_counter()
        placed = place_light_samples(built, pbl.surface_samples, pbl.segments_per_beam,
                                     pbl.max_internal_reflections, pbl.max_layers, seed + k, threads)
        timings["pass_samples_s"] += time.perf_counter() - t
        return placed

    faces = {m: medium_faces(built, m) for m in expanded}  # the flat faces of each medium's boundary
    image_k = {m: medium_extrapolation(built, m) for m in expanded}  # and its curved parts' image planes

    def lit_sets(current) -> dict:
        return {m: SampleSet(current, m, built.media, expanded[m], pbl.beam_width, faces[m], image_k[m])
                for m in expanded}

    held = {}  # "lit": the one light-sample set's SampleSets (light_sets 1); "bounced": (first pass, {m: set})

    def media_for_pass(p: int) -> dict:
        nonlocal samples
        if not has_medium:
            return {}
        if pbl.light_sets == 1:  # the same samples every pass: their octrees built once
            current = samples
            if "lit" not in held:
                held["lit"] = lit_sets(samples)
            lit = held["lit"]
        else:
            current = light_samples(p)
            lit = lit_sets(current)
        # the bounced samples of passes g0 .. g0 + bounced_passes - 1, built from pass g0's light samples: the
        # bounced light is smooth, its camera side's noise rules, and a set a pass cost a sky-lit pass a fifth of
        # its time (docs/pbl.md)
        g0 = p - p % pbl.bounced_passes
        if held.get("bounced", (None,))[0] != g0:
            held.pop("bounced", None)  # freed before the next is built
            if g0 == p or pbl.light_sets == 1:
                source, base = current, lit
            else:  # a render of later passes only (render --samples) starts inside a group
                source = light_samples(g0)
                base = lit_sets(source)
            t = time.perf_counter()
            cached = first_bounced if g0 == 0 else None  # (pass 0's set: the cached light samples, the seed)
            held["bounced"] = (g0, {m: _bounced_set(built, source, m, base[m], expanded[m], pbl, seed + g0, threads,
                                                    cached) for m in base})
            timings["bounced_s"] += time.perf_counter() - t
        if p == 0 and pbl.light_sets == 0:
            samples = None  # no later pass reads them: freed once this pass's sets are built (docs/pbl.md, memory)
        return {m: (lit[m], held["bounced"][1][m]) for m in lit}

    image, layers, stats = render_pbl(built, media_for_pass, spp, seed, pbl, threads, progress,
                                      time_limit=time_limit, entry=entry, first_pass=first_pass)
    return image, layers, stats, timings


def _bounced_set(built, samples, m: int, lit: SampleSet, tables: tuple, pbl, seed: int, threads: int,
                 cached=None):
    """The bounced samples of medium m as a SampleSet, or None: scattered light that its boundary reflects back
    (bounced.py; through cached(m, build) when given) and scattered light that left it and the scene sends back in
    (the light samples' v_returned part, light_samples._indirect)."""
    if "bounced" not in pbl.components:
        return None
    # (their cross-sections scaled so that the bounced samples' kernel keeps the lights' beams' width)
    back = returned_samples(samples, m, (pbl.beam_width / BOUNCED_KERNEL) ** 2)
    b = None
    if pbl.bounce_generations > 0 and lit.count > 0:
        b = cached(m, lambda: _reflected(built, m, lit, back, tables, pbl, seed, threads)) if cached else \
            _reflected(built, m, lit, back, tables, pbl, seed, threads)
    if b is not None:
        back = SimpleNamespace(**{k: np.concatenate([getattr(b, k), getattr(back, k)]) for k in SAMPLE_KEYS})
    if len(back.v_len) == 0:
        return None
    return SampleSet(back, m, built.media, tables, BOUNCED_KERNEL, lit.medium.faces, lit.medium.image_k)


def _reflected(built, m: int, lit: SampleSet, back, tables: tuple, pbl, seed: int, threads: int):
    """The scattered light of medium m that its boundary reflects back, generation after generation (bounced.py),
    as a namespace of v_* arrays, or None."""
    # the returned light's own reflections on the boundary too
    extra = (SampleSet(back, m, built.media, tables, BOUNCED_KERNEL, lit.medium.faces, lit.medium.image_k)
             if len(back.v_len) else None)
    # the light arriving at the boundary points: one point per gather ray for each estimator (the reflected
    # light is smooth; the boundary points average it)
    gather = GatherSettings(1, pbl.cut_size, pbl.clamp, True, True, True, 1, 1, pbl.cut_size, float(pbl.cut_roulette))
    caster = TriangleCaster(built.vertices, built.faces, threads)
    pool = ThreadPoolExecutor(threads) if threads > 1 else None
    try:
        return bounced_samples(built, caster, pool, threads, m, lit,
                               lambda smp: SampleSet(smp, m, built.media, tables, pbl.beam_width,
                                                     lit.medium.faces, lit.medium.image_k),
                               pbl.bounce_samples, pbl.bounce_generations, max(1, pbl.segments_per_beam // 4),
                               pbl.max_internal_reflections, gather, seed, extra,
                               pbl.bounce_near_sources if pbl.bounce_near_sources > 0 and built.medium_is_convex(m)
                               else 0.0)
    finally:
        caster.close()
        if pool is not None:
            pool.shutdown()
