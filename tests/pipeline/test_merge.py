"""render --samples A:B and pbvol merge: parts merge into the image of one render of their union, bit for bit
(render/sample_sums.py: a canonical tree of additions); mismatched parts, overlaps and gaps are refused."""

import numpy as np
from typer.testing import CliRunner

from conftest import write_scene
from pbvol_cli.imageio import read_exr
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
    r = runner.invoke(app, ["render", str(scene), "-o", out, "--samples", "0:2", "--method", "vpl"])
    assert r.exit_code == 1 and "volpath" in r.output
