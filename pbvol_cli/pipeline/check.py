"""`pbvol check`: build a scene and describe it, so that a user sees what the renderer will see."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pbvol_cli import config as C
from pbvol_cli.geometry.scene_build import MED_SEALED
from pbvol_cli.multiple_scattering.extent import DEFAULT_EXTENT, light_spread, table_extents
from pbvol_cli.pointbased.flat_faces import medium_faces


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
        box = b.medium_box(k)
        obj = float(np.linalg.norm(box[1] - box[0])) if box is not None else float("nan")
        across = obj / mfp
        out["media"].append({"label": mi.label, "albedo": alb.tolist(), "mean_free_path": mfp.tolist(),
                             "g": mi.material.g, "phase": mi.material.phase, "sealed": bool(b.media[k, MED_SEALED]),
                             "object_size": obj, "mean_free_paths_across": across.tolist(),
                             "diffusion_poor": _diffusion_regime(b, k, box),
                             "pointbased_poor": pointbased_regime(b, k, box, extent),
                             "table_extent": table_extents(mi.sigma_a, mi.sigma_s, mi.material.g,
                                                           _smallest_side(box), extent).tolist(),
                             "marching_poor": _marching_regime(b, k, across,
                                                               scene.render.raymarch.shadows_through_dielectrics),
                             "density": _density_text(b, k),
                             "emission": list(mi.material.emission) if mi.material.emission is not None else None})
        if mi.material.density is not None or mi.material.emission is not None:
            out["notes"].append(f"{mi.label}: heterogeneous or emissive: --method volpath renders it, "
                                "--method raymarch approximates it (emission and single scattering), --method vpl "
                                "adds its multiple scattering; pbl and dipole take homogeneous, non-emissive media")
    out["notes"] += _reach_notes(scene, b)
    out["notes"] += _similarity_notes(scene, b)
    return out


def _similarity_notes(scene: C.Scene, b) -> list[str]:
    """What [render.pbl] similarity does to each medium: pbl's image is of the transformed one
    (pointbased/similarity.py), and a medium it cannot transform is rendered as given."""
    import math

    from pbvol_cli.physics.phase import TRUNCATION_COS, truncated_share
    from pbvol_cli.pointbased.similarity import TRUNCATED_MIN_G, delta_eddington_coefficients, transformed

    choice = scene.render.pbl.similarity
    if choice == "none":
        return []
    notes = []
    for mi in b.medium_info:
        g = mi.material.g
        if not transformed(mi.material.phase, g) or (choice == "truncated" and g < TRUNCATED_MIN_G):
            notes.append(f"{mi.label}: [render.pbl] similarity leaves it as given ({mi.material.phase}, g {g:g}): "
                         "only Henyey-Greenstein media of g > 0 have a forward peak to fold into the beams")
        elif choice == "delta-eddington":
            _, g2 = delta_eddington_coefficients(mi.sigma_s, g)
            notes.append(f"{mi.label}: pbl renders it as its delta-Eddington equivalent ([render.pbl] similarity: "
                         f"g {g:g} -> {g2:.3g}, sigma_s x {1.0 - g * g:.3g}; docs/pbl.md, section 2)")
        else:
            angle = math.degrees(math.acos(TRUNCATION_COS))
            notes.append(f"{mi.label}: pbl renders it with its lobe's forward peak (within {angle:.0f} degrees) "
                         f"taken as unscattered ([render.pbl] similarity: sigma_s x {truncated_share(g):.3g}, "
                         "the phase function exact beyond; docs/pbl.md, section 2)")
    return notes


DIFFUSION_THICKNESS = 10.0  # reduced mean free paths: a thinner body is far from the dipole's half-space
DIFFUSION_ALBEDO = 0.9  # reduced albedo below which diffusion is a poor model (docs/dipole.md)
POINTBASED_ALBEDO = DIFFUSION_ALBEDO  # reduced albedo above which a body diffuses (pointbased_regime)
FLAT_REFLECTING_DIFFUSION_LENGTHS = 2.5  # half-thickness in diffusion lengths beyond which a body with flat faces
# behind a reflecting boundary reads low over a few passes (its bounced light heavy-tailed from one set of samples to
# the next): grey boxes of albedo 0.999 behind eta 1.5 read 1.02 of volpath's scattered light at 1.6, 0.85 at 3.3,
# 0.77 at 6.6 with 8 passes (1.03 and 0.88 at 32; index-matched 1.00, 0.98, 0.97; docs/pbl.md, section 7)
POINTBASED_DIFFUSION_LENGTHS = 7.0  # half-thickness in diffusion lengths 1/sigma_tr beyond which pbl reads low:
# grey spheres behind eta 1.5 read 0.99 of volpath's scattered light at 3.3, 0.96 at 6.6, 0.85 at 10.4 (albedo
# 0.99); the marble sphere 0.92 in blue at 7.6 (docs/pbl.md, section 11)


def _density_text(b, k: int) -> str:
    """How medium k's density varies, in words ("homogeneous" where it does not)."""
    from pbvol_cli.geometry.scene_build import GRID_DIMS, MED_FIELD, MED_MAJORANT

    dens = b.medium_info[k].material.density
    if dens is None:
        return "homogeneous"
    if dens.type == "grid":
        dims = "x".join(str(int(v)) for v in b.media[k, MED_FIELD + GRID_DIMS:MED_FIELD + GRID_DIMS + 3])
        return f"grid {dims} voxels from {dens.file}, majorant sigma_t {b.media[k, MED_MAJORANT]:.3g}"
    return (f"exponential {dens.a:g} e^(-{dens.b:g} h) along {list(dens.up)}, majorant sigma_t "
            f"{b.media[k, MED_MAJORANT]:.3g}")


def reduced_thickness(b, k: int, box=None) -> tuple[np.ndarray, np.ndarray] | None:
    """Medium k's body per channel: (its smallest side in reduced mean free paths 1/sigma'_t, its reduced albedo
    sigma'_s / sigma'_t), sigma'_s = (1 - g) sigma_s; None for a heterogeneous or emissive medium (neither the
    dipole nor pbl takes it: check's note says so), without a bounding box or without extinction. box: the body's
    bounding box (None: found here)."""
    mi = b.medium_info[k]
    box = b.medium_box(k) if box is None else box
    if mi.material.density is not None or mi.material.emission is not None:
        return None
    sp = (1.0 - mi.material.g) * mi.sigma_s
    tp = mi.sigma_a + sp
    if box is None or not np.any(tp > 0):
        return None
    return _smallest_side(box) * tp, np.where(tp > 0, sp / np.maximum(tp, 1e-300), 1.0)


def _smallest_side(box) -> float | None:
    """The smallest side of a (lo, hi) box (None: no box)."""
    return None if box is None else float(np.min(box[1] - box[0]))


def _diffusion_regime(b, k: int, box) -> str:
    """Whether the dipole's diffusion (--method dipole) suits medium k: "" where it does, else why not (its body
    thin in reduced mean free paths 1/sigma'_t, so light crosses it rather than diffusing back out, or its reduced
    albedo low)."""
    reduced = reduced_thickness(b, k, box)
    if reduced is None:
        return ""
    thickness, albedo = reduced
    thin = float(np.min(thickness[thickness > 0]))
    why = []
    if thin < DIFFUSION_THICKNESS:
        why.append(f"only {thin:.2g} reduced mean free paths thick")
    if float(np.min(albedo)) < DIFFUSION_ALBEDO:
        why.append(f"reduced albedo {float(np.min(albedo)):.2g}")
    return ", ".join(why)


def pointbased_regime(b, k: int, box=None, extent: float | str = "auto") -> str:
    """Whether the point-based method (--method pbl) renders medium k's scattered light in full: "" where it does,
    else why not and what to use instead. In a channel of reduced albedo above POINTBASED_ALBEDO, pbl reads low
    (benchmarks/pbl_thickness.py, docs/pbl.md section 11) where half the body's smallest side is more than
    POINTBASED_DIFFUSION_LENGTHS diffusion lengths (the multiple term's images, image_planes.py, fitted up to about
    7), where flat faces bound a body more than FLAT_REFLECTING_DIFFUSION_LENGTHS thick behind a reflecting boundary
    (its bounced light reads low under them), or where light spreads over more mean free paths than the
    multiple-scattering table holds: the smaller of extent.TABLE_REACH diffusion lengths and the body's side, beyond
    the table's extent (`extent`: [render.lut] extent, a number of mean free paths or "auto", which reaches as far
    up to extent.AUTO_EXTENT_MAX). box: the body's bounding box (None: found here)."""
    reduced = reduced_thickness(b, k, box)
    if reduced is None:
        return ""
    thickness, albedo = reduced
    diffusing = albedo > POINTBASED_ALBEDO
    if not np.any(diffusing):
        return ""
    mi = b.medium_info[k]
    transport = mi.sigma_a + (1.0 - mi.material.g) * mi.sigma_s
    lengths = np.sqrt(3.0 * mi.sigma_a / np.maximum(transport, 1e-300)) * thickness  # 2 R sigma_tr
    half = float(np.max(0.5 * lengths[diffusing]))
    if half > POINTBASED_DIFFUSION_LENGTHS:
        instead = "--method dipole suits it" if _diffusion_regime(b, k, box) == "" else "volpath renders it"
        return (f"half its thickness is {half:.2g} diffusion lengths (reduced albedo "
                f"{float(np.max(albedo[diffusing])):.3g}): pbl's multiple scattering reads low in a body this thick "
                f"(docs/pbl.md, section 11); {instead}")
    side = _smallest_side(box) if box is not None else b.medium_side(k)
    if half > FLAT_REFLECTING_DIFFUSION_LENGTHS and len(medium_faces(b, k)) and b.reflects_into(k):
        instead = "--method dipole suits it" if _diffusion_regime(b, k, box) == "" else "volpath renders it"
        return (f"flat faces behind a reflecting boundary, half its thickness {half:.2g} diffusion lengths: pbl's "
                "bounced light is heavy-tailed under them and reads low over a few passes (a grey box 120 reduced "
                "mean free paths thick behind eta 1.5: 0.85 of volpath's scattered light at 8 passes, 1.03 at 32; "
                f"docs/pbl.md, section 7); {instead}")
    spread = light_spread(mi.sigma_a, mi.sigma_s, mi.material.g, side)
    held = table_extents(mi.sigma_a, mi.sigma_s, mi.material.g, side, extent)
    short = diffusing & (spread > held)
    if np.any(short):
        reach = float(np.max(spread[short]))
        return (f"light spreads over about {reach:.3g} mean free paths, beyond the multiple-scattering table's "
                f"{float(np.min(held[short])):g}: pbl reads low (docs/pbl.md, section 11); set [render.lut] "
                f"extent = {np.ceil(reach):.0f}")
    return ""


MARCHING_DENSE = 20.0  # mean free paths across: a denser high-albedo body makes the VPLs spike (docs/vpl.md)
MARCHING_ALBEDO = 0.9


def _marching_regime(b, k: int, across, through_dielectrics: bool) -> str:
    """Whether the marching methods (--method raymarch, vpl) suit medium k: "" where they do, else why not: sealed
    behind refracting boundaries (their shadow rays do not refract: no single scattering from the lights), or
    dense with a high albedo (the VPLs, clamped at half a mean free path, spike; the ray marcher misses most of
    the light, which scatters many times)."""
    mi = b.medium_info[k]
    why = []
    if b.media[k, MED_SEALED] and not through_dielectrics:
        why.append("sealed behind refracting boundaries: no single scattering from the lights unless "
                   "[render.raymarch] shadows_through_dielectrics (flat glass only)")
    st = mi.sigma_a + mi.sigma_s
    albedo = float(np.max(np.where(st > 0, mi.sigma_s / np.maximum(st, 1e-300), 0.0)))
    thick = float(np.max(np.where(np.isfinite(across), across, 0.0)))
    if thick > MARCHING_DENSE and albedo > MARCHING_ALBEDO:
        why.append(f"{thick:.3g} mean free paths across with albedo {albedo:.2g}: multiple scattering dominates "
                   "and the VPLs spike")
    return "; ".join(why)


SMALL_LIGHT_SR = 0.01  # a light subtending less than this from a sealed medium is found by volpath only by chance


def _reach_notes(scene: C.Scene, b) -> list[str]:
    """The lights a path tracer cannot bring into a sealed medium (behind refracting boundaries only, so no shadow
    ray reaches a light from inside): delta lights, which volpath renders none of there, and small lights, which
    its paths hit only by chance. pbl refracts the light in from the light's side, so it reaches both."""
    notes = []
    sealed = [k for k in range(len(b.medium_info)) if b.media[k, MED_SEALED]]
    for i, L in enumerate(scene.lights):
        if L.type in ("point", "directional"):
            if sealed and np.max(getattr(L, "intensity", getattr(L, "irradiance", 0.0))) > 0:
                names = ", ".join(b.medium_info[k].label for k in sealed)
                notes.append(f"lights[{i}] ({L.type}) is a delta light: volpath renders none of its light inside "
                             f"{names} (sealed behind a refracting boundary) nor its caustics; pbl does "
                             "(--method pbl)")
            continue
        for k in sealed:
            box = b.medium_box(k)
            omega = _solid_angle(L, 0.5 * (box[0] + box[1])) if box is not None else None
            if omega is not None and omega < SMALL_LIGHT_SR:
                notes.append(f"lights[{i}] ({L.type}) subtends {omega:.2g} sr from {b.medium_info[k].label}, which "
                             "is sealed behind a refracting boundary: volpath's paths reach it only by chance "
                             "(slow to converge); pbl is made for this (--method pbl)")
    return notes


def _solid_angle(light, point: np.ndarray) -> float | None:
    """Solid angle (sr) a sphere or quad light subtends from point (a quad's: its projected area over the squared
    distance, for a far light); None for the sky or a point inside the light."""
    if light.type == "sphere":
        d = float(np.linalg.norm(np.asarray(light.center) - point))
        if d <= light.radius:
            return None
        return 2.0 * np.pi * (1.0 - np.sqrt(1.0 - (light.radius / d) ** 2))
    if light.type == "quad":
        e1, e2 = np.asarray(light.edge1, float), np.asarray(light.edge2, float)
        centre = np.asarray(light.corner, float) + 0.5 * (e1 + e2)
        to = point - centre
        d2 = float(to @ to)
        n = np.cross(e1, e2)
        return None if d2 == 0 else min(2.0 * np.pi, abs(float(n @ to)) / d2 ** 1.5)
    return None


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
        if any(e != DEFAULT_EXTENT for e in m["table_extent"]):
            ext = m["table_extent"]
            lines.append(f"      multiple-scattering table: {ext[0]:g} mean free paths in half" if len(set(ext)) == 1
                         else f"      multiple-scattering tables: {_f(ext)} mean free paths in half")
        if m["density"] != "homogeneous" or m["emission"]:
            lines.append(f"      density: {m['density']}" + (f"; emission {_f(m['emission'])}" if m["emission"]
                                                               else ""))
        if m["diffusion_poor"]:
            lines.append(f"      dipole: far from its thick, high-albedo regime ({m['diffusion_poor']})")
        if m["pointbased_poor"]:
            lines.append(f"      pbl: {m['pointbased_poor']}")
        if m["marching_poor"]:
            better = ("volpath" if m["density"] != "homogeneous" or m["emission"] else
                      "dipole" if "dipole suits" in m["pointbased_poor"] else "pbl (or dipole)")
            lines.append(f"      raymarch, vpl: far from their regime ({m['marching_poor']}); {better} suits it "
                         "better")
    lines += [f"  note: {n}" for n in d["notes"]]
    return "\n".join(lines)


def _medium_label(ref) -> str | None:
    """A shape's medium reference as the user wrote it (an inline table: its name, else "inline")."""
    if ref is None:
        return None
    return ref if isinstance(ref, str) else (ref.name or "inline")


def _f(v) -> str:
    return "[" + ", ".join(f"{x:.3g}" for x in v) + "]"
