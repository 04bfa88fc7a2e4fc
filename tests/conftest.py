"""Shared helpers: scenes written from dicts, rendered in-process at small sizes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tomli_w

from pbvol_cli import config as C
from pbvol_cli.geometry.scene_build import build_scene


def write_scene(tmp_path: Path, scene: dict, name: str = "scene.toml") -> Path:
    p = Path(tmp_path) / name
    p.write_bytes(tomli_w.dumps(scene).encode())
    return p


def camera(res=(16, 16), position=(0.0, 0.0, 4.0), fov=40.0):
    return {"position": list(position), "look_at": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fov": fov,
            "resolution": list(res)}


def build(tmp_path: Path, scene: dict):
    p = write_scene(tmp_path, scene)
    return build_scene(C.load_scene(p), p)


def volpath(built, spp=16, seed=1, orders=None, max_depth=100000, rr_depth=8, batch=1 << 17, threads=2):
    from pbvol_cli.render.volpath import render_volpath

    img, _, _ = render_volpath(built, spp, seed, max_depth, rr_depth, orders, batch, threads)
    return img


@pytest.fixture
def tmp_scene(tmp_path):
    return lambda scene, name="scene.toml": write_scene(tmp_path, scene, name)
