"""Cache writers killed (SIGKILL) at random moments never leave an entry that is trusted and wrong: after each
kill the next reader either reuses an entry identical to an intact build or rebuilds it, without waiting on a dead
writer's lock.

Each trial starts a writer process that rebuilds and stores the entry over and over (--force), kills it at a
random moment, then reads the entry as a render would. The default run kills the generic writer a dozen times;
`pytest -m slow tests/pipeline/test_cache_kill.py` kills each writer (generic, table, light samples) 60 times."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from conftest import write_scene
from pbvol_cli.pipeline.cache import save_npz_atomic

# A writer: prints "ready" once its imports are done, then rebuilds the entry for ever, printing "writing" as each
# write starts (so that half the kills can be aimed into the write). {setup} defines get(force).
WRITER = textwrap.dedent("""
    import numpy as np
    def _announced(save):
        def write(*args, **kwargs):
            print("writing", flush=True)
            save(*args, **kwargs)
        return write
    np.savez_compressed, np.savez = _announced(np.savez_compressed), _announced(np.savez)  # (light samples: savez)
    {setup}
    print("ready", flush=True)
    while True:
        get(True)
""")

GENERIC = """
import numpy as np
from pbvol_cli.pipeline.cache import cached_entry

class Entry:
    def __init__(self, values):
        self.values = values
    def arrays(self):
        return {"values": self.values}
    @classmethod
    def from_arrays(cls, d):
        return cls(d["values"])

def build():  # about 8 MB of incompressible numbers: the write takes a while
    return Entry(np.random.default_rng(5).random(1_000_000))

def get(force=False):
    entry, reused = cached_entry(PATH, ("values",), Entry.from_arrays, build, force)
    return entry.arrays(), reused
"""

TABLE = """
from pbvol_cli.multiple_scattering.layout import Layout
from pbvol_cli.multiple_scattering.table import TableSettings
from pbvol_cli.pipeline.lut import get_table

SETTINGS = TableSettings(particles=3000, seed=2, layout=Layout(extent=20.0, kill_radius=40.0), sh_order=6)

def get(force=False):
    r = get_table(0.9, 0.3, 1, SETTINGS, CACHE, force)
    return r.table.arrays(), r.reused
"""

SAMPLES = """
from pbvol_cli import config as C
from pbvol_cli.geometry.scene_build import build_scene
from pbvol_cli.pipeline.samples import get_light_samples

SCENE = C.load_scene(SCENE_FILE)
BUILT = build_scene(SCENE, SCENE_FILE)

def get(force=False):
    r = get_light_samples(BUILT, SCENE.render.pbl, 1, CACHE, 1, force)
    return r.samples.arrays(), r.reused
"""


def _setup(kind: str, folder) -> str:
    where = f"import pathlib\nCACHE = pathlib.Path({str(folder / 'cache')!r})\nPATH = CACHE / 'entry_kill.npz'\n"
    if kind == "samples":
        scene = write_scene(folder, {
            "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "fov": 40, "resolution": [8, 8]},
            "render": {"pbl": {"surface_samples": 2000, "segments_per_beam": 4}},
            "lights": [{"type": "directional", "direction": [0, -1, -0.5], "irradiance": 1.0}],
            "shapes": [{"type": "sphere", "radius": 1.0, "interface": "dielectric", "eta": 1.3, "medium": "wax"}]})
        where += f"SCENE_FILE = pathlib.Path({str(scene)!r})\n"
    return where + {"generic": GENERIC, "table": TABLE, "samples": SAMPLES}[kind]


def _reader(setup: str):
    """get() run here, in a fresh namespace (as a render reading the cache would)."""
    ns: dict = {}
    exec(setup, ns)
    return ns["get"]


def _kill_trials(kind: str, trials: int, folder):
    """Kill the writer at a random moment of its work (odd trials) or of a write (even trials), with the entry
    present or removed beforehand; read it after each kill. Returns how often it was reused, rebuilt, and how
    often a kill left a temporary file (it landed in a write)."""
    setup = _setup(kind, folder)
    get = _reader(setup)
    reference, _ = get(True)  # an intact build
    t0 = time.perf_counter()
    get(True)
    cycle = time.perf_counter() - t0  # one rebuild and write
    t0 = time.perf_counter()
    save_npz_atomic(folder / "timing.npz", kind != "samples", **reference)  # (light samples: uncompressed)
    write = time.perf_counter() - t0
    rng = np.random.default_rng(11)
    outcomes = {"reused": 0, "rebuilt": 0, "temporary left": 0}
    cache = folder / "cache"
    for trial in range(trials):
        if trial % 4 < 2:
            for entry in cache.rglob("*.npz"):
                entry.unlink()
        proc = subprocess.Popen([sys.executable, "-c", WRITER.format(setup=setup)], stdout=subprocess.PIPE,
                                stderr=subprocess.DEVNULL, text=True, env={**os.environ, "NUMBA_NUM_THREADS": "1"})
        try:
            assert proc.stdout.readline().strip() == "ready", f"{kind}: the writer did not start"
            if trial % 2:
                time.sleep(rng.uniform(0.0, 2.5 * cycle))  # anywhere in its first two builds and writes
            else:
                assert proc.stdout.readline().strip() == "writing"
                time.sleep(rng.uniform(0.0, 1.5 * write))  # in (or just after) its first write
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
        left = [p for p in cache.rglob(".*.tmp.*") if p.name.endswith(".npz")]
        outcomes["temporary left"] += bool(left)
        for p in left:  # (a reader removes them only when an hour old)
            p.unlink()
        t0 = time.perf_counter()
        arrays, reused = get()
        assert time.perf_counter() - t0 < 60 + 3 * cycle, f"{kind}: the reader waited on a dead writer's lock"
        outcomes["reused" if reused else "rebuilt"] += 1
        assert arrays.keys() == reference.keys()
        for name, a in reference.items():  # a reused entry is the intact one, byte for byte
            if name == "metrics":  # a table's build statistics: JSON with its times, which differ run to run
                a, arrays[name] = (_untimed(x) for x in (a, arrays[name]))
            assert np.array_equal(arrays[name], a), (kind, trial, name)
    return outcomes


def _untimed(metrics) -> str:
    return json.dumps({k: v for k, v in json.loads(str(metrics)).items() if not k.endswith("_s")}, sort_keys=True)


def test_a_killed_writer_never_leaves_a_trusted_corrupt_entry(tmp_path):
    outcomes = _kill_trials("generic", 12, tmp_path)
    assert outcomes["temporary left"] >= 2 and outcomes["rebuilt"] >= 2, outcomes  # some kills landed in writes


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["generic", "table", "samples"])
def test_every_cache_writer_killed_sixty_times(tmp_path, kind):
    outcomes = _kill_trials(kind, 60, tmp_path)
    assert outcomes["temporary left"] >= 10 and outcomes["rebuilt"] >= 10, outcomes
