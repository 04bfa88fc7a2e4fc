"""`pbvol check`: build a scene and describe it, so that a user sees what the renderer will see."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pbvol_cli import config as C
from pbvol_cli.geometry.scene_build import MED_SEALED, SPH_SURFACE, sphere_bounds


def describe(scene: C.Scene, path: Path) -> dict:
    """What the renderer will see, as data (`check --json`): camera, shapes, lights, media with their mean free
    paths against their object's size, and notes on what may not render as the user expects."""
    from pbvol_cli.geometry.scene_build import build_scene

    b = build_scene(scene, path)
    out = {"file": str(path), "unit": scene.unit, "resolution": list(scene.camera.resolution),
           "fov_deg": scene.camera.fov, "spp": scene.render.spp, "max_depth": scene.render.max_depth,
           "seed": scene.render.seed, "triangles": int(len(b.faces)), "analytic_spheres": int(len(b.spheres)),
           "scene_diagonal": float(np.linalg.norm(b.bbox[1] - b.bbox[0])), "shapes": [], "lights": [],
           "media": [], "notes": []}
    for (name, tris), shape in zip(b.shape_triangles, scene.shapes):
        out["shapes"].append({"name": name, "type": shape.type, "interface": shape.interface, "eta": shape.eta,
                              "medium": _medium_label(shape.medium),
                              "liquid": _medium_label(getattr(shape, "liquid", None)), "triangles": int(tris)})
    out["lights"] = [L.type for L in scene.lights]
    extent = scene.render.lut.extent
    for k, mi in enumerate(b.medium_info):
        st = mi.sigma_a + mi.sigma_s
        mfp = np.where(st > 0, 1.0 / np.maximum(st, 1e-300), np.inf)
        alb = np.where(st > 0, mi.sigma_s / np.maximum(st, 1e-300), 0.0)
        obj = _medium_size(b, k)
        across = obj / mfp
        out["media"].append({"label": mi.label, "albedo": alb.tolist(), "mean_free_path": mfp.tolist(),
                             "g": mi.material.g, "phase": mi.material.phase, "sealed": bool(b.media[k, MED_SEALED]),
                             "object_size": obj, "mean_free_paths_across": across.tolist()})
        if np.nanmax(across) > 2.0 * extent:
            out["notes"].append(f"{mi.label}: {np.nanmax(across):.3g} mean free paths across, beyond the "
                                f"multiple-scattering table's {2.0 * extent:g} ([render.lut] extent {extent:g}): pbl "
                                "loses the light that diffuses farther (docs/pbl.md)")
    if not any(L.type in ("sphere", "quad", "environment") for L in scene.lights):
        out["notes"].append("only delta lights: volpath cannot reach them through a refracting boundary (pbl can)")
    return out


def summarize(scene: C.Scene, path: Path) -> str:
    """describe() as the text `check` prints."""
    d = describe(scene, path)
    W, H = d["resolution"]
    lines = [f"{path}: OK", f"  unit: {d['unit']}; camera {W}x{H}, fov {d['fov_deg']:g} deg; "
             f"render {d['spp']} spp, max depth {d['max_depth']}, seed {d['seed']}",
             f"  shapes: {len(d['shapes'])} ({d['triangles']} triangles, {d['analytic_spheres']} analytic spheres)"]
    for sh in d["shapes"]:
        extra = f", liquid {sh['liquid']}" if sh["liquid"] else ""
        eta = f", eta {sh['eta']:g}" if sh["eta"] is not None else ""
        lines.append(f"    {sh['name']}: {sh['type']}, {sh['interface']}{eta}, medium {sh['medium'] or '-'}{extra}"
                     + (f", {sh['triangles']} triangles" if sh["triangles"] else " (analytic)"))
    lines.append(f"  lights: {len(d['lights'])}")
    lines += [f"    {t}" for t in d["lights"]]
    lines.append(f"  media: {len(d['media'])} (scene diagonal {d['scene_diagonal']:.4g} {d['unit']})")
    for m in d["media"]:
        lines.append(f"    {m['label']}: albedo {_f(m['albedo'])}, mean free path {_f(m['mean_free_path'])} "
                     f"{d['unit']}, g {m['g']:g}, phase {m['phase']}"
                     + (", sealed (no light reaches it directly)" if m["sealed"] else ""))
        lines.append(f"      object size {m['object_size']:.4g} = {_f(m['mean_free_paths_across'])} mean free paths")
    lines += [f"  note: {n}" for n in d["notes"]]
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
