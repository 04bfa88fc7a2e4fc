"""The render stage: scene file -> image file, for every method, with progress, metadata and a summary."""

from __future__ import annotations

import hashlib
import os
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pbvol_cli import __version__
from pbvol_cli import config as C
from pbvol_cli.errors import PbvolError, RenderFailed
from pbvol_cli.physics.lights import LIGHT_RGB
from pbvol_cli.pipeline.progress import CompileMonitor, available_memory, peak_memory_mb, progress_bar, set_threads

METHODS = ("volpath", "pbl", "dipole", "raymarch", "vpl")
VOLPATH_SUMS = "image"  # the one sum of a volpath render (it has no layers)
RAYMARCH_LAYERS = ("volume", "surface")  # the ray marcher's: emission and single scattering, the camera paths' rest
VPL_LAYERS = ("volume", "vpl", "surface")  # and the VPLs' light
DIPOLE_LAYERS = ("single", "diffusion", "surface")  # the dipole's image: pbl's single scattering, the diffusion
# term where camera paths enter a medium, and the camera paths' surfaces


@dataclass
class RenderOptions:
    method: str = "volpath"
    spp: int | None = None
    seed: int | None = None
    threads: int | None = None
    time_limit: float | None = None
    resolution: tuple[int, int] | None = None
    orders: str | None = None
    max_depth: int | None = None
    components: str | None = None
    cache_dir: Path | None = None
    quiet: bool = False
    timings: bool = True  # False: no times, peaks or cache reuse in the file, a fixed date: byte-identical reruns
    samples: tuple[int, int] | None = None  # (A, B): samples (passes) A .. B-1 of the scene's sequence (merge)
    shards: int | None = None  # with dask: pieces of the samples (None: one per worker thread)


def scene_hash(scene: C.Scene, built) -> str:
    """Hash of everything the image depends on in the scene (config and resolved media)."""
    h = hashlib.sha256(scene.model_dump_json().encode())
    for arr in (built.surfaces, built.media, built.lights, built.spheres, built.vertices, built.faces):
        h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()[:16]


FIXED_DATE_TIME = "1970:01:01 00:00:00"  # the EXR's DateTime when timings are left out

ABSURD_FACTOR = 1e6  # a pixel this many times brighter than the scene's light can make it is a numerical failure


def implausible_pixels(img: np.ndarray, layers: dict | None = None, light_radiance: float = 0.0) -> str | None:
    """What is wrong with a rendered image, or None: non-finite values, or values over ABSURD_FACTOR times the
    larger of the median positive pixel and the brightest radiance a light emits (light_radiance: a pixel that sees
    a light has at most its radiance). A legitimate highlight or caustic is orders of magnitude below that; an
    estimator that diverged, as the bounced light of a thick marble sphere once did, is far above."""
    for name, a in (("the image", img), *((f"layer {k!r}", v) for k, v in (layers or {}).items())):
        bad = ~np.isfinite(a)
        if bad.any():
            return f"{name} has {int(bad.any(axis=-1).sum())} pixels with non-finite values"
    lum = img.mean(axis=-1)
    positive = lum[lum > 0]
    if len(positive):
        limit = ABSURD_FACTOR * max(float(np.median(positive)), light_radiance)
        top = float(lum.max())
        if top > limit:
            return (f"the image has {int((lum > limit).sum())} pixels brighter than {ABSURD_FACTOR:g} x the median "
                    f"lit pixel (up to {top:.3g})")
    return None


# image-sized buffers per pixel (bytes): volpath's accumulator, the mean and the float32 file; pbl's five layers
# with their pass accumulators, the pixel statistics, the mean and the float32 layers (docs/pbl.md, memory)
IMAGE_BYTES_PER_PIXEL = {"volpath": 96, "pbl": 800, "dipole": 900, "raymarch": 800, "vpl": 800}


def check_memory(method: str, width: int, height: int, pbl=None, scene_path="", available: int | None = None):
    """Refuse, before any work, a render whose image buffers and (pbl, for a scene with a medium: pbl given) light
    samples would not fit in the available memory, naming what to lower."""
    from pbvol_cli.pipeline.samples import check_samples_memory, samples_memory

    image = IMAGE_BYTES_PER_PIXEL[method] * width * height
    samples = samples_memory(pbl) if pbl is not None else 0
    available = available_memory() if available is None else available
    if available is None or image + samples <= available:
        return
    if image >= samples:
        raise PbvolError(f"--resolution {width}x{height}: the {method} image buffers need about "
                         f"{image / 2**30:.1f} GiB, {available / 2**30:.1f} GiB is available; render smaller")
    check_samples_memory(pbl, scene_path, available - image)  # what is left beside the image


def writable_file(path: Path, what: str):
    """Refuse, before any work, a file that cannot be written: its folder missing or read-only, or itself
    read-only or a folder."""
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise PbvolError(f"{path}: cannot write {what}: the folder {parent} does not exist")
    if path.is_dir():
        raise PbvolError(f"{path}: cannot write {what}: it is a folder")
    if not os.access(parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise PbvolError(f"{path}: cannot write {what}: permission denied")


@dataclass
class Rendered:
    """A render in memory: the image and layers (H, W, 3) float64, the EXR metadata, the summary (render_scene's,
    without the output), and `problem`: why the image is implausible (non-finite or absurd pixels), else None."""

    image: np.ndarray
    layers: dict
    metadata: dict
    summary: dict
    problem: str | None
    sums: dict | None = None  # {layer: render/sample_sums.SampleSums}, the image their means' sum in this order
    # (VOLPATH_SUMS: volpath's image itself); what pbvol merge needs
    surface_paths: list | None = None  # the pass-based methods' mean camera paths per pixel, per pass


def render_loaded(scene: C.Scene, scene_path: Path, opts: RenderOptions, reference_size=None) -> Rendered:
    """Render a validated scene (scene_path: where its relative files live, and its name in errors and metadata)
    with opts. reference_size: (W, H) a reference image must match, checked before rendering."""
    from pbvol_cli.geometry.scene_build import build_scene

    if opts.method not in METHODS:
        raise PbvolError(f"unknown method {opts.method!r}; expected one of: {', '.join(METHODS)}")
    rs = scene.render
    spp = opts.spp or rs.spp
    first = 0
    if opts.samples is not None:
        first, end = opts.samples
        if not 0 <= first < end:
            raise PbvolError(f"--samples {first}:{end}: expected A:B with 0 <= A < B")
        spp = end - first
    seed = rs.seed if opts.seed is None else opts.seed
    max_depth = opts.max_depth or rs.max_depth
    time_limit = opts.time_limit if opts.time_limit is not None else rs.time_limit
    threads = set_threads(opts.threads or rs.threads)
    t_build = time.perf_counter()
    built = build_scene(scene, scene_path, opts.resolution)
    t_build = time.perf_counter() - t_build
    W, H = built.resolution
    check_memory(opts.method, W, H, rs.pbl if opts.method != "volpath" and built.medium_info else None, scene_path)
    if reference_size is not None and tuple(reference_size) != (W, H):
        raise PbvolError(f"the reference is {reference_size[0]}x{reference_size[1]}, the render {W}x{H}")

    layers, stages = {}, {}
    with CompileMonitor(opts.quiet) as compiling:
        if opts.method in ("pbl", "dipole", "raymarch", "vpl"):
            img, layers, stats, stages = _render_pbl(scene, built, spp, seed, threads, time_limit, opts,
                                                     scene_path, first)
            if "sums" in stats:  # the kept layers' sums, in the order the image adds them
                stats["sums"] = {k: v for k, v in stats["sums"].items() if k in layers}
            spp_done = stats["spp"]
        else:
            from pbvol_cli.render.volpath import orders_mask, render_volpath

            try:
                orders_mask(opts.orders)
            except ValueError as e:
                raise PbvolError(f"--orders: {e}") from None
            prog, update = progress_bar(opts.quiet, f"volpath {W}x{H} {spp} spp")
            with prog:
                img, spp_done, stats = render_volpath(
                    built, spp, seed, max_depth, rs.volpath.rr_depth, opts.orders, rs.volpath.batch_paths, threads,
                    time_limit, update, first_sample=first, split_depth=rs.volpath.split_depth,
                    split_rule=rs.volpath.split_rule,
                )
            if "sums" in stats:
                stats["sums"] = {VOLPATH_SUMS: stats["sums"]}
    elapsed = stats["time_s"]
    meta = {
        "method": opts.method, "spp": spp_done, "seed": seed, "threads": threads, "version": __version__,
        "scene": str(scene_path), "scene_hash": scene_hash(scene, built),
        "orders": opts.orders or "all", "max_depth": max_depth, "samples": f"{first}:{first + spp_done}",
    }
    if opts.timings:
        meta.update({"time_s": round(elapsed, 4), "build_s": round(t_build, 4),
                     **{f"stage_{k}": round(v, 4) for k, v in stages.items()}})
    if opts.method != "volpath":  # camera paths per pixel and pass (the mean over passes; 0 in the setting: auto)
        ks = stats["surface_paths"]
        meta["surface_paths"] = float(np.mean(ks))
        meta["surface_paths_per_pass"] = ",".join(f"{k:.4g}" for k in ks)
        meta["surface_paths_setting"] = scene.render.pbl.surface_paths
    summary = {
        "method": opts.method, "resolution": [W, H], "spp": spp_done,
        "time_s": elapsed, "samples_per_second": W * H * spp_done / max(elapsed, 1e-9),
        "peak_memory_mb": peak_memory_mb(), "threads": threads, "compile_s": compiling.seconds,
    }
    if stages:
        summary["stages"] = stages
    problem = implausible_pixels(img, layers, float(built.lights[:, LIGHT_RGB:LIGHT_RGB + 3].max(initial=0.0)))
    return Rendered(img, layers, meta, summary, problem, stats.get("sums"), stats.get("surface_paths"))


def render_scene(scene_path: Path, out_path: Path, opts: RenderOptions, preview: Path | None = None,
                 reference: Path | None = None, exposure: float = 0.0, renderer=None) -> dict:
    """Render a scene file to an EXR (renderer, with render_loaded's arguments: render_loaded itself by default,
    or pipeline/distributed.on_dask's), then the file. Returns the summary dict (also printed by the CLI)."""
    from pbvol_cli.imageio import read_exr, write_preview_png

    if opts.method not in METHODS:
        raise PbvolError(f"unknown method {opts.method!r}; expected one of: {', '.join(METHODS)}")
    out_path = Path(out_path)
    if out_path.suffix.lower() != ".exr":
        raise PbvolError(f"{out_path}: the output must be an .exr file (use --preview for a PNG)")
    writable_file(out_path, "the output")
    if preview is not None:
        writable_file(Path(preview), "--preview")
    ref_img = None
    if reference is not None:
        ref_img, _ = read_exr(reference)
        if not np.all(np.isfinite(ref_img)):
            raise PbvolError(f"{reference}: the reference has non-finite pixels; expected a finite image")
    if opts.shards is not None and renderer is None:
        raise PbvolError("--shards: only with --dask")
    scene = C.load_scene(scene_path)
    try:
        r = (renderer or render_loaded)(scene, Path(scene_path), opts,
                                        None if ref_img is None else ref_img.shape[1::-1])
    except PbvolError as e:
        if ref_img is not None and str(e).startswith("the reference is"):
            raise PbvolError(f"{reference}: {e}") from None
        raise
    write_render(out_path, r, opts)
    img = r.image
    if preview is not None:
        write_preview_png(preview, img, exposure)
    summary = {"output": str(out_path), **r.summary}
    if ref_img is not None:
        from pbvol_cli.pipeline.compare import image_metrics

        m = image_metrics(img.astype(np.float32), ref_img)
        summary["mse"] = m["mse"]
        summary["rel_mse"] = m["rel_mse"]
    return summary


def write_render(out_path: Path, r: Rendered, opts: RenderOptions):
    """The EXR of a render (float32, its layers and metadata) and, for a --samples part, its sums beside it; raises
    RenderFailed, after writing, when the image is implausible."""
    from pbvol_cli.imageio import write_exr

    write_exr(out_path, r.image.astype(np.float32), r.metadata,
              layers={k: v.astype(np.float32) for k, v in r.layers.items()} if r.layers else None,
              date_time=None if opts.timings else FIXED_DATE_TIME)
    if opts.samples is not None and r.sums is not None:
        save_sample_sums(out_path, r.sums, r.metadata, r.surface_paths)
    if r.problem:
        raise RenderFailed(f"{out_path}: written, but {r.problem}: the render failed (please report the scene)")


def sums_path(exr: Path) -> Path:
    """Where a part rendered with --samples keeps its exact per-pixel sums (beside its EXR)."""
    return Path(exr).with_name(Path(exr).name + ".samples.npz")


def save_sample_sums(exr: Path, sums: dict, meta: dict, surface_paths=None):
    """The part's sums beside its EXR: per layer (in the image's order) the nodes of its SampleSums, and each pass's
    mean camera paths per pixel (the pass-based methods)."""
    from pbvol_cli.pipeline.cache import save_npz_atomic

    arrays = {f"{name}.{k}": v for name, ss in sums.items() for k, v in ss.arrays().items()}
    if surface_paths is not None:
        arrays["surface_paths"] = np.asarray(surface_paths, np.float64)
    save_npz_atomic(sums_path(exr), scene_hash=np.array(meta["scene_hash"]), seed=np.array(meta["seed"]),
                    method=np.array(meta["method"]), layers=np.array(list(sums), dtype=str), **arrays)


@dataclass
class Part:
    """A render of a range of samples, as merge takes it: its metadata, each layer's sums (in the order the image
    adds them), each pass's mean camera paths per pixel (the pass-based methods, else None), its EXR's layer
    names, and what to call it in errors."""

    meta: dict
    sums: dict
    surface_paths: object
    layer_names: list
    name: str

    @classmethod
    def of(cls, r: Rendered, name: str) -> "Part":
        return cls(r.metadata, r.sums, r.surface_paths, list(r.layers), name)


def _load_part(part: Path) -> Part:
    from pbvol_cli.imageio import read_exr, read_layers
    from pbvol_cli.pipeline.cache import load_npz
    from pbvol_cli.render.sample_sums import SampleSums

    _, meta = read_exr(part)
    data = load_npz(sums_path(part), ("layers", "scene_hash", "method"))
    if data is None or any(f"{n}.sums" not in data for n in data["layers"]):
        raise PbvolError(f"{part}: its sums {sums_path(part).name} are missing or damaged; render it again with "
                         "--samples A:B")
    if str(data["scene_hash"]) != meta.get("scene_hash") or str(data["method"]) != meta.get("method"):
        raise PbvolError(f"{part}: its sums belong to another render (scene hash, method)")
    sums = {str(n): SampleSums.from_arrays({k: data[f"{n}.{k}"] for k in ("lo", "hi", "sums")})
            for n in data["layers"]}
    return Part(meta, sums, data.get("surface_paths"), list(read_layers(part)), str(part))


MERGE_MATCH = ("method", "scene_hash", "seed", "orders", "max_depth", "surface_paths_setting")  # what parts share


def merge_loaded(parts: list[Part], shape) -> Rendered:
    """The parts' sums pooled: the image and layers (shape (H, W, 3)), the same bit for bit as one render of their
    union (for pbl with auto surface paths, as the parts' passes were rendered: first_path_indices), with the
    merged metadata and sums (summary empty). Refuses parts of other scenes, seeds or methods, overlapping ranges
    or gaps."""
    from pbvol_cli.render.sample_sums import SampleSums, layer_means

    if not parts:
        raise PbvolError("merge: no parts given")
    first = parts[0]
    for part in parts[1:]:
        for key in MERGE_MATCH:
            if part.meta.get(key) != first.meta.get(key):
                raise PbvolError(f"{part.name}: {key} {part.meta.get(key)} differs from {first.name}'s "
                                 f"{first.meta.get(key)}")
        if list(part.sums) != list(first.sums):
            raise PbvolError(f"{part.name}: layers {', '.join(part.sums)} differ from {first.name}'s "
                             f"{', '.join(first.sums)}")
    try:
        merged = {name: SampleSums.merged([p.sums[name] for p in parts]) for name in first.sums}
    except ValueError as e:
        raise PbvolError(f"merge: the parts' sample ranges overlap or leave a gap ({e})") from None
    lo, hi = next(iter(merged.values())).range
    means = layer_means(merged, hi - lo, shape)
    image = sum(means.values())
    layers = {name: means.get(name, np.zeros(shape)) for name in first.layer_names}
    meta = {k: v for k, v in first.meta.items() if not k.startswith("stage_") and k not in ("time_s", "build_s")}
    meta.update({"spp": hi - lo, "samples": f"{lo}:{hi}", "merged_parts": len(parts)})
    ks = None
    if first.surface_paths is not None:  # the passes' camera paths, in pass order
        ordered = sorted(parts, key=lambda p: next(iter(p.sums.values())).range[0])
        ks = [float(k) for p in ordered for k in p.surface_paths]
        meta["surface_paths"] = float(np.mean(ks))
        meta["surface_paths_per_pass"] = ",".join(f"{k:.4g}" for k in ks)
    return Rendered(image, layers, meta, {}, None, merged, ks)


def merge_parts(parts: list[Path], out_path: Path) -> dict:
    """pbvol merge: the parts' exact sums (render --samples) pooled into one image and its layers (merge_loaded),
    written with their sums. Returns the merged metadata."""
    from pbvol_cli.imageio import read_exr, write_exr

    out_path = Path(out_path)
    if out_path.suffix.lower() != ".exr":
        raise PbvolError(f"{out_path}: the output must be an .exr file")
    writable_file(out_path, "the output")
    if not parts:
        raise PbvolError("merge: no parts given")
    r = merge_loaded([_load_part(part) for part in parts], read_exr(parts[0])[0].shape[:2] + (3,))
    write_exr(out_path, r.image.astype(np.float32), r.metadata,
              layers={k: v.astype(np.float32) for k, v in r.layers.items()} or None, date_time=FIXED_DATE_TIME)
    save_sample_sums(out_path, r.sums, r.metadata, r.surface_paths)
    return r.metadata


def _render_pbl(scene, built, spp, seed, threads, time_limit, opts, scene_path, first_pass=0):
    """Light samples and tables from the cache (built when missing), then the passes (pointbased/passes.py). The
    dipole (opts.method) takes the point-based method's single scattering, no tables, and its diffusion term from
    the irradiance samples (dipole/)."""
    from pbvol_cli.pipeline.samples import bounced_cache
    from pbvol_cli.pointbased.passes import render_passes

    if opts.method in ("raymarch", "vpl"):
        return _render_raymarch(scene, built, spp, seed, threads, time_limit, opts, first_pass)
    side = light_side(scene, built, seed, threads, opts, scene_path)
    pbl, res, stages, built = side.pbl, side.samples, side.stages, side.built
    samples = [res.samples if res else None]  # the passes take the only reference: freed when no longer needed
    if res:
        res.samples = None
    W, H = built.resolution
    prog, update = progress_bar(opts.quiet, f"{opts.method} {W}x{H} {spp} spp", "pixel samples")
    with prog:
        img, layers, stats, timings = render_passes(
            built, samples, side.tables, pbl, seed, spp, threads, update, time_limit,
            bounced_cache(side.cache, res.path, pbl, side.table_names) if res else None, side.entry, first_pass)
    if opts.method == "dipole":
        layers = {k: layers.get(k, np.zeros_like(img)) for k in DIPOLE_LAYERS}
    stages["render_s"] = stats["time_s"]
    stages["pass_samples_s"] = timings["pass_samples_s"]
    stages["bounced_s"] = timings["bounced_s"]
    stages["peak_memory_mb"] = peak_memory_mb()
    return img, layers, stats, stages


@dataclass
class LightSide:
    """What the point-based passes and the dipole read from the cache: pass 0's light samples (SamplesResult, None
    without a medium), the tables ({medium: [MSTable or None] x 3}) and their entries' names, the dipole's
    diffusion term (entry), the settings with the method's components, the cache folder, the stages' times and
    the scene as the passes render it (its media after [render.pbl] similarity)."""

    pbl: object
    samples: object
    tables: dict
    table_names: dict
    entry: object
    cache: Path
    stages: dict
    built: object


def pbl_media(built, pbl, method: str):
    """The scene as the point-based method renders it: its media after pbl.similarity (pointbased/similarity.py), for
    --method pbl only (the dipole's single scattering takes the media as given). built itself when unchanged."""
    from pbvol_cli.pointbased.similarity import TRANSFORMS

    if method == "pbl" and pbl.similarity in TRANSFORMS:
        return replace(built, media=TRANSFORMS[pbl.similarity](built.media))
    return built


def _note_thick_bodies(built, scene_path, extent: float):
    """A note on stderr for each medium whose body pbl renders too dark (check.pointbased_regime): a render that
    reads low where the method is known to, said before it starts."""
    from pbvol_cli.pipeline.check import pointbased_regime

    for k, info in enumerate(built.medium_info):
        why = pointbased_regime(built, k, extent=extent)
        if why:
            print(f"note: {scene_path}: medium {info.label!r}: {why}", file=sys.stderr)


def light_side(scene, built, seed, threads, opts, scene_path) -> LightSide:
    """The light side of a pbl or dipole render from the cache (built and stored when missing)."""
    from pbvol_cli.geometry.scene_build import MED_G, MED_PHASE
    from pbvol_cli.pipeline.cache import cache_dir
    from pbvol_cli.pipeline.lut import get_table, table_groups
    from pbvol_cli.pipeline.samples import get_light_samples
    from pbvol_cli.physics.phase import mean_cosine
    from pbvol_cli.pointbased.camera_pass import COMPONENTS
    from pbvol_cli.pointbased.passes import TABLE_COMPONENTS

    homogeneous_media_only(built, opts.method, scene_path)
    if opts.method == "pbl":
        _note_thick_bodies(built, scene_path, scene.render.lut.extent)
    pbl = scene.render.pbl
    dipole = opts.method == "dipole"
    if dipole and opts.components:
        raise PbvolError("--components: the dipole's layers are fixed (single, diffusion, surface); it takes no "
                         "--components")
    if dipole:
        pbl = pbl.model_copy(update={"components": ("single",)})
    if opts.components:
        comps = tuple(c.strip() for c in opts.components.split(",") if c.strip())
        bad = [c for c in comps if c not in COMPONENTS]
        if bad:
            raise PbvolError(f"--components: unknown {', '.join(bad)}; "
                             f"expected a comma list of {', '.join(COMPONENTS)}")
        pbl = pbl.model_copy(update={"components": comps})
    built = pbl_media(built, pbl, opts.method)
    cache = cache_dir(opts.cache_dir)
    stages = {}
    t0 = time.perf_counter()
    res = None  # surfaces only: no samples
    if built.medium_info:
        prog, update = progress_bar(opts.quiet, "place-samples", "steps")
        with prog:
            res = get_light_samples(built, pbl, seed, cache, threads, progress=update)
    entry = None
    if dipole and built.medium_info:
        entry, stages["irradiance_s"], stages["irradiance_reused"] = _diffusion_term(scene, built, seed, cache,
                                                                                     threads, opts.quiet)
    stages["samples_s"] = time.perf_counter() - t0
    stages["samples_reused"] = float(res.reused) if res else 0.0
    stages["samples_peak_mb"] = peak_memory_mb()
    t0 = time.perf_counter()
    tables, table_names = {}, {}
    wanted = any(c in pbl.components for c in TABLE_COMPONENTS)
    for m in range(len(built.medium_info)):
        tables[m], table_names[m] = [None] * 3, [None] * 3
        if not wanted:
            continue
        # the phase function as pbl renders it: the material's, or its similarity transform's
        kind, g = int(built.media[m, MED_PHASE]), float(built.media[m, MED_G])
        for alpha, channels, settings in table_groups(*built.medium_sigmas(m), mean_cosine(kind, g),
                                                      built.medium_side(m), scene.render.lut):
            r = get_table(alpha, g, kind, settings, cache)
            for c in channels:
                tables[m][c], table_names[m][c] = r.table, r.path.name
    stages["tables_s"] = time.perf_counter() - t0
    stages["tables_peak_mb"] = peak_memory_mb()
    return LightSide(pbl, res, tables, table_names, entry, cache, stages, built)


def _render_raymarch(scene, built, spp, seed, threads, time_limit, opts, first_pass=0):
    """The ray-marching integrator (render/raymarch.py) or, for opts.method "vpl", it and the VPLs (vpl/gather.py):
    the point-based method's camera paths, no light samples, each medium segment marched. Layers: RAYMARCH_LAYERS,
    VPL_LAYERS."""
    from pbvol_cli.pointbased.camera_pass import render_pbl
    from pbvol_cli.render.raymarch import RayMarcher

    if opts.components:
        names = RAYMARCH_LAYERS if opts.method == "raymarch" else VPL_LAYERS
        raise PbvolError(f"--components: the {opts.method} method's layers are fixed ({', '.join(names)}); it takes "
                         "no --components")
    pbl = scene.render.pbl.model_copy(update={"components": (), "surface_paths": 1})  # every path gathers
    if opts.method == "vpl":
        from pbvol_cli.vpl.gather import VPLGather

        segment, names = VPLGather(built, scene.render.raymarch, scene.render.vpl, seed), VPL_LAYERS
    else:
        segment, names = RayMarcher(built, scene.render.raymarch), RAYMARCH_LAYERS
    W, H = built.resolution
    prog, update = progress_bar(opts.quiet, f"{opts.method} {W}x{H} {spp} spp", "pixel samples")
    with prog:
        img, layers, stats = render_pbl(built, lambda p: {}, spp, seed, pbl, threads, update, time_limit=time_limit,
                                        segment=segment, first_pass=first_pass)
    return img, {k: layers[k] for k in names}, stats, {}


def homogeneous_media_only(built, method: str, scene_path):
    """pbl and the dipole model homogeneous, non-emissive media only: refuse the others, naming the medium."""
    from pbvol_cli.geometry.scene_build import HOMOGENEOUS, MED_KIND

    for m, info in enumerate(built.medium_info):
        if built.media[m, MED_KIND] != HOMOGENEOUS:
            what = "a density field" if info.material.density is not None else "emission"
            raise PbvolError(f"{scene_path}: medium {info.label!r} has {what}: --method {method} renders "
                             "homogeneous, non-emissive media only; render it with --method volpath")


def _diffusion_term(scene, built, seed, cache, threads, quiet):
    """(the dipole's DiffusionPasses, seconds, whether pass 0's samples came from the cache)."""
    from pbvol_cli.dipole.hierarchy import DiffusionPasses
    from pbvol_cli.dipole.irradiance import place_irradiance_samples
    from pbvol_cli.pipeline.samples import get_irradiance_samples

    prog, update = progress_bar(quiet, "irradiance samples", "steps")
    with prog:
        res = get_irradiance_samples(built, scene, seed, cache, threads, progress=update,
                                     note=lambda text: print(f"note: {text}", file=sys.stderr))
    pbl, dip = scene.render.pbl, scene.render.dipole

    def place(p: int):
        return place_irradiance_samples(built, res.count, pbl.max_internal_reflections, pbl.max_layers, seed + p,
                                        threads)

    return DiffusionPasses(built, res.samples, place, dip.max_error, pbl.light_sets), res.seconds, float(res.reused)


def format_summary(s: dict) -> str:
    line = (f"{s['method']}: {s['resolution'][0]}x{s['resolution'][1]}, {s['spp']} spp in {s['time_s']:.2f} s "
            f"({s['samples_per_second'] / 1e6:.3f} M samples/s, {s['threads']} threads), "
            f"peak memory {s['peak_memory_mb']:.0f} MiB -> {s['output']}")
    if s.get("compile_s", 0.0) >= 1.0:
        line += f"\ncompiling numba kernels took {s['compile_s']:.0f} s of it (once: cached for later runs)"
    st = s.get("stages")
    if st:
        line += (f"\nstages: light samples {st['samples_s']:.2f} s"
                 f"{' (cached)' if st.get('samples_reused') else ''}, peak {st['samples_peak_mb']:.0f} MiB; "
                 f"tables {st['tables_s']:.2f} s, peak {st['tables_peak_mb']:.0f} MiB; "
                 f"camera pass {st['render_s']:.2f} s "
                 f"(of which {st['pass_samples_s']:.2f} s new light samples per pass, "
                 f"{st.get('bounced_s', 0.0):.2f} s bounced samples), peak {st['peak_memory_mb']:.0f} MiB")
    if "mse" in s:
        line += f"\nMSE against reference: {s['mse']:.6g} (relMSE {s['rel_mse']:.6g})"
    return line
