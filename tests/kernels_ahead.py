"""The point-based method's numba kernels compiled ahead, in a second process, while a full test run starts.

A clean checkout compiles every kernel once (about two minutes on 2 cores, numba's cache next to the sources); the
first tests compile the path tracer's, the dipole's and the table's on one core while the other idles. This
renders one small pbl scene (a dielectric ball of medium on a diffuse floor under a sphere light: light samples,
bounced samples, caustic photons, bins and the glow's pooling) in a process of its own at the session's start, so
that the point-based tests later load those kernels from the cache. The images the tests read do not depend on it:
a kernel loaded from the cache is the one compiled in-process."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FULL_RUN = 200  # tests collected from which a run counts as a full one (a few tests alone compile what they use)

SCRIPT = r"""
import sys, tempfile
from pathlib import Path
import tomli_w
from pbvol_cli.pipeline.render import RenderOptions, render_scene
folder = Path(tempfile.mkdtemp(prefix="pbvol-kernels-"))
scene = {"camera": {"position": [0.0, 1.0, 4.0], "look_at": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fov": 40.0,
                    "resolution": [8, 8]},
         "render": {"spp": 1, "lut": {"particles": 2000}},
         "lights": [{"type": "sphere", "center": [2.0, 3.0, 2.0], "radius": 0.3, "radiance": 20.0},
                    {"type": "environment", "radiance": 0.1}],
         "shapes": [{"type": "sphere", "radius": 1.0, "interface": "dielectric", "eta": 1.5,
                     "medium": {"albedo": 0.9, "mean_free_path": 0.5, "g": 0.3}},
                    {"type": "quad", "center": [0.0, -1.0, 0.0], "size": [8.0, 8.0], "interface": "diffuse",
                     "albedo": 0.8}]}
path = folder / "scene.toml"
path.write_bytes(tomli_w.dumps(scene).encode())
render_scene(path, folder / "o.exr", RenderOptions(method="pbl", threads=1, cache_dir=folder, quiet=True))
"""


def start(count: int):
    """The compiling process (subprocess.Popen) for a run of `count` tests, or None for a partial run."""
    if count < FULL_RUN:
        return None
    return subprocess.Popen([sys.executable, "-c", SCRIPT], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)


def finish(proc):
    """Stops the compiling process if it still runs (a run cut short; a full run outlasts it by minutes). numba
    writes each cache file whole under a temporary name and renames it, so a stopped compile leaves no entry to
    trust."""
    if proc is None:
        return
    if proc.poll() is None:
        proc.kill()
    proc.wait()
