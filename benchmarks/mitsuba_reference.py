#!/usr/bin/env python3
"""Mitsuba 3 reference renderer: a speed and correctness anchor for pbvol.

Run it with the *Mitsuba* interpreter (a separate venv, not pbvol's), e.g.::

    /work/mitsuba-venv/bin/python benchmarks/mitsuba_reference.py \\
        --scene wax_sphere --spp 64 --threads 2 --out /tmp/wax.exr --json

This script deliberately does not import pbvol.  The scene is either a built-in
(``--scene wax_sphere``) or a small JSON description given with
``--scene-json`` (inline JSON text, or a path to a .json file).  ``--dump-scene``
prints the resolved description, which is the schema below::

    {
      "camera": {"origin": [x,y,z], "target": [x,y,z], "up": [x,y,z],
                 "fov": deg, "fov_axis": "y", "resolution": [W, H]},
      "objects": [{"shape": "sphere", "center": [x,y,z], "radius": r,
                   "bsdf": {"type": "dielectric", "int_ior": n, "ext_ior": n}
                           | {"type": "null"},
                   "interior": {"type": "homogeneous", "albedo": [r,g,b],
                                "sigma_t": [r,g,b], "scale": s,
                                "phase": {"type": "hg", "g": g}
                                         | {"type": "isotropic"}}}],
      "lights": [{"type": "sphere", "center": [x,y,z], "radius": r,
                  "radiance": [r,g,b]}],
      "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 8}
    }

Timing: the scene is first rendered once at 1 spp (JIT compilation warm-up,
not timed); the main render is then timed up to and including conversion of
the result to a NumPy array, so all kernel work has completed.

Mitsuba conventions worth knowing when comparing with pbvol:
  * ``rr_depth``: Russian roulette runs at the top of each path-loop iteration
    when ``depth > rr_depth`` (strictly), where depth counts scattering
    vertices (medium scatters and non-null surface interactions).  The
    survival probability is ``min(max(throughput) * eta^2, 0.95)``.
  * volpath/volpathmis cannot do next-event estimation through a smooth
    ``dielectric`` boundary (its null transmission is 0), so inside the wax
    sphere light arrives only from phase-sampled paths that happen to refract
    out and hit the small light: expect very sparse, slowly converging images.
  * The image's +x is world +x for this camera (look_at builds a frame whose
    "left" is -x), +y is up.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import sys
import time

# Dr.Jit's LLVM backend needs a recent libLLVM (Debian bookworm's 14/15 crash
# it); prefer libllvm19's library unless the caller already chose one.
_LLVM19_CANDIDATES = (
    "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1",
    "/usr/lib/x86_64-linux-gnu/libLLVM-19.so",
    "/usr/lib/aarch64-linux-gnu/libLLVM.so.19.1",
    "/usr/lib/aarch64-linux-gnu/libLLVM-19.so",
)
if "DRJIT_LIBLLVM_PATH" not in os.environ:
    for _cand in _LLVM19_CANDIDATES:
        if os.path.exists(_cand):
            os.environ["DRJIT_LIBLLVM_PATH"] = _cand
            break

WAX_SPHERE = {
    "camera": {
        "origin": [0.0, 0.0, 20.0],
        "target": [0.0, 0.0, 0.0],
        "up": [0.0, 1.0, 0.0],
        "fov": 30.0,
        "fov_axis": "y",
        "resolution": [256, 256],
    },
    "objects": [
        {
            "shape": "sphere",
            "center": [0.0, 0.0, 0.0],
            "radius": 5.0,
            "bsdf": {"type": "dielectric", "int_ior": 1.44, "ext_ior": 1.0},
            "interior": {
                "type": "homogeneous",
                "albedo": [0.9803, 0.9615, 0.7500],
                "sigma_t": [1.0 / 0.6536, 1.0 / 0.6250, 1.0 / 0.5882],
                "scale": 1.0,
                "phase": {"type": "hg", "g": 0.8},
            },
        }
    ],
    "lights": [
        {
            "type": "sphere",
            "center": [10.0, 10.0, 10.0],
            "radius": 0.5,
            "radiance": [400.0, 400.0, 400.0],
        }
    ],
    "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 8},
}

BUILTIN_SCENES = {"wax_sphere": WAX_SPHERE}


def _rgb(v, unbounded=False):
    if isinstance(v, (int, float)):
        v = [v, v, v]
    if unbounded:
        # The 'rgb' shorthand is a reflectance and rejects components > 1;
        # the underlying 'srgb' plugin accepts them with unbounded=True.
        return {"type": "srgb", "color": [float(c) for c in v], "unbounded": True}
    return {"type": "rgb", "value": [float(c) for c in v]}


def _phase(desc):
    kind = (desc or {"type": "isotropic"}).get("type", "isotropic")
    if kind == "hg":
        return {"type": "hg", "g": float(desc.get("g", 0.0))}
    if kind == "isotropic":
        return {"type": "isotropic"}
    raise ValueError(f"unsupported phase function {kind!r}")


def _medium(desc):
    if desc.get("type", "homogeneous") != "homogeneous":
        raise ValueError(f"unsupported medium {desc.get('type')!r}")
    return {
        "type": "homogeneous",
        "albedo": _rgb(desc["albedo"]),
        "sigma_t": _rgb(desc["sigma_t"], unbounded=True),
        "scale": float(desc.get("scale", 1.0)),
        "phase": _phase(desc.get("phase")),
    }


def _bsdf(desc):
    kind = desc.get("type", "null")
    if kind == "dielectric":
        return {
            "type": "dielectric",
            "int_ior": float(desc.get("int_ior", 1.5046)),
            "ext_ior": float(desc.get("ext_ior", 1.0)),
        }
    if kind == "null":
        return {"type": "null"}
    if kind == "diffuse":
        return {"type": "diffuse", "reflectance": _rgb(desc.get("reflectance", 0.5))}
    raise ValueError(f"unsupported bsdf {kind!r}")


def to_mitsuba_dict(mi, desc, spp, integrator_type=None):
    """Translate the small JSON description into a Mitsuba scene dict."""
    cam = desc["camera"]
    w, h = cam["resolution"]
    integ = dict(desc.get("integrator", {}))
    itype = integrator_type or integ.get("type", "volpath")
    scene = {
        "type": "scene",
        "integrator": {
            "type": itype,
            "max_depth": int(integ.get("max_depth", -1)),
            "rr_depth": int(integ.get("rr_depth", 5)),
        },
        "sensor": {
            "type": "perspective",
            "fov": float(cam["fov"]),
            "fov_axis": cam.get("fov_axis", "y"),
            "to_world": mi.ScalarTransform4f().look_at(
                origin=cam["origin"], target=cam["target"], up=cam["up"]
            ),
            "sampler": {"type": "independent", "sample_count": int(spp)},
            "film": {
                "type": "hdrfilm",
                "width": int(w),
                "height": int(h),
                "pixel_format": "rgb",
                "component_format": "float32",
                "rfilter": {"type": "box"},
            },
        },
    }
    for i, obj in enumerate(desc.get("objects", [])):
        if obj.get("shape") != "sphere":
            raise ValueError(f"unsupported shape {obj.get('shape')!r}")
        shape = {
            "type": "sphere",
            "center": [float(c) for c in obj["center"]],
            "radius": float(obj["radius"]),
            "bsdf": _bsdf(obj.get("bsdf", {"type": "null"})),
        }
        if obj.get("interior"):
            shape["interior"] = _medium(obj["interior"])
        if obj.get("exterior"):
            shape["exterior"] = _medium(obj["exterior"])
        scene[f"object_{i}"] = shape
    for i, light in enumerate(desc.get("lights", [])):
        if light.get("type") != "sphere":
            raise ValueError(f"unsupported light {light.get('type')!r}")
        scene[f"light_{i}"] = {
            "type": "sphere",
            "center": [float(c) for c in light["center"]],
            "radius": float(light["radius"]),
            # A black BSDF: the light sphere should only emit.
            "bsdf": {"type": "diffuse", "reflectance": _rgb(0.0)},
            "emitter": {"type": "area", "radiance": _rgb(light["radiance"])},
        }
    return scene


def load_description(args):
    if args.scene_json:
        text = args.scene_json
        if os.path.exists(text):
            with open(text) as f:
                text = f.read()
        desc = json.loads(text)
    else:
        desc = copy.deepcopy(BUILTIN_SCENES[args.scene])
    if args.resolution:
        desc["camera"]["resolution"] = list(args.resolution)
    if args.max_depth is not None:
        desc.setdefault("integrator", {})["max_depth"] = args.max_depth
    if args.rr_depth is not None:
        desc.setdefault("integrator", {})["rr_depth"] = args.rr_depth
    if args.integrator:
        desc.setdefault("integrator", {})["type"] = args.integrator
    return desc


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default="wax_sphere", choices=sorted(BUILTIN_SCENES))
    p.add_argument("--scene-json", help="JSON description (text or file path); overrides --scene")
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--resolution", type=int, nargs=2, metavar=("W", "H"))
    p.add_argument("--integrator", choices=["volpath", "volpathmis"])
    p.add_argument("--max-depth", type=int, help="override max_depth (-1 = unbounded)")
    p.add_argument("--rr-depth", type=int, help="override rr_depth")
    p.add_argument("--threads", type=int, help="Dr.Jit worker threads (default: all cores)")
    p.add_argument("--variant", default="llvm_ad_rgb")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-warmup", action="store_true", help="skip the 1-spp JIT warm-up render")
    p.add_argument("--out", help="output EXR path")
    p.add_argument("--json", action="store_true", help="print the timing summary as JSON")
    p.add_argument("--dump-scene", action="store_true",
                   help="print the resolved JSON description and exit")
    args = p.parse_args(argv)

    desc = load_description(args)
    if args.dump_scene:
        print(json.dumps(desc, indent=2))
        return 0
    if args.spp < 1:
        p.error("--spp must be >= 1")

    import drjit as dr
    import mitsuba as mi
    import numpy as np

    mi.set_variant(args.variant)
    if args.threads:
        dr.set_thread_count(args.threads)

    itype = desc.get("integrator", {}).get("type", "volpath")
    w, h = desc["camera"]["resolution"]
    scene = mi.load_dict(to_mitsuba_dict(mi, desc, args.spp, itype))

    warmup_s = None
    if not args.no_warmup:
        t0 = time.perf_counter()
        warm = mi.render(scene, spp=1, seed=args.seed + 1_000_003)
        np.asarray(warm)
        warmup_s = time.perf_counter() - t0
        del warm

    t0 = time.perf_counter()
    img = mi.render(scene, spp=args.spp, seed=args.seed)
    arr = np.array(img, dtype=np.float32)  # forces dr.eval + completion
    elapsed = time.perf_counter() - t0

    if args.out:
        mi.Bitmap(arr, pixel_format=mi.Bitmap.PixelFormat.RGB).write(args.out)

    summary = {
        "time_s": elapsed,
        "spp": args.spp,
        "samples_per_second": w * h * args.spp / elapsed,
        "variant": args.variant,
        "integrator": itype,
        "resolution": [w, h],
        "threads": dr.thread_count(),
        "warmup_s": warmup_s,
        "mean_rgb": [float(x) for x in arr.reshape(-1, arr.shape[-1]).mean(axis=0)],
        "nonfinite_pixels": int((~np.isfinite(arr)).any(axis=-1).sum()),
        "out": args.out,
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{itype} {args.variant} {w}x{h} spp={args.spp} threads={summary['threads']}: "
              f"{elapsed:.3f} s, {summary['samples_per_second']:.3e} samples/s "
              f"(warm-up {warmup_s if warmup_s is None else round(warmup_s, 3)} s); "
              f"mean rgb {summary['mean_rgb']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
