"""render --samples A:B and pbvol merge: parts merge into the image of one render of their union, bit for bit
(render/sample_sums.py: a canonical tree of additions), for every method; mismatched parts, overlaps and gaps are
refused."""

import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import write_scene
from pbvol_cli.imageio import read_exr, read_layers
from pbvol_cli.main import app
from test_api import SCENE

runner = CliRunner()


def _render(tmp_path, scene, name, *args):
    r = runner.invoke(app, ["render", str(scene), "-o", str(tmp_path / name), "-q", *args])
    assert r.exit_code == 0, r.output
    return tmp_path / name


def test_parts_merge_into_the_whole_render_bit_for_bit(tmp_path):
    scene = write_scene(tmp_path, SCENE)
    whole = _render(tmp_path, scene, "whole.exr", "--spp", "7")
    parts = [_render(tmp_path, scene, f"p{a}.exr", "--samples", f"{a}:{b}") for a, b in ((0, 3), (3, 4), (4, 7))]
    r = runner.invoke(app, ["merge", *map(str, parts[::-1]), "-o", str(tmp_path / "merged.exr")])
    assert r.exit_code == 0, r.output
    a, meta_a = read_exr(whole)
    b, meta_b = read_exr(tmp_path / "merged.exr")
    assert np.array_equal(a, b) and meta_b["samples"] == "0:7" and meta_b["spp"] == 7
    assert not np.array_equal(a, read_exr(parts[0])[0])  # the parts differ from the whole: the check has teeth
    # a merge is a part too: merging it with the next range gives the render of 0:9
    _render(tmp_path, scene, "p7.exr", "--samples", "7:9")
    r = runner.invoke(app, ["merge", str(tmp_path / "merged.exr"), str(tmp_path / "p7.exr"), "-o",
                            str(tmp_path / "m9.exr")])
    assert r.exit_code == 0, r.output
    nine = _render(tmp_path, scene, "nine.exr", "--spp", "9")
    assert np.array_equal(read_exr(nine)[0], read_exr(tmp_path / "m9.exr")[0])


def test_merge_refuses_what_does_not_belong_together(tmp_path):
    scene = write_scene(tmp_path, SCENE)
    other = write_scene(tmp_path, dict(SCENE, render={"spp": 2, "seed": 5}), name="other.toml")
    p0 = _render(tmp_path, scene, "p0.exr", "--samples", "0:2")
    p1 = _render(tmp_path, scene, "p1.exr", "--samples", "2:4")
    p3 = _render(tmp_path, scene, "p3.exr", "--samples", "3:5")
    q = _render(tmp_path, other, "q.exr", "--samples", "2:4")
    plain = _render(tmp_path, scene, "plain.exr")
    out = str(tmp_path / "m.exr")
    for parts, needle in (([p0, p0], "overlap"), ([p0, p3], "gap"), ([p0, q], "differs"), ([p0, plain], "sums"),
                          ([p0, p1, p3], "overlap")):
        r = runner.invoke(app, ["merge", *map(str, parts), "-o", out])
        assert r.exit_code == 1 and needle in r.output, (parts, r.output)
    v = _render(tmp_path, scene, "v.exr", "--samples", "2:4", "--method", "vpl")
    r = runner.invoke(app, ["merge", str(p0), str(v), "-o", out])
    assert r.exit_code == 1 and "method" in r.output, r.output


# fixed camera paths per pixel (auto counts follow the passes before: first_path_indices); few light samples
PASS_SCENE = dict(SCENE, render={"spp": 2, "seed": 4, "pbl": {"surface_paths": 2, "surface_samples": 800,
                                                             "bounce_samples": 100, "bounce_generations": 1},
                                 "lut": {"particles": 1000}, "dipole": {"min_samples": 500, "max_samples": 500}})


@pytest.mark.parametrize("method,pbl", [("pbl", {}), ("pbl", {"bin_splits": 0.5}), ("dipole", {}), ("raymarch", {}),
                                        ("vpl", {})])
def test_passes_merge_into_the_whole_render_bit_for_bit(tmp_path, method, pbl):
    """Every pass-based method: parts of passes merge into one render of them all, image and layers, bit for bit
    (light samples, VPLs and irradiance samples are seeded by the pass; the camera paths by the paths before; with
    a fixed path count the bins' extra evaluations follow no pass before)."""
    render = dict(PASS_SCENE["render"], pbl=dict(PASS_SCENE["render"]["pbl"], **pbl))
    scene = write_scene(tmp_path, dict(PASS_SCENE, render=render))
    common = ["--method", method, "--cache-dir", str(tmp_path / "cache")]
    whole = _render(tmp_path, scene, "whole.exr", "--spp", "5", *common)
    parts = [_render(tmp_path, scene, f"p{a}.exr", "--samples", f"{a}:{b}", *common) for a, b in ((0, 1), (1, 5))]
    r = runner.invoke(app, ["merge", *map(str, parts), "-o", str(tmp_path / "merged.exr")])
    assert r.exit_code == 0, r.output
    (a, meta_a), (b, meta_b) = read_exr(whole), read_exr(tmp_path / "merged.exr")
    assert np.array_equal(a, b) and meta_b["samples"] == "0:5" and meta_b["method"] == method
    la, lb = read_layers(whole), read_layers(tmp_path / "merged.exr")
    assert list(la) == list(lb) and all(np.array_equal(la[k], lb[k]) for k in la)
    assert meta_a["surface_paths_per_pass"] == meta_b["surface_paths_per_pass"]
    assert not np.array_equal(a, read_exr(parts[1])[0])


def test_auto_surface_paths_parts_are_independent_and_merge(tmp_path):
    """With auto camera paths a part picks its counts from its own passes and its paths' streams start past any
    that earlier passes use: a part 2:4 is not passes 2 and 3 of a whole render, but it differs from 0:2, and the
    merge of 0:2 and 2:4 is the mean of the two parts (their passes weighed equally)."""
    pbl = dict(PASS_SCENE["render"]["pbl"], surface_paths=0)
    scene = write_scene(tmp_path, dict(PASS_SCENE, render=dict(PASS_SCENE["render"], pbl=pbl)))
    common = ["--method", "pbl", "--cache-dir", str(tmp_path / "cache")]
    p0, p1 = (_render(tmp_path, scene, f"p{a}.exr", "--samples", f"{a}:{a + 2}", *common) for a in (0, 2))
    r = runner.invoke(app, ["merge", str(p0), str(p1), "-o", str(tmp_path / "m.exr")])
    assert r.exit_code == 0, r.output
    a, b, m = read_exr(p0)[0], read_exr(p1)[0], read_exr(tmp_path / "m.exr")[0]
    assert not np.array_equal(a, b)
    np.testing.assert_allclose(m, (a.astype(np.float64) + b) / 2, rtol=1e-6, atol=1e-7)
