"""A non-editable install works: the wheel carries the material presets, and the installed package finds them
away from the repository."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# what a wheel is built from: the package and its metadata (not the caches, the venv or the tests)
SOURCES = ("pyproject.toml", "README.md", "pbvol_cli")


def _run(cmd, **kw):
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, **kw)
    assert r.returncode == 0, (cmd, r.stdout[-2000:], r.stderr[-2000:])
    return r.stdout


def test_the_wheel_carries_the_presets_and_the_installed_package_finds_them(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc", "*.egg-info")
    for name in SOURCES:
        p = ROOT / name
        (shutil.copytree(p, src / name, ignore=ignore) if p.is_dir() else shutil.copy(p, src / name))
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "--disable-pip-version-check",
          "-w", str(tmp_path / "dist"), str(src)])
    wheel, = (tmp_path / "dist").glob("pbvol-*.whl")
    target = tmp_path / "site"
    _run([sys.executable, "-m", "pip", "install", "--no-deps", "--quiet", "--disable-pip-version-check",
          "--target", str(target), str(wheel)])
    presets = sorted(p.name for p in (ROOT / "materials").glob("*.toml"))
    assert sorted(p.name for p in (target / "pbvol_cli" / "materials").glob("*.toml")) == presets
    # run the installed copy from elsewhere, with PBVOL_MATERIALS unset: the package's own presets are used
    env = {k: v for k, v in os.environ.items() if k != "PBVOL_MATERIALS"}
    env["PYTHONPATH"] = str(target)
    work = tmp_path / "elsewhere"
    work.mkdir()
    where = _run([sys.executable, "-c", "import pbvol_cli; print(pbvol_cli.__file__)"], cwd=work, env=env)
    assert where.strip().startswith(str(target)), where
    listed = _run([sys.executable, "-m", "pbvol_cli.main", "materials"], cwd=work, env=env)
    assert listed.count("source:") == len(presets)
    (work / "scene.toml").write_text(
        'unit = "cm"\n[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n'
        '[[lights]]\ntype = "environment"\nradiance = 1.0\n'
        '[[shapes]]\ntype = "sphere"\nradius = 1.0\ninterface = "dielectric"\neta = 1.5\nmedium = "marble"\n')
    checked = _run([sys.executable, "-m", "pbvol_cli.main", "check", "scene.toml"], cwd=work, env=env)
    assert "marble" in checked
