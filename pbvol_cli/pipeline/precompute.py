"""`pbvol precompute-lut`: the tables of every medium of a material or scene file."""

from __future__ import annotations

from pathlib import Path


from pbvol_cli import config as C
from pbvol_cli.geometry.scene_build import MediumInfo
from pbvol_cli.physics.phase import KINDS
from pbvol_cli.pointbased.similarity import delta_eddington_coefficients, transformed


def media_of_file(path: Path) -> tuple[list[MediumInfo], C.LutSettings]:
    """The media of a scene file (every distinct one) or of a material file, with the table settings to use."""
    data = C.read_toml(path)
    if "camera" in data or "shapes" in data:
        scene = C.load_scene(path)
        media = [MediumInfo(label, mat, *mat.coefficients(scene.unit)) for label, mat in C.scene_media(scene, path)]
        if scene.render.pbl.similarity == "delta-eddington":  # the tables pbl renders this scene with
            media = [_delta_eddington(m) for m in media]
        return media, scene.render.lut
    mat = C.load_material(path)
    return [MediumInfo(mat.name or path.stem, mat, *mat.coefficients(mat.length_unit))], C.LutSettings()


def _delta_eddington(m: MediumInfo) -> MediumInfo:
    """m as [render.pbl] similarity = "delta-eddington" renders it (pointbased/similarity.py)."""
    if not transformed(m.material.phase, m.material.g):
        return m
    sigma_s, g = delta_eddington_coefficients(m.sigma_s, m.material.g)
    return MediumInfo(f"{m.label} (delta-Eddington)", m.material.model_copy(update={"g": g}), m.sigma_a, sigma_s)


def precompute(path: Path, cache: Path, particles: int | None, seed: int | None, force: bool, quiet: bool,
               echo) -> list[dict]:
    """Build or reuse every table; echo(line) reports each. Returns one record per table."""
    from pbvol_cli.pipeline.lut import channel_tables, get_table, table_settings
    from pbvol_cli.pipeline.progress import progress_bar

    media, lut = media_of_file(path)
    if not media:
        echo(f"{path}: no participating media: nothing to precompute")
        return []
    settings = table_settings(lut, particles, seed)
    records = []
    for m in media:
        kind = KINDS[m.material.phase]
        for alpha, channels in channel_tables(m.sigma_a, m.sigma_s):
            names = "".join("RGB"[c] for c in channels)
            label = f"{m.label} {names} (albedo {alpha:.6g}, g {m.material.g:g}, {m.material.phase})"
            prog, update = progress_bar(quiet, label, "particles")
            with prog:
                r = get_table(alpha, m.material.g, kind, settings, cache, force, update)
            size = r.path.stat().st_size
            met = r.table.metrics
            what = "reused cached table" if r.reused else f"built in {r.seconds:.1f} s"
            echo(f"{label}: {what}; {met['particles']} particles, {met['leaves']} quadtree leaves, "
                 f"{size / 1e6:.2f} MB, compact vs dense error {100 * met['err_compact_vs_dense_99']:.1f}% "
                 f"(99% energy cells) -> {r.path}")
            records.append({"medium": m.label, "channels": names, "alpha": alpha, "g": m.material.g,
                            "reused": r.reused, "seconds": r.seconds, "bytes": size, "path": str(r.path), **met})
    return records
