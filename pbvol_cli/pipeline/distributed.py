"""Rendering across a Dask cluster: a scene's sample range (passes, for the pass-based methods) split into shards,
each rendered by a worker as `render --samples A:B` would, and the shards' sums merged exactly (render.merge_loaded):
the image is the same, bit for bit, as one process's render of the whole range.

What travels: the validated scene (its meshes and density grids are read by the workers at the same paths: they
need a shared file system, or the same files in the same place) and, for pbl and the dipole, the cache entries the
render reads (pass 0's light samples, the tables, the irradiance samples), filled once by this process. A local
cluster (`local[N]`) shares this machine's cache folder, so nothing is shipped; for a remote scheduler each entry
is scattered once to every worker, which installs it in its own cache (install_entry) unless it holds it already.
A worker that dies loses its shard; the scheduler runs it again elsewhere, and as every shard's image is fixed by
its range and seed, the result does not change.
"""

from __future__ import annotations

import logging
import os
import re
import time
from dataclasses import replace
from pathlib import Path

from pbvol_cli import config as C
from pbvol_cli.errors import PbvolError
from pbvol_cli.pipeline.progress import peak_memory_mb, progress_bar
from pbvol_cli.pipeline.render import (Part, format_summary, implausible_pixels, light_side, merge_loaded,
                                       render_loaded, render_scene, writable_file, write_render)

LOCAL = re.compile(r"local(?:\[(\d+)\])?$")  # local[N]: a LocalCluster of N single-threaded worker processes


def connect(address: str):
    """(client, cluster or None, whether the workers share this machine's files) for --dask ADDRESS: local[N]
    starts a LocalCluster of N processes (all cores when N is left out), anything else is a scheduler's address."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise PbvolError("--dask: Dask is not installed; install it with: pip install 'pbvol[dask]'") from None
    local = LOCAL.match(address.strip())
    if local:
        n = int(local.group(1) or os.cpu_count() or 1)
        if not 1 <= n <= 256:
            raise PbvolError(f"--dask {address}: expected local[N] with 1 <= N <= 256")
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)
        return Client(cluster), cluster, True
    try:
        return Client(address, timeout="10s"), None, False
    except (OSError, TimeoutError, ValueError) as e:
        raise PbvolError(f"--dask {address}: cannot reach the scheduler ({' '.join(str(e).split())})") from None


def shard_ranges(first: int, end: int, shards: int) -> list[tuple[int, int]]:
    """[first, end) cut into at most `shards` contiguous ranges of near-equal length, in order."""
    n = max(1, min(shards, end - first))
    cuts = [first + (end - first) * i // n for i in range(n + 1)]
    return [(a, b) for a, b in zip(cuts, cuts[1:]) if b > a]


def cache_entries(scene, scene_path: Path, opts, read: bool = True) -> dict:
    """{path relative to the cache folder: bytes (None unless read)} of the entries a render of the scene reads
    (light samples, tables, irradiance samples), built here when missing."""
    from pbvol_cli.geometry.scene_build import build_scene
    from pbvol_cli.pipeline.cache import cache_dir, entries_used
    from pbvol_cli.pipeline.progress import set_threads

    if opts.method not in ("pbl", "dipole"):
        return {}
    built = build_scene(scene, scene_path, opts.resolution)
    if not built.medium_info:
        return {}
    seed = scene.render.seed if opts.seed is None else opts.seed
    with entries_used() as used:
        light_side(scene, built, seed, set_threads(opts.threads or scene.render.threads), opts, scene_path)
    root = cache_dir(opts.cache_dir)
    return {str(p.relative_to(root)): p.read_bytes() if read else None for p in sorted(used) if p.exists()}


def render_shard(scene, scene_path: Path, opts, entries: dict, cache):
    """A worker's task: install the shipped cache entries (when any), render the shard's range (opts.samples), and
    return it as a render.Part."""
    from pbvol_cli.pipeline.cache import cache_dir, install_entry

    root = cache_dir(cache)
    for rel, data in (entries or {}).items():
        install_entry(root / rel, data)
    a, b = opts.samples
    return Part.of(render_loaded(scene, scene_path, replace(opts, cache_dir=cache, quiet=True)), f"samples {a}:{b}")


def render_distributed(jobs: list, dask, shards: int | None = None, ship_cache: bool | None = None,
                       worker_cache=None, quiet: bool = False) -> list:
    """Render jobs [(config.Scene, scene path, render.RenderOptions)] across a Dask cluster; returns their
    render.Rendered, each the same image as one process renders. dask: local[N], a scheduler's address, or a
    distributed.Client. shards: per job (default: the cluster's worker threads). ship_cache: send the cache
    entries to the workers (default: for a remote scheduler); worker_cache: the workers' cache folder when shipped
    (default: theirs). One progress bar over every job's passes."""
    from distributed import Client, as_completed

    from pbvol_cli.geometry.scene_build import build_scene
    from pbvol_cli.physics.lights import LIGHT_RGB

    for _, path, opts in jobs:
        if opts.time_limit is not None:
            raise PbvolError(f"{path}: --time-limit: not with --dask (shards stop on their own clocks, so the "
                             "image would depend on timing); give --spp instead")
    own = not isinstance(dask, Client)
    client, cluster, shared = connect(dask) if own else (dask, None, False)
    try:
        t0 = time.perf_counter()
        ship = (not shared) if ship_cache is None else ship_cache
        threads = sum(client.nthreads().values()) or 1
        n_shards = shards or threads
        futures, total = {}, 0
        for j, (scene, path, opts) in enumerate(jobs):
            rs = scene.render
            first, end = opts.samples if opts.samples is not None else (0, opts.spp or rs.spp)
            if shared and opts.threads is None:  # the machine's cores shared among its worker processes
                opts = replace(opts, threads=max(1, (os.cpu_count() or 1) // len(client.nthreads())))
            entries = cache_entries(scene, path, opts, read=ship)
            entries = client.scatter(entries, broadcast=True) if ship and entries else None
            cache = worker_cache if ship else opts.cache_dir
            for a, b in shard_ranges(first, end, n_shards):
                f = client.submit(render_shard, scene, path, replace(opts, samples=(a, b), spp=None), entries, cache,
                                  pure=False, key=f"pbvol-{j}-{a}-{b}-{os.urandom(4).hex()}")
                futures[f] = (j, b - a)
                total += b - a
        label = f"{jobs[0][2].method} on dask ({len(futures)} shards)" if len(jobs) == 1 else \
            f"{len(jobs)} scenes on dask ({len(futures)} shards)"
        prog, update = progress_bar(quiet, label, "samples")
        parts, done = {j: [] for j in range(len(jobs))}, 0
        with prog:
            for f in as_completed(futures):
                j, n = futures[f]
                parts[j].append(_shard_result(f, jobs[j][1], client, futures))
                done += n
                update(done, total)
        out = []
        for j, (scene, path, opts) in enumerate(jobs):
            built = build_scene(scene, path, opts.resolution)
            W, H = built.resolution
            r = merge_loaded(parts[j], (H, W, 3))
            r.metadata.pop("merged_parts", None)
            elapsed = time.perf_counter() - t0
            if opts.timings:
                r.metadata["time_s"] = round(elapsed, 4)
            spp = r.metadata["spp"]
            r.summary = {"method": opts.method, "resolution": [W, H], "spp": spp, "time_s": elapsed,
                         "samples_per_second": W * H * spp / max(elapsed, 1e-9), "peak_memory_mb": peak_memory_mb(),
                         "threads": threads, "compile_s": 0.0, "shards": len(parts[j])}
            r.problem = implausible_pixels(r.image, r.layers,
                                           float(built.lights[:, LIGHT_RGB:LIGHT_RGB + 3].max(initial=0.0)))
            out.append(r)
        return out
    finally:
        if own:
            client.close()
            if cluster is not None:
                cluster.close()


def _shard_result(future, scene_path, client, futures):
    """A finished shard's render.Part; a shard that failed cancels the others and raises a one-line PbvolError
    (a worker's own PbvolError as it is, anything else named with the scene)."""
    try:
        return future.result()
    except PbvolError:
        client.cancel(list(futures))
        raise
    except Exception as e:  # a worker's failure arrives as the exception it raised
        client.cancel(list(futures))
        raise PbvolError(f"{scene_path}: a shard failed on a Dask worker: {type(e).__name__}: "
                         f"{' '.join(str(e).split())}") from None


def on_dask(dask, shards: int | None = None, quiet: bool = False):
    """A renderer for render.render_scene (render_loaded's arguments) that renders on the cluster dask."""
    def render(scene, scene_path, opts, reference_size=None):
        r = render_distributed([(scene, scene_path, opts)], dask, shards, quiet=quiet)[0]
        W, H = r.summary["resolution"]
        if reference_size is not None and tuple(reference_size) != (W, H):
            raise PbvolError(f"the reference is {reference_size[0]}x{reference_size[1]}, the render {W}x{H}")
        return r

    return render


def render_batch(scene_paths: list[Path], out_dir: Path, opts, dask: str | None = None,
                 report=print) -> int:
    """pbvol batch: every scene rendered to out_dir/<its name>.exr, one after the other, or with dask all their
    shards on the cluster at once. A scene that fails is reported (report(line)) and
    the others go on. Returns how many failed."""
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise PbvolError(f"{out_dir}: the output folder does not exist")
    outs = [out_dir / f"{Path(p).stem}.exr" for p in scene_paths]
    seen = {}
    for path, out in zip(scene_paths, outs):
        if out in seen:
            raise PbvolError(f"{path}: its image {out.name} would overwrite {seen[out]}'s; rename one")
        seen[out] = path
    if opts.shards is not None and dask is None:
        raise PbvolError("--shards: only with --dask")
    failed = 0
    if dask is None:
        for path, out in zip(scene_paths, outs):
            try:
                report(format_summary(render_scene(path, out, opts)))
            except (PbvolError, OSError) as e:
                failed += 1
                report(f"error: {' '.join(str(e).split())}")
        return failed
    jobs, targets = [], []
    for path, out in zip(scene_paths, outs):
        try:
            writable_file(out, "the output")
            jobs.append((C.load_scene(path), Path(path), opts))
            targets.append(out)
        except (PbvolError, OSError) as e:
            failed += 1
            report(f"error: {' '.join(str(e).split())}")
    rendered = render_distributed(jobs, dask, opts.shards, quiet=opts.quiet) if jobs else []
    for out, r in zip(targets, rendered):
        try:
            write_render(out, r, opts)
            report(format_summary({"output": str(out), **r.summary}))
        except (PbvolError, OSError) as e:
            failed += 1
            report(f"error: {' '.join(str(e).split())}")
    return failed


