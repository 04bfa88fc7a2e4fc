"""`pbvol precompute-lut`: the tables of every medium of a material or scene file."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pbvol_cli import config as C
from pbvol_cli.multiple_scattering.table import TableSettings
from pbvol_cli.physics.phase import KINDS, mean_cosine


@dataclass
class MediumTables:
    """A medium's tables as precompute-lut builds them: groups of (albedo, RGB channels, settings)."""

    label: str
    g: float
    phase: str
    groups: list[tuple[float, list[int], TableSettings]]


def media_of_file(path: Path, particles: int | None, seed: int | None) -> list[MediumTables]:
    """The tables of a scene file's media, as a pbl render reads them (after [render.pbl] similarity, each table as
    wide as its body needs: pipeline/lut.table_groups), or of a material file (no body: the default extent)."""
    from pbvol_cli.geometry.scene_build import MED_G, MED_PHASE, build_scene
    from pbvol_cli.pipeline.lut import table_groups
    from pbvol_cli.pipeline.render import pbl_media
    from pbvol_cli.pointbased.similarity import NAMES

    data = C.read_toml(path)
    if "camera" in data or "shapes" in data:
        scene = C.load_scene(path)
        built = pbl_media(build_scene(scene, path), scene.render.pbl, "pbl")
        names = {v: k for k, v in KINDS.items()}
        out = []
        for m, info in enumerate(built.medium_info):
            kind, g, mat = int(built.media[m, MED_PHASE]), float(built.media[m, MED_G]), info.material
            changed = kind != KINDS[mat.phase] or g != mat.g  # (by [render.pbl] similarity)
            label = info.label + (f" ({NAMES[scene.render.pbl.similarity]})" if changed else "")
            out.append(MediumTables(label, g, names[kind], table_groups(*built.medium_sigmas(m),
                                                                        mean_cosine(kind, g), built.medium_side(m),
                                                                        scene.render.lut, particles, seed)))
        return out
    mat = C.load_material(path)
    sigma_a, sigma_s = mat.coefficients(mat.length_unit)
    return [MediumTables(mat.name or path.stem, mat.g, mat.phase,
                         table_groups(sigma_a, sigma_s, mat.g, None, C.LutSettings(), particles, seed))]


def precompute(path: Path, cache: Path, particles: int | None, seed: int | None, force: bool, quiet: bool,
               echo) -> list[dict]:
    """Build or reuse every table; echo(line) reports each. Returns one record per table."""
    from pbvol_cli.pipeline.lut import get_table
    from pbvol_cli.pipeline.progress import progress_bar

    media = media_of_file(path, particles, seed)
    if not media:
        echo(f"{path}: no participating media: nothing to precompute")
        return []
    records = []
    for m in media:
        kind = KINDS[m.phase]
        for alpha, channels, settings in m.groups:
            names = "".join("RGB"[c] for c in channels)
            label = f"{m.label} {names} (albedo {alpha:.6g}, g {m.g:g}, {m.phase})"
            prog, update = progress_bar(quiet, label, "particles")
            with prog:
                r = get_table(alpha, m.g, kind, settings, cache, force, update)
            size = r.path.stat().st_size
            met = r.table.metrics
            what = "reused cached table" if r.reused else f"built in {r.seconds:.1f} s"
            extent = settings.layout.extent
            echo(f"{label}: {what}; {extent:g} mean free paths in half, {met['particles']} particles, "
                 f"{met['leaves']} quadtree leaves, {size / 1e6:.2f} MB, compact vs dense error "
                 f"{100 * met['err_compact_vs_dense_99']:.1f}% (99% energy cells) -> {r.path}")
            records.append({"medium": m.label, "channels": names, "alpha": alpha, "g": m.g, "extent": extent,
                            "reused": r.reused, "seconds": r.seconds, "bytes": size, "path": str(r.path), **met})
    return records
