"""`pbvol check`: build a scene and describe it, so that a user sees what the renderer will see."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pbvol_cli import config as C
from pbvol_cli.geometry.scene_build import MED_SEALED, SPH_SURFACE, sphere_bounds


def summarize(scene: C.Scene, path: Path) -> str:
    from pbvol_cli.geometry.scene_build import build_scene

    b = build_scene(scene, path)
    W, H = scene.camera.resolution
    lines = [f"{path}: OK", f"  unit: {scene.unit}; camera {W}x{H}, fov {scene.camera.fov:g} deg; "
             f"render {scene.render.spp} spp, max depth {scene.render.max_depth}, seed {scene.render.seed}"]
    ntri = int(len(b.faces))
    lines.append(f"  shapes: {len(scene.shapes)} ({ntri} triangles, {len(b.spheres)} analytic spheres)")
    for (name, tris), shape in zip(b.shape_triangles, scene.shapes):
        med = _medium_label(shape.medium) or "-"
        extra = f", liquid {_medium_label(shape.liquid)}" if getattr(shape, "liquid", None) else ""
        eta = f", eta {shape.eta:g}" if shape.eta is not None else ""
        lines.append(f"    {name}: {shape.type}, {shape.interface}{eta}, medium {med}{extra}"
                     + (f", {tris} triangles" if tris else " (analytic)"))
    lines.append(f"  lights: {len(scene.lights)}")
    for L in scene.lights:
        lines.append(f"    {L.type}")
    size = float(np.linalg.norm(b.bbox[1] - b.bbox[0]))
    lines.append(f"  media: {len(b.medium_info)} (scene diagonal {size:.4g} {scene.unit})")
    for k, mi in enumerate(b.medium_info):
        st = mi.sigma_a + mi.sigma_s
        mfp = np.where(st > 0, 1.0 / np.maximum(st, 1e-300), np.inf)
        alb = np.where(st > 0, mi.sigma_s / np.maximum(st, 1e-300), 0.0)
        obj = _medium_size(b, k)
        ratio = obj / mfp
        lines.append(f"    {mi.label}: albedo {_f(alb)}, mean free path {_f(mfp)} {scene.unit}, g {mi.material.g:g}, "
                     f"phase {mi.material.phase}"
                     + (", sealed (no light reaches it directly)" if b.media[k, MED_SEALED] else ""))
        lines.append(f"      object size {obj:.4g} = {_f(ratio)} mean free paths")
    if not any(L.type in ("sphere", "quad", "environment") for L in scene.lights):
        lines.append("  note: only delta lights: volpath cannot reach them through a refracting boundary")
    return "\n".join(lines)


def _medium_label(ref) -> str | None:
    """A shape's medium reference as the user wrote it (an inline table: its name, else "inline")."""
    if ref is None:
        return None
    return ref if isinstance(ref, str) else (ref.name or "inline")


def _medium_size(b, k: int) -> float:
    """Diameter of the bounding box of the surfaces that bound medium k."""
    surf = np.flatnonzero(b.surfaces_bounding(k))
    pts = []
    if len(b.faces):
        tri = np.isin(b.tri_surface, surf)
        if tri.any():
            pts.append(b.vertices[b.faces[tri]].reshape(-1, 3).astype(float))
    for s in b.spheres:
        if int(s[SPH_SURFACE]) in surf:
            pts.append(sphere_bounds(s))
    if not pts:
        return float("nan")
    p = np.concatenate(pts)
    return float(np.linalg.norm(p.max(0) - p.min(0)))


def _f(v) -> str:
    return "[" + ", ".join(f"{x:.3g}" for x in v) + "]"
