"""Every example scene, rendered small with every method at a fixed seed, against stored digests of its pixels.

A change that is meant to leave images alone (a refactoring, a faster kernel doing the same arithmetic) must keep
every digest; a change that alters images on purpose rewrites them in the same commit:

    .venv/bin/python tests/test_image_digests.py --write

Floating-point results depend on the CPU's instruction set (numba compiles for the host) and on the numerical
libraries' versions, so the digests are compared only where those match the machine that wrote them.
"""

from __future__ import annotations

import hashlib
import json
import sys
import tempfile
import tomllib
from pathlib import Path

import pytest
import tomli_w

ROOT = Path(__file__).resolve().parents[1]
DIGESTS = ROOT / "tests" / "data" / "image_digests.json"
METHODS = ("volpath", "pbl", "dipole", "vpl")
HETEROGENEOUS_METHODS = ("volpath", "raymarch", "vpl")  # pbl and the dipole refuse heterogeneous media
# small enough for the default test run: 20x20 pixels, 2 samples, few light samples, coarse tables
OVERRIDES = {"resolution": [20, 20], "spp": 2, "seed": 3, "surface_samples": 1500, "bounce_samples": 200,
             "particles": 1000, "irradiance_samples": 2000}


def platform_signature() -> dict:
    import llvmlite.binding as llvm
    import numba
    import numpy

    return {"cpu": llvm.get_host_cpu_name(), "features": llvm.get_host_cpu_features().flatten(),
            "numpy": numpy.__version__, "numba": numba.__version__}


def small_scene(config: Path, out_dir: Path) -> Path:
    """The example scene with the small settings of OVERRIDES, written elsewhere (its mesh files' paths made
    absolute)."""
    scene = tomllib.loads(config.read_text())
    scene["camera"]["resolution"] = OVERRIDES["resolution"]
    render = scene.setdefault("render", {})
    render["spp"], render["seed"] = OVERRIDES["spp"], OVERRIDES["seed"]
    render.setdefault("pbl", {}).update(surface_samples=OVERRIDES["surface_samples"],
                                        bounce_samples=OVERRIDES["bounce_samples"])
    render.setdefault("lut", {})["particles"] = OVERRIDES["particles"]
    render.setdefault("dipole", {}).update(min_samples=OVERRIDES["irradiance_samples"],
                                           max_samples=OVERRIDES["irradiance_samples"])
    for shape in scene.get("shapes", []):
        if "file" in shape:
            shape["file"] = str((config.parent / shape["file"]).resolve())
    for material in scene.get("materials", {}).values():
        if "file" in material.get("density", {}):
            material["density"]["file"] = str((config.parent / material["density"]["file"]).resolve())
    path = out_dir / config.name
    path.write_bytes(tomli_w.dumps(scene).encode())
    return path


def render_digests() -> dict:
    """{config name: {method: sha256 of the image and its layers}} for every example config."""
    from pbvol_cli.imageio import read_exr, read_layers
    from pbvol_cli.pipeline.render import RenderOptions, render_scene

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for config in sorted((ROOT / "configs").glob("*.toml")):
            scene = small_scene(config, tmp)
            out[config.name] = {}
            heterogeneous = any("density" in m or "emission" in m
                                for m in tomllib.loads(scene.read_text()).get("materials", {}).values())
            for method in HETEROGENEOUS_METHODS if heterogeneous else METHODS:
                exr = tmp / f"{config.stem}_{method}.exr"
                render_scene(scene, exr, RenderOptions(method=method, threads=2, cache_dir=tmp / "cache", quiet=True))
                h = hashlib.sha256(read_exr(exr)[0].astype("<f4").tobytes())
                for name, img in sorted(read_layers(exr).items()):
                    h.update(name.encode())
                    h.update(img.astype("<f4").tobytes())
                out[config.name][method] = h.hexdigest()
    return out


def test_example_images_match_their_digests():
    stored = json.loads(DIGESTS.read_text())
    if stored["platform"] != platform_signature():
        pytest.skip("digests were written on another CPU or library version; rewrite them with --write to compare")
    assert render_digests() == stored["images"]


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        sys.exit("usage: python tests/test_image_digests.py --write")
    DIGESTS.parent.mkdir(exist_ok=True)
    DIGESTS.write_text(json.dumps({"platform": platform_signature(), "overrides": OVERRIDES,
                                   "images": render_digests()}, indent=1) + "\n")
    print(f"wrote {DIGESTS}")
