"""The `pbvol` command line: one thin function per subcommand, no physics here."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer
from typer.core import TyperGroup

from pbvol_cli.config import MAX_DEPTH, MAX_RESOLUTION, MAX_SEED, MAX_SPP, MAX_THREADS
from pbvol_cli.errors import PbvolError, RenderFailed

# Exit statuses, one convention for every command (README: Errors and exit codes).
EXIT_OK, EXIT_BAD_INPUT, EXIT_COMPARISON_FAILED, EXIT_RENDER_FAILED, EXIT_INTERRUPTED = 0, 1, 2, 3, 130


class OneLineErrors(TyperGroup):
    """The command line's own mistakes (an unknown option, a value out of its bounds) print as one line and exit
    EXIT_BAD_INPUT, like pbvol's; Ctrl-C says so and exits EXIT_INTERRUPTED."""

    def main(self, *args, standalone_mode: bool = True, **kwargs):
        if not standalone_mode:
            return super().main(*args, standalone_mode=False, **kwargs)
        try:
            status = super().main(*args, standalone_mode=False, **kwargs)
        except (KeyboardInterrupt, typer.Abort):
            status = EXIT_INTERRUPTED
        except Exception as e:  # click's usage errors (typer vendors click: matched by what they carry)
            if not (hasattr(e, "format_message") and hasattr(e, "exit_code")):
                raise
            if type(e).__name__ == "NoArgsIsHelpError":
                e.show()
            else:
                typer.echo(f"error: {' '.join(e.format_message().split())}", err=True)
            sys.exit(EXIT_BAD_INPUT)
        if status == EXIT_INTERRUPTED:
            typer.echo("error: interrupted", err=True)
        sys.exit(status if isinstance(status, int) else EXIT_OK)


app = typer.Typer(
    cls=OneLineErrors,
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="Render participating media behind refractive boundaries from TOML scene files.",
)


def _print_version(value: bool):
    if value:
        from pbvol_cli import __version__

        typer.echo(f"pbvol {__version__}")
        raise typer.Exit()


@app.callback()
def _options(version: Annotated[bool, typer.Option("--version", callback=_print_version, is_eager=True,
                                                   help="print the version and exit")] = False):
    """Render participating media behind refractive boundaries from TOML scene files."""


# options several commands share
SceneArg = Annotated[Path, typer.Argument(help="scene file (TOML)")]
SeedOpt = Annotated[Optional[int], typer.Option(min=0, max=MAX_SEED, help="random seed (overrides the scene)")]
ThreadsOpt = Annotated[Optional[int], typer.Option(min=1, max=MAX_THREADS,
                                                   help="worker threads (default: all cores)")]
CacheDirOpt = Annotated[Optional[Path], typer.Option(help="cache directory (else $PBVOL_CACHE_DIR, else "
                                                    "$XDG_CACHE_HOME/pbvol, else ~/.cache/pbvol)")]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="no progress bar")]
JsonOpt = Annotated[bool, typer.Option("--json", help="print the summary as one line of JSON (for scripts)")]
ForceOpt = Annotated[bool, typer.Option("--force", help="rebuild even when the cache holds a matching entry")]
DaskOpt = Annotated[Optional[str], typer.Option(help="render on a Dask cluster: a scheduler's address "
                                                "(tcp://host:8786) or local[N] for N local worker processes; the "
                                                "image is the same as without")]
ShardsOpt = Annotated[Optional[int], typer.Option(min=1, max=MAX_SPP, help="with --dask: pieces of each scene's "
                                                  "samples (default: one per worker thread)")]


def _fail(err: Exception, code: int = EXIT_BAD_INPUT):
    typer.echo(f"error: {err}", err=True)
    raise typer.Exit(code)


def _parse_resolution(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        w, h = (int(x) for x in text.lower().replace(",", "x").split("x"))
        if not (1 <= w <= MAX_RESOLUTION and 1 <= h <= MAX_RESOLUTION):
            raise ValueError
    except ValueError:
        raise PbvolError(f"--resolution: expected WIDTHxHEIGHT such as 256x256, each 1 to {MAX_RESOLUTION}, got "
                         f"{text!r}") from None
    return w, h


@app.command()
def render(
    scene: SceneArg,
    output: Annotated[Path, typer.Option("-o", "--output", help="output image (.exr)")],
    method: Annotated[str, typer.Option(help="volpath (the reference path tracer), pbl (point-based), dipole "
                                        "(diffusion BSSRDF), raymarch (emission and single scattering, marched) "
                                        "or vpl (raymarch and virtual point lights)")] = "volpath",
    spp: Annotated[Optional[int], typer.Option(min=1, max=MAX_SPP, help="samples (volpath) or passes (pbl, dipole, "
                                                "raymarch, vpl) per pixel (overrides the scene)")] = None,
    seed: SeedOpt = None,
    threads: ThreadsOpt = None,
    time_limit: Annotated[Optional[float], typer.Option(min=0.001, help="stop after the pass that crosses this "
                                                        "many seconds")] = None,
    resolution: Annotated[Optional[str], typer.Option(help="WIDTHxHEIGHT (overrides the scene)")] = None,
    orders: Annotated[Optional[str], typer.Option(help="volpath: keep only paths with these numbers of volume "
                                                  "scattering events: 0, 1, 2, 3+, or a comma list")] = None,
    max_depth: Annotated[Optional[int], typer.Option(min=1, max=MAX_DEPTH,
                                                     help="maximum path depth (overrides the scene)")] = None,
    components: Annotated[Optional[str], typer.Option(help="pbl: comma list of single, double, multiple, "
                                                      "bounced")] = None,
    preview: Annotated[Optional[Path], typer.Option(help="also write a tone-mapped sRGB PNG here")] = None,
    exposure: Annotated[float, typer.Option(help="preview exposure in stops")] = 0.0,
    reference: Annotated[Optional[Path], typer.Option(help="print the MSE against this image at the end")] = None,
    cache_dir: CacheDirOpt = None,
    quiet: QuietOpt = False,
    as_json: JsonOpt = False,
    timings: Annotated[bool, typer.Option(help="record times in the EXR metadata (--no-timings: leave them and the "
                                          "writing date out, so the same render gives the same bytes)")] = True,
    samples: Annotated[Optional[str], typer.Option(help="A:B: render samples (passes) A .. B-1 of the scene's "
                                                   "sequence, a part for `pbvol merge`")] = None,
    dask: DaskOpt = None,
    shards: ShardsOpt = None,
):
    """Render SCENE to an EXR image (float32 RGB with metadata)."""
    from pbvol_cli.pipeline.cache import cache_dir as resolve_cache
    from pbvol_cli.pipeline.render import RenderOptions, format_summary, render_scene

    try:
        resolve_cache(cache_dir)
        opts = RenderOptions(method=method, spp=spp, seed=seed, threads=threads, time_limit=time_limit,
                             resolution=_parse_resolution(resolution), orders=orders, max_depth=max_depth,
                             components=components, cache_dir=cache_dir, quiet=quiet, timings=timings,
                             samples=_parse_samples(samples), shards=shards)
        renderer = None
        if dask is not None:
            from pbvol_cli.pipeline.distributed import on_dask

            renderer = on_dask(dask, shards, quiet)
        summary = render_scene(scene, output, opts, preview=preview, reference=reference, exposure=exposure,
                               renderer=renderer)
    except RenderFailed as e:
        _fail(e, EXIT_RENDER_FAILED)
    except (PbvolError, OSError) as e:
        _fail(e)
    typer.echo(json.dumps(summary) if as_json else format_summary(summary))


def _parse_samples(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    a, sep, b = text.partition(":")
    try:
        first, end = int(a), int(b)
    except ValueError:
        raise PbvolError(f"--samples: expected A:B (samples A .. B-1), got {text!r}") from None
    if not sep or not 0 <= first < end <= MAX_SPP:
        raise PbvolError(f"--samples: expected A:B with 0 <= A < B <= {MAX_SPP}, got {text!r}")
    return first, end


@app.command()
def merge(
    parts: Annotated[list[Path], typer.Argument(help="EXRs rendered with --samples (their .samples.npz beside)")],
    output: Annotated[Path, typer.Option("-o", "--output", help="merged image (.exr)")],
    quiet: QuietOpt = False,
):
    """Merge renders of sample ranges (render --samples A:B) into one image, the same bit for bit as one render of
    the union; refuses parts of another scene, seed or method, and ranges that overlap or leave a gap."""
    from pbvol_cli.pipeline.render import merge_parts

    try:
        meta = merge_parts(parts, output)
    except (PbvolError, OSError) as e:
        _fail(e)
    if not quiet:
        typer.echo(f"merged {len(parts)} parts: samples {meta['samples']} -> {output}")


@app.command()
def batch(
    scenes: Annotated[list[Path], typer.Argument(help="scene files (TOML)")],
    output_dir: Annotated[Path, typer.Option("-o", "--output-dir", help="folder for the images (NAME.exr for "
                                             "NAME.toml)")],
    method: Annotated[str, typer.Option(help="as render's")] = "volpath",
    spp: Annotated[Optional[int], typer.Option(min=1, max=MAX_SPP, help="samples or passes per pixel (overrides "
                                               "the scenes)")] = None,
    seed: SeedOpt = None,
    threads: ThreadsOpt = None,
    resolution: Annotated[Optional[str], typer.Option(help="WIDTHxHEIGHT (overrides the scenes)")] = None,
    dask: DaskOpt = None,
    shards: ShardsOpt = None,
    cache_dir: CacheDirOpt = None,
    quiet: QuietOpt = False,
):
    """Render many scenes, one after the other or, with --dask, all on a cluster at once; a scene that fails is
    reported and the others go on (exit status 3 when any failed)."""
    from pbvol_cli.pipeline.distributed import render_batch
    from pbvol_cli.pipeline.render import RenderOptions

    try:
        opts = RenderOptions(method=method, spp=spp, seed=seed, threads=threads,
                             resolution=_parse_resolution(resolution), cache_dir=cache_dir, quiet=quiet,
                             shards=shards)
        failed = render_batch(scenes, output_dir, opts, dask, report=lambda line: _batch_line(line, quiet))
    except (PbvolError, OSError) as e:
        _fail(e)
    if failed:
        typer.echo(f"error: {failed} of {len(scenes)} scenes failed", err=True)
        sys.exit(EXIT_RENDER_FAILED)


def _batch_line(line: str, quiet: bool):
    """A batch's report: errors on stderr, the scenes' summaries on stdout (none with -q)."""
    if line.startswith("error: "):
        typer.echo(line, err=True)
    elif not quiet:
        typer.echo(line)


@app.command("export-mitsuba")
def export_mitsuba_cmd(
    scene: SceneArg,
    output: Annotated[Path, typer.Option("-o", "--output", help="Mitsuba 3 scene: .json (mi.load_dict form) or "
                                         ".xml; meshes and grids are written beside it")],
    spp: Annotated[Optional[int], typer.Option(min=1, max=MAX_SPP, help="samples per pixel (overrides the "
                                               "scene)")] = None,
    resolution: Annotated[Optional[str], typer.Option(help="WIDTHxHEIGHT (overrides the scene)")] = None,
    quiet: QuietOpt = False,
):
    """Write SCENE as a Mitsuba 3 scene (volpath) for every feature both share, to cross-check pbvol in Mitsuba;
    what Mitsuba lacks is refused (emissive media) or approximated with a warning (README: export-mitsuba)."""
    from pbvol_cli.pipeline.export_mitsuba import export_mitsuba

    try:
        warnings = export_mitsuba(scene, output, spp=spp, resolution=_parse_resolution(resolution))
    except (PbvolError, OSError) as e:
        _fail(e)
    for w in warnings:
        typer.echo(f"warning: {w}", err=True)
    if not quiet:
        typer.echo(f"wrote {output}")


@app.command("precompute-lut")
def precompute_lut(
    file: Annotated[Path, typer.Argument(help="material file, or scene file (then every medium in it)")],
    particles: Annotated[Optional[int], typer.Option(min=1000, help="particles per table (default: a collision "
                                                     "budget)")] = None,
    seed: SeedOpt = None,
    threads: ThreadsOpt = None,
    force: ForceOpt = False,
    cache_dir: CacheDirOpt = None,
    quiet: QuietOpt = False,
):
    """Precompute the multiple-scattering tables (one per distinct albedo of each medium) into the cache."""
    from pbvol_cli.pipeline.cache import cache_dir as resolve_cache
    from pbvol_cli.pipeline.precompute import precompute
    from pbvol_cli.pipeline.progress import set_threads

    try:
        set_threads(threads)
        precompute(file, resolve_cache(cache_dir, for_writing=True), particles, seed, force, quiet, typer.echo)
    except (PbvolError, OSError) as e:
        _fail(e)


@app.command("place-samples")
def place_samples(
    scene: SceneArg,
    seed: SeedOpt = None,
    threads: ThreadsOpt = None,
    force: ForceOpt = False,
    cache_dir: CacheDirOpt = None,
    quiet: QuietOpt = False,
    method: Annotated[str, typer.Option(help="pbl: the light samples; dipole: those (its single scattering) and the "
                                        "irradiance samples; vpl, raymarch, volpath: nothing to place")] = "pbl",
):
    """Place the light surface and volume samples of the point-based method (and the dipole's irradiance samples)
    and cache them."""
    from pbvol_cli import config as C
    from pbvol_cli.geometry.scene_build import build_scene
    from pbvol_cli.pipeline.cache import cache_dir as resolve_cache
    from pbvol_cli.pipeline.progress import peak_memory_mb, progress_bar, set_threads
    from pbvol_cli.pipeline.render import homogeneous_media_only, pbl_media
    from pbvol_cli.pipeline.samples import check_samples_memory, get_irradiance_samples, get_light_samples

    try:
        if method not in ("pbl", "dipole", "vpl", "raymarch", "volpath"):
            raise PbvolError(f"--method: expected pbl, dipole, vpl, raymarch or volpath, got {method!r}")
        n = set_threads(threads)
        sc = C.load_scene(scene)
        if method not in ("pbl", "dipole"):
            # nothing worth caching: vpl's walks (a few hundred per pass) take milliseconds, less than reading an
            # entry
            why = "its walks are traced each pass, in milliseconds" if method == "vpl" else "it needs none"
            typer.echo(f"{scene}: --method {method} places no samples ({why}); nothing to cache")
            return
        check_samples_memory(sc.render.pbl, scene)
        built = build_scene(sc, scene)
        homogeneous_media_only(built, "pbl" if method == "pbl" else "dipole", scene)
        built = pbl_media(built, sc.render.pbl, method)  # (what render places: [render.pbl] similarity)
        cache = resolve_cache(cache_dir, for_writing=True)
        the_seed = sc.render.seed if seed is None else seed
        prog, update = progress_bar(quiet, "place-samples", "steps")
        with prog:
            r = get_light_samples(built, sc.render.pbl, the_seed, cache, n, force, update)
        if method == "dipole":
            prog, update = progress_bar(quiet, "irradiance samples", "steps")
            with prog:
                ir = get_irradiance_samples(built, sc, the_seed, cache, n, force, update,
                                            note=lambda text: typer.echo(f"note: {text}", err=True))
    except (PbvolError, OSError) as e:
        _fail(e)
    what = "reused cached samples" if r.reused else f"placed in {r.seconds:.2f} s"
    typer.echo(f"{scene}: {what}: {len(r.samples.s_pos)} surface samples, {len(r.samples.v_start)} volume samples, "
               f"peak memory {peak_memory_mb():.0f} MiB -> {r.path}")
    if method == "dipole":
        what = "reused cached samples" if ir.reused else f"placed in {ir.seconds:.2f} s"
        typer.echo(f"{scene}: {what}: {len(ir.samples.pos)} irradiance samples -> {ir.path}")


# compare --fail-above METRIC=VALUE: the key of image_metrics each metric reads
GATED_METRICS = {"mse": "mse", "rel-mse": "rel_mse", "relmse": "rel_mse", "flip": "flip",
                 "pixels": "pixels_over", "pixels-percent": "pixels_over_percent"}


def _gates(fail_above: list[str], metric: str) -> list[tuple[str, float]]:
    """(metric, bound) of each --fail-above: METRIC=VALUE, or a bare VALUE for --metric."""
    gates = []
    for item in fail_above:
        name, _, text = item.rpartition("=")
        name = name.strip() or metric
        if name not in GATED_METRICS:
            raise PbvolError(f"--fail-above {item}: unknown metric {name!r}; expected one of "
                             f"{', '.join(GATED_METRICS)}")
        try:
            bound = float(text)
        except ValueError:
            raise PbvolError(f"--fail-above {item}: expected METRIC=NUMBER or a number") from None
        if not math.isfinite(bound):
            raise PbvolError(f"--fail-above: expected a finite number, got {bound}")
        gates.append((name, bound))
    return gates


def _compared(path: Path, layer: str | None, channel: str | None):
    """The image of an EXR to compare: its RGB or a named layer, all channels or one (replicated to RGB)."""
    import numpy as np

    from pbvol_cli.imageio import read_exr, read_layers

    img = read_exr(path)[0]
    if layer is not None:
        layers = read_layers(path)
        if layer not in layers:
            raise PbvolError(f"{path}: no layer {layer!r}; it has {', '.join(sorted(layers)) or 'none'}")
        img = layers[layer]
    if channel is not None:
        k = "RGB".index(channel)
        img = np.repeat(img[..., k:k + 1], 3, axis=2)
    return img


@app.command()
def compare(
    image: Annotated[Path, typer.Argument(help="image to evaluate")],
    reference: Annotated[Path, typer.Argument(help="reference image")],
    diff: Annotated[Optional[Path], typer.Option(help="write a false-colour error image (PNG)")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="print the metrics as JSON")] = False,
    fail_above: Annotated[Optional[list[str]], typer.Option(
        help="METRIC=VALUE (mse, rel-mse, flip, pixels, pixels-percent; repeatable) or a bare VALUE for --metric: "
             "exit with status 2 when a metric exceeds its bound")] = None,
    metric: Annotated[str, typer.Option(help="what a bare --fail-above bounds: mse, or rel-mse (the relative MSE, "
                                        "(a - b)^2 / (b^2 + 0.01), which weighs dark and bright pixels alike)")]
    = "mse",
    pixel_threshold: Annotated[Optional[float], typer.Option(
        help="count the pixels differing by more than this in some channel (idiff's -fail; gate them with "
             "--fail-above pixels=N or pixels-percent=P)")] = None,
    layer: Annotated[Optional[str], typer.Option(help="compare this layer of both files (e.g. single, vpl)")] = None,
    channel: Annotated[Optional[str], typer.Option(help="compare one channel: R, G or B")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="print nothing: the exit status says whether "
                                        "--fail-above passed")] = False,
):
    """MSE, relative MSE, PSNR and FLIP of IMAGE against REFERENCE, overall and per channel. Exit status: 0 the
    images compare (within every --fail-above), 2 they differ beyond a bound, 1 they cannot be compared (missing
    or unreadable files, sizes or layers that differ, non-finite pixels, bad options)."""
    from pbvol_cli.pipeline.compare import error_image_png, format_report, image_metrics

    try:
        if metric not in GATED_METRICS:
            raise PbvolError(f"--metric: expected one of {', '.join(GATED_METRICS)}, got {metric!r}")
        gates = _gates(fail_above or [], metric)
        if channel is not None and channel not in ("R", "G", "B"):
            raise PbvolError(f"--channel: expected R, G or B, got {channel!r}")
        if pixel_threshold is not None and not (math.isfinite(pixel_threshold) and pixel_threshold >= 0):
            raise PbvolError(f"--pixel-threshold: expected a finite number >= 0, got {pixel_threshold}")
        if any(GATED_METRICS[n].startswith("pixels") for n, _ in gates) and pixel_threshold is None:
            raise PbvolError("--fail-above pixels...: give --pixel-threshold too")
        a = _compared(image, layer, channel)
        b = _compared(reference, layer, channel)
        try:
            m = image_metrics(a, b, pixel_threshold)
        except PbvolError as e:
            msg = str(e).replace(" A ", f" {image} ").replace(" B ", f" {reference} ")
            msg = msg.replace("A has", f"{image} has").replace("B has", f"{reference} has")
            raise PbvolError(msg) from None
        if diff is not None:
            error_image_png(a, b, diff)
    except PbvolError as e:
        _fail(e)
    if not quiet:
        typer.echo(json.dumps(m, allow_nan=False) if as_json else format_report(m, str(image), str(reference)))
    failed = [(n, m[GATED_METRICS[n]], bound) for n, bound in gates if m[GATED_METRICS[n]] > bound]
    for n, value, bound in failed:
        typer.echo(f"FAIL: {n} {value:.6g} exceeds {bound:g}", err=True)
    if failed:
        raise typer.Exit(EXIT_COMPARISON_FAILED)


@app.command()
def materials(quiet: Annotated[bool, typer.Option("--quiet", "-q", help="the names only")] = False):
    """List the material presets with their parameters and sources."""
    from pbvol_cli.config import load_material, materials_dir, preset_names

    try:
        names = preset_names()
        if not names:
            raise PbvolError(f"no material presets found in {materials_dir()}")
        for name in names:
            if quiet:
                typer.echo(name)
                continue
            m = load_material(materials_dir() / f"{name}.toml")
            sa, ss = m.coefficients(m.length_unit)
            st = sa + ss
            alb = [s / t if t > 0 else 0.0 for s, t in zip(ss, st)]
            unit = "scene unit" if m.length_unit == "scene" else m.length_unit
            typer.echo(f"{name}")
            typer.echo(f"    albedo {_fmt3(alb)}   mean free path {_fmt3(1 / st)} {unit}   g {m.g:g}   "
                       f"phase {m.phase}   eta {m.eta:g}")
            typer.echo(f"    sigma_a {_fmt3(sa)} /{unit}   sigma_s {_fmt3(ss)} /{unit}")
            typer.echo(f"    source: {m.source}")
    except PbvolError as e:
        _fail(e)


def _fmt3(v) -> str:
    return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"


@app.command()
def check(scene: SceneArg, as_json: JsonOpt = False,
          quiet: Annotated[bool, typer.Option("--quiet", "-q", help="print only the notes (the exit status "
                                              "says whether the scene is valid)")] = False):
    """Validate SCENE and summarise it: shapes, triangles, lights, media, mean free paths vs object size."""
    from pbvol_cli import config as C
    from pbvol_cli.pipeline.check import describe, summarize

    try:
        sc = C.load_scene(scene)
        if quiet and not as_json:
            for note in describe(sc, scene)["notes"]:
                typer.echo(f"note: {note}")
        else:
            typer.echo(json.dumps(describe(sc, scene)) if as_json else summarize(sc, scene))
    except PbvolError as e:
        _fail(e)


@app.command()
def schema(
    kind: Annotated[str, typer.Argument(help="scene or material")] = "scene",
    markdown: Annotated[bool, typer.Option("--markdown", help="print the field reference (docs/scene-format.md) "
                                           "instead")] = False,

    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="accepted like every command's (schema shows no "
                                        "progress)")] = False,
):
    """Print the JSON Schema of a scene file or a material file (every field, with its type, unit and default)."""
    from pbvol_cli.config_reference import SCHEMAS, json_schema, markdown_reference

    if kind not in SCHEMAS:
        _fail(PbvolError(f"schema: unknown kind {kind!r}; expected one of: {', '.join(SCHEMAS)}"))
    typer.echo(markdown_reference() if markdown else json.dumps(json_schema(kind), indent=2))


def main():  # pragma: no cover - console entry
    app()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(app())
