#!/usr/bin/env python3
"""Mitsuba 3 reference renderer: a speed and correctness anchor for pbvol.

Run it with the *Mitsuba* interpreter (a separate venv, not pbvol's), e.g.::

    /work/mitsuba-venv/bin/python benchmarks/mitsuba_reference.py \\
        --scene wax_sphere --spp 64 --threads 2 --out /tmp/wax.exr --json

This script deliberately does not import pbvol.  The scene is either a built-in
(``--scene wax_sphere``) or the JSON that ``pbvol export-mitsuba SCENE -o
scene.json`` writes, given with ``--scene-json`` (a path to the .json file, or
inline JSON text).  That JSON is the dictionary ``mi.load_dict`` takes, with two
conventions JSON needs (``load_dict_form`` applies them):

  * a transform is ``{"type": "transform", "matrix": [[4 rows of 4]]}``
    (row-major; becomes ``mi.ScalarTransform4f``);
  * a ``"filename"`` (meshes, volume grids) is relative to the JSON file's
    folder (relative to the current folder for inline text).

``--dump-scene`` prints the resolved JSON (overrides applied) and exits.

Timing: the scene is first rendered once at 1 spp (JIT compilation warm-up,
not timed); the main render is then timed up to and including conversion of
the result to a NumPy array, so all kernel work has completed.

Mitsuba conventions worth knowing when comparing with pbvol (the export maps
them: pbvol_cli/pipeline/export_mitsuba.py):
  * ``max_depth`` counts path segments (1: emitters seen directly), pbvol's
    the interactions: the export writes pbvol's + 1.  ``--max-depth`` here
    takes Mitsuba's convention.
  * ``rr_depth``: Russian roulette runs at the top of each path-loop iteration
    when ``depth > rr_depth`` (strictly), where depth counts scattering
    vertices (medium scatters and non-null surface interactions); pbvol's
    starts once depth >= its rr_depth, so the export writes pbvol's - 1.  The
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


def _wax_sphere():
    """configs/wax_sphere.toml as `pbvol export-mitsuba` writes it: a sphere of the paper's wax (materials/wax.toml)
    of radius 5 behind a dielectric of index 1.44, a sphere light of radius 0.5 and radiance 400, 256 x 256."""
    albedo = [0.9803, 0.9615, 0.7500]
    sigma_t = [1.0 / 0.6536, 1.0 / 0.6250, 1.0 / 0.5882]
    top = max(sigma_t)
    return {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": 100001, "rr_depth": 7, "hide_emitters": False},
        "sensor": {
            "type": "perspective",
            "fov": 30.0,
            "fov_axis": "y",
            "near_clip": 0.001,
            "far_clip": 1000.0,
            # look_at(origin=[0, 0, 20], target=[0, 0, 0], up=[0, 1, 0])
            "to_world": {"type": "transform", "matrix": [[-1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0],
                                                         [0.0, 0.0, -1.0, 20.0], [0.0, 0.0, 0.0, 1.0]]},
            "sampler": {"type": "independent", "sample_count": 16, "seed": 1},
            "film": {"type": "hdrfilm", "width": 256, "height": 256, "pixel_format": "rgb",
                     "component_format": "float32", "rfilter": {"type": "box"}},
        },
        "medium_0": {
            "type": "homogeneous",
            "albedo": {"type": "rgb", "value": albedo},
            "sigma_t": {"type": "rgb", "value": [s / top for s in sigma_t]},
            "scale": top,
            "phase": {"type": "hg", "g": 0.8},
        },
        "shape_0": {
            "type": "sphere",
            "center": [0.0, 0.0, 0.0],
            "radius": 5.0,
            "bsdf": {"type": "dielectric", "int_ior": 1.44, "ext_ior": 1.0},
            "interior": {"type": "ref", "id": "medium_0"},
        },
        "light_0": {
            "type": "sphere",
            "center": [10.0, 10.0, 10.0],
            "radius": 0.5,
            # a black BSDF: the light sphere only emits
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}},
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [400.0, 400.0, 400.0]}},
        },
    }


BUILTIN_SCENES = {"wax_sphere": _wax_sphere}
SENSORS = ("perspective", "thinlens", "orthographic")
INTEGRATORS = ("volpath", "volpathmis", "path", "prbvolpath")


def load_dict_form(mi, desc, base_dir=None):
    """The dictionary for ``mi.load_dict`` from the export's JSON form: every
    {"type": "transform", "matrix": M} becomes ``mi.ScalarTransform4f(M)``, and
    every relative "filename" is joined to base_dir (the JSON file's folder).
    Pure Python but for ``mi.ScalarTransform4f``: pass any stand-in for mi."""

    def walk(value, key=None):
        if isinstance(value, dict):
            if value.get("type") == "transform":
                return mi.ScalarTransform4f(value["matrix"])
            return {k: walk(v, k) for k, v in value.items()}
        if isinstance(value, list):
            return [walk(v) for v in value]
        if key == "filename" and isinstance(value, str) and base_dir and not os.path.isabs(value):
            return os.path.join(base_dir, value)
        return value

    return walk(desc)


def find_object(desc, types):
    """The top-level entry of the scene dict whose type is one of types (the sensor, the integrator)."""
    for key, value in desc.items():
        if isinstance(value, dict) and value.get("type") in types:
            return value
    raise ValueError(f"the scene has no {' or '.join(types)} entry")


def load_description(args):
    """(scene dict in the JSON form, the folder its filenames are relative to), the command line's overrides
    applied."""
    base_dir = None
    if args.scene_json:
        text = args.scene_json
        if os.path.exists(text):
            base_dir = os.path.dirname(os.path.abspath(text))
            with open(text) as f:
                text = f.read()
        desc = json.loads(text)
    else:
        desc = copy.deepcopy(BUILTIN_SCENES[args.scene]())
    sensor = find_object(desc, SENSORS)
    if args.resolution:
        sensor["film"]["width"], sensor["film"]["height"] = args.resolution
    sensor.setdefault("sampler", {"type": "independent"})["sample_count"] = args.spp
    integ = find_object(desc, INTEGRATORS)
    if args.max_depth is not None:
        integ["max_depth"] = args.max_depth
    if args.rr_depth is not None:
        integ["rr_depth"] = args.rr_depth
    if args.integrator:
        integ["type"] = args.integrator
    return desc, base_dir


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default="wax_sphere", choices=sorted(BUILTIN_SCENES))
    p.add_argument("--scene-json", help="a scene as `pbvol export-mitsuba` writes it (a .json path, or JSON text); "
                   "overrides --scene")
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--resolution", type=int, nargs=2, metavar=("W", "H"))
    p.add_argument("--integrator", choices=["volpath", "volpathmis"])
    p.add_argument("--max-depth", type=int, help="override max_depth, Mitsuba's convention (path segments; "
                   "-1 = unbounded)")
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

    desc, base_dir = load_description(args)
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

    itype = find_object(desc, INTEGRATORS)["type"]
    film = find_object(desc, SENSORS)["film"]
    w, h = int(film["width"]), int(film["height"])
    scene = mi.load_dict(load_dict_form(mi, desc, base_dir))

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
