"""pbvol as a Python library: load a scene, render it, get numpy arrays back.

    import pbvol
    scene = pbvol.load_scene("configs/oil_glass.toml")        # or a dict with the scene file's contents
    result = pbvol.render(scene, method="volpath", spp=16, seed=1, resolution=(128, 128))
    result.image            # (H, W, 3) float64, linear radiance
    result.layers           # {"surface": ..., "single": ...}: the method's layers, which sum to the image
    result.metadata         # what the EXR header holds: method, spp, seed, scene hash, ...
    result.save("out.exr")  # the EXR `pbvol render` writes

The command line (`pbvol render`) is a thin layer over the same functions (pbvol_cli.pipeline.render). Errors
are pbvol_cli.errors.PbvolError (ConfigError for a bad scene), one line naming the file and the field.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pbvol_cli import __version__
from pbvol_cli import config as _config
from pbvol_cli.errors import ConfigError, PbvolError, RenderFailed
from pbvol_cli.pipeline.render import METHODS

__all__ = ["Scene", "Result", "load_scene", "render", "METHODS", "PbvolError", "ConfigError", "RenderFailed",
           "__version__"]


@dataclass
class Scene:
    """A validated scene: its settings (`config`, the Pydantic model of the scene file) and the path its relative
    files (meshes, density grids, material files) are found from."""

    config: _config.Scene
    path: Path


@dataclass
class Result:
    """A render: image and layers (H, W, 3) float64 in linear radiance, the EXR's metadata, a summary (time, peak
    memory, samples per second) and `problem`: why the image looks broken (non-finite or absurd pixels), else
    None."""

    image: np.ndarray
    layers: dict = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)
    summary: dict = field(default_factory=dict)
    problem: str | None = None

    def save(self, path) -> Path:
        """Write the image, its layers and metadata to an EXR (float32), as `pbvol render` does."""
        from pbvol_cli.imageio import write_exr

        path = Path(path)
        write_exr(path, self.image.astype(np.float32), self.metadata,
                  layers={k: v.astype(np.float32) for k, v in self.layers.items()} or None)
        return path


def load_scene(source, base_dir=None) -> Scene:
    """A scene from a TOML file's path, or from a dict holding what such a file would (relative files found from
    base_dir, default the current folder). Raises ConfigError on a bad scene."""
    if isinstance(source, dict):
        base = Path(base_dir) if base_dir is not None else Path.cwd()
        path = base / "<scene dict>"
        return Scene(_config.scene_from_data(source, path), path)
    path = Path(source)
    return Scene(_config.load_scene(path), path)


def render(scene, method: str = "volpath", spp: int | None = None, seed: int | None = None,
           resolution: tuple[int, int] | None = None, threads: int | None = None, time_limit: float | None = None,
           orders: str | None = None, components: str | None = None, max_depth: int | None = None,
           samples: tuple[int, int] | None = None, cache_dir=None, progress: bool = False, dask=None,
           shards: int | None = None) -> Result:
    """Render a Scene (or a path or dict, loaded by load_scene). The arguments are the command line's options
    (None: the scene's setting; samples=(A, B): samples (passes) A .. B-1); progress: show the progress bar on
    stderr; dask: render on a Dask cluster (local[N], a scheduler's address or a distributed.Client; shards:
    pieces of the samples), the same image. Tables and light samples come from the cache (cache_dir, else
    $PBVOL_CACHE_DIR, else ~/.cache/pbvol)."""
    from pbvol_cli.pipeline.render import RenderOptions, render_loaded

    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    opts = RenderOptions(method=method, spp=spp, seed=seed, threads=threads, time_limit=time_limit,
                         resolution=tuple(resolution) if resolution is not None else None, orders=orders,
                         max_depth=max_depth, components=components,
                         samples=tuple(samples) if samples is not None else None,
                         cache_dir=Path(cache_dir) if cache_dir is not None else None, quiet=not progress)
    if dask is not None:
        from pbvol_cli.pipeline.distributed import render_distributed

        r = render_distributed([(scene.config, scene.path, opts)], dask, shards, quiet=not progress)[0]
    else:
        r = render_loaded(scene.config, scene.path, opts)
    return Result(r.image, dict(r.layers), r.metadata, r.summary, r.problem)
