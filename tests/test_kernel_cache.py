"""numba's cached kernels follow the whole package's source (pbvol_cli/kernel_cache.py)."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# compile (or load) one kernel under NUMBA_CACHE_DIR, the package's stamp replaced by argv[1] where given, and print
# whether numba's cache served it
PROBE = r"""
import sys
import numpy as np
import pbvol_cli.kernel_cache as kc
if len(sys.argv) > 1:
    kc.package_stamp = lambda: sys.argv[1]
from pbvol_cli.pointbased.camera_pass import add_rows
add_rows(np.zeros((2, 3)), np.zeros(1, np.int64), np.ones((1, 3)))
print("hit" if add_rows.stats.cache_hits else "miss")
"""


def probe(cache_dir: Path, *stamp: str) -> str:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir)}
    r = subprocess.run([sys.executable, "-c", PROBE, *stamp], capture_output=True, text=True, cwd=ROOT, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout.split()[-1]


def test_kernels_take_the_package_stamp():
    """A cached kernel's entry is stamped with its file's hash and the package's; the stamp covers every source
    file of the package."""
    from pbvol_cli import kernel_cache
    from pbvol_cli.physics.sampling import stratified_depth
    from pbvol_cli.pointbased.camera_pass import add_rows

    for kernel in (add_rows, stratified_depth):
        stamp = kernel._cache._cache_file._source_stamp
        assert getattr(kernel._cache._impl.locator, "pbvol_package_stamp", False)
        assert stamp[1] == kernel_cache.package_stamp()
    files = {p.relative_to(kernel_cache.PACKAGE).as_posix() for p in kernel_cache.PACKAGE.rglob("*.py")}
    assert {"physics/sampling.py", "pointbased/gather.py", "config.py"} <= files


def test_a_change_elsewhere_in_the_package_compiles_the_kernels_again(tmp_path):
    """The same kernel in fresh processes: compiled and cached, then served from the cache; under another package
    stamp (another file changed: a callee or a constant the kernel froze) compiled again, then served; back under
    the first stamp compiled again (numba's index holds the last stamp written)."""
    assert probe(tmp_path) == "miss"
    assert probe(tmp_path) == "hit"
    assert probe(tmp_path, "another package") == "miss"
    assert probe(tmp_path, "another package") == "hit"
    assert probe(tmp_path) == "miss"
