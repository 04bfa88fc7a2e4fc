"""Rendering on a Dask cluster (pipeline/distributed.py): the same image as one process for volpath and pbl, the
cache entries shipped to workers that do not share the cache, a killed worker's shard run again, batches of
scenes, and the command line's errors."""

import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import write_scene
from pbvol_cli import config as C
from pbvol_cli.main import app
from pbvol_cli.pipeline.distributed import render_batch, render_distributed, shard_ranges
from pbvol_cli.pipeline.render import RenderOptions, render_loaded
from test_api import SCENE
from test_merge import PASS_SCENE

distributed = pytest.importorskip("distributed")
runner = CliRunner()


@pytest.fixture(scope="module")
def client():
    import logging

    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                       silence_logs=logging.ERROR)
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


def test_shard_ranges_tile_the_range_in_order():
    assert shard_ranges(0, 10, 3) == [(0, 3), (3, 6), (6, 10)]
    assert shard_ranges(5, 7, 4) == [(5, 6), (6, 7)]
    assert shard_ranges(2, 3, 1) == [(2, 3)]


def _one_process(path, opts):
    return render_loaded(C.load_scene(path), path, opts)


@pytest.mark.parametrize("method", ["volpath", "pbl"])
def test_a_dask_render_is_the_one_process_image(tmp_path, client, method):
    """Shards on two worker processes merge into one process's image and layers, bit for bit; for pbl the cache
    entries are shipped to a cache of the workers' own, which then holds the same files."""
    spp = 7 if method == "volpath" else 4
    path = write_scene(tmp_path, dict(PASS_SCENE, render=dict(PASS_SCENE["render"], spp=spp)))
    opts = RenderOptions(method=method, cache_dir=tmp_path / "cache", quiet=True, threads=1)
    one = _one_process(path, opts)
    worker_cache = tmp_path / "worker-cache"
    (r,) = render_distributed([(C.load_scene(path), path, opts)], client, shards=3, ship_cache=True,
                              worker_cache=worker_cache, quiet=True)
    assert np.array_equal(one.image, r.image) and r.problem is None
    assert list(one.layers) == list(r.layers) and all(np.array_equal(one.layers[k], r.layers[k]) for k in r.layers)
    assert r.metadata["spp"] == spp and r.metadata["samples"] == f"0:{spp}" and r.summary["shards"] == 3
    if method == "pbl":
        shipped = sorted(p.relative_to(worker_cache) for p in worker_cache.rglob("*.npz"))
        kept = {p.relative_to(tmp_path / "cache") for p in (tmp_path / "cache").rglob("*.npz")}
        assert shipped and all(s in kept for s in shipped)
        assert all((worker_cache / s).read_bytes() == (tmp_path / "cache" / s).read_bytes() for s in shipped
                   if "tables" in str(s) or "light_samples" in str(s))


def test_a_killed_workers_shard_runs_again(tmp_path, client):
    """A worker killed while it renders a shard: the scheduler runs the shard again and the image is unchanged."""
    path = write_scene(tmp_path, dict(SCENE, camera=dict(SCENE["camera"], resolution=[48, 40]),
                                      render={"spp": 192, "seed": 4}))
    opts = RenderOptions(cache_dir=tmp_path / "cache", quiet=True, threads=1)
    one = _one_process(path, opts)
    pids = client.run(os.getpid)
    killed = []

    def kill_a_busy_worker():
        deadline = time.time() + 60
        while time.time() < deadline and not killed:
            busy = [w for w, tasks in client.processing().items() if tasks and w in pids]
            if busy:
                time.sleep(0.05)  # into its shard (one takes a few tenths of a second)
                # the shards it holds now (one shorter than the wait is done, and is not run again)
                tasks = client.processing().get(busy[0], ())
                if tasks:
                    os.kill(pids[busy[0]], signal.SIGKILL)
                    killed.extend(tasks)
            time.sleep(0.05)

    t = threading.Thread(target=kill_a_busy_worker)
    t.start()
    (r,) = render_distributed([(C.load_scene(path), path, opts)], client, shards=4, quiet=True)
    t.join()
    assert killed, "no worker was seen rendering"
    assert np.array_equal(one.image, r.image)

    def times_started(dask_scheduler, keys):
        return max(sum(t[2] == "processing" for t in dask_scheduler.story(k)) for k in keys)

    assert client.run_on_scheduler(times_started, keys=killed) >= 2  # the killed shard was run again
    client.wait_for_workers(2, timeout=60)  # the nanny restarts it, for the tests after this one


def test_a_batch_renders_every_scene_and_reports_failures(tmp_path, client):
    a = write_scene(tmp_path, dict(SCENE, render={"spp": 3, "seed": 4}), name="a.toml")
    b = write_scene(tmp_path, dict(SCENE, render={"spp": 2, "seed": 9}), name="b.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("camera = 3\n")
    out = tmp_path / "out"
    out.mkdir()
    lines = []
    failed = render_batch([a, bad, b], out, RenderOptions(quiet=True, threads=1), client, report=lines.append)
    assert failed == 1 and sum(line.startswith("error: ") and "bad.toml" in line for line in lines) == 1
    from pbvol_cli.imageio import read_exr

    for scene, name in ((a, "a.exr"), (b, "b.exr")):
        assert np.array_equal(read_exr(out / name)[0],
                              _one_process(scene, RenderOptions(quiet=True)).image.astype(np.float32))
    with pytest.raises(Exception, match="would overwrite"):
        render_batch([a, a], out, RenderOptions(quiet=True), client)


def test_the_command_line_refuses_what_dask_cannot_do(tmp_path):
    path = write_scene(tmp_path, SCENE)
    out = str(tmp_path / "o.exr")
    for args, needle in ((["--dask", "local[2]", "--time-limit", "5"], "--time-limit"),
                         (["--shards", "2"], "only with --dask"),
                         (["--dask", "local[0]"], "local[N]")):
        r = runner.invoke(app, ["render", str(path), "-o", out, "-q", *args])
        assert r.exit_code == 1 and needle in r.output and "Traceback" not in r.output, (args, r.output)
    assert not Path(out).exists()


def test_the_api_renders_on_dask(tmp_path, client):
    import pbvol

    scene = pbvol.load_scene(dict(SCENE, render={"spp": 5, "seed": 2}), base_dir=tmp_path)
    one = pbvol.render(scene, threads=1)
    assert np.array_equal(pbvol.render(scene, dask=client, shards=2).image, one.image)


def test_a_shard_that_fails_on_a_worker_is_one_line_naming_the_scene(tmp_path, client):
    """A mesh the workers cannot read (here: removed after this process checked the scene) fails the render with
    one line, not a traceback."""
    mesh = tmp_path / "tri.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    path = write_scene(tmp_path, dict(SCENE, shapes=[*SCENE["shapes"], {"type": "mesh", "file": "tri.obj",
                                                                         "interface": "diffuse"}]))
    scene = C.load_scene(path)
    mesh.unlink()
    with pytest.raises(Exception) as err:
        render_distributed([(scene, path, RenderOptions(quiet=True, spp=2))], client, quiet=True)
    assert type(err.value).__name__ in ("PbvolError", "ConfigError") and "tri.obj" in str(err.value)
    assert "\n" not in str(err.value)
