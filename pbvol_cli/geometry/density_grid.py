"""Density grids read from files (render/media.py evaluates them): a 3D array of voxels in an .npz file, checked
so that a bad file gives one line naming the scene file and the field."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pbvol_cli import config as C
from pbvol_cli.errors import ConfigError

MAX_VOXELS = 512 ** 3  # a grid larger than this is refused (its float64 copy would be 1 GiB)


def load_grid(scene_path: Path, dens: C.GridDensity, where: str):
    """(density voxels (nx, ny, nz) float64, emission voxels or None) of a grid density, checked; ConfigError naming
    the scene file and the field otherwise."""
    f = Path(scene_path).parent / dens.file
    fld = f"{where}: density.file"
    if f.suffix.lower() == ".vdb":
        raise ConfigError(scene_path, fld, f"{dens.file}: OpenVDB files are not read (no maintained Python reader "
                          "on PyPI); save the grid as .npz with a 3D array `density`")
    try:
        with np.load(f, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except FileNotFoundError:
        raise ConfigError(scene_path, fld, f"{f}: file not found") from None
    except (OSError, ValueError) as e:
        raise ConfigError(scene_path, fld, f"{f}: not a readable .npz file ({e})") from None
    grid = _voxels(arrays, "density", scene_path, fld, f)
    emission = None
    if dens.emission_key is not None:
        emission = _voxels(arrays, dens.emission_key, scene_path, f"{where}: density.emission_key", f)
        if emission.shape != grid.shape:
            raise ConfigError(scene_path, f"{where}: density.emission_key", f"{f}: {dens.emission_key!r} has shape "
                              f"{emission.shape}, the density {grid.shape}; expected the same shape")
    return grid, emission


def _voxels(arrays: dict, key: str, scene_path, fld: str, f: Path) -> np.ndarray:
    if key not in arrays:
        raise ConfigError(scene_path, fld, f"{f}: no array {key!r} (it has {', '.join(sorted(arrays)) or 'none'})")
    a = arrays[key]
    if a.ndim != 3 or min(a.shape) < 1 or a.size > MAX_VOXELS or not np.issubdtype(a.dtype, np.number):
        raise ConfigError(scene_path, fld, f"{f}: {key!r} is {a.dtype} of shape {a.shape}; expected a 3D numeric "
                          f"array of at most {MAX_VOXELS} voxels")
    a = a.astype(np.float64)
    if not np.all(np.isfinite(a)) or a.min() < 0:
        raise ConfigError(scene_path, fld, f"{f}: {key!r} has negative or non-finite values; expected values >= 0")
    return np.ascontiguousarray(a)
