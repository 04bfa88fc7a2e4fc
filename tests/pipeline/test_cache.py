"""The cache's entries: reused when intact; rebuilt, saying so, when damaged, renamed, altered or holding NaN;
built once by concurrent builders; temporary files of killed runs removed; an unwritable cache read, not written."""

import os
import threading
import time

import numpy as np

import pytest

from pbvol_cli.errors import PbvolError
from pbvol_cli.pipeline import cache as cache_module
from pbvol_cli.pipeline.cache import cache_dir, cached_entry, remove_stale_temporaries, save_npz_atomic


class Entry:
    def __init__(self, values):
        self.values = np.asarray(values, float)

    def arrays(self):
        return {"values": self.values}

    @classmethod
    def from_arrays(cls, data):
        return cls(data["values"])


def _get(path, builds, value=1.0, delay=0.0):
    def build():
        time.sleep(delay)
        builds.append(threading.get_ident())
        return Entry([value, 2.0, 3.0])

    return cached_entry(path, ("values",), Entry.from_arrays, build)


def test_an_intact_entry_is_reused_and_a_damaged_one_rebuilt_with_a_message(tmp_path, capsys):
    path = tmp_path / "entry_abc.npz"
    builds = []
    entry, reused = _get(path, builds)
    assert not reused and len(builds) == 1
    entry, reused = _get(path, builds)
    assert reused and len(builds) == 1 and entry.values[0] == 1.0
    assert capsys.readouterr().err == ""
    cases = {
        "truncated": lambda: path.write_bytes(path.read_bytes()[:100]),
        "altered": lambda: _rewrite(path, values=np.array([9.0, 2.0, 3.0])),
        "holds NaN": lambda: save_npz_atomic(path, values=np.array([np.nan, 2.0, 3.0])),  # a valid checksum
        "renamed": lambda: os.replace(_other(tmp_path), path),
        "older version": lambda: np.savez(path, values=np.array([1.0, 2.0, 3.0])),
    }
    for what, damage in cases.items():
        damage()
        entry, reused = _get(path, builds)
        err = capsys.readouterr().err
        assert not reused and entry.values[0] == 1.0, what
        assert err.count("\n") == 1 and str(path) in err and "rebuilding" in err, (what, err)
    assert len(builds) == 1 + len(cases)


def _rewrite(path, **changes):
    """The entry's file with some arrays replaced and its stamp (name, checksum) kept: damage a checksum finds."""
    with np.load(path) as z:
        data = {k: z[k] for k in z.files}
    data.update(changes)
    np.savez_compressed(path, **data)


def _other(folder):
    other = folder / "entry_other.npz"
    save_npz_atomic(other, values=np.array([1.0, 2.0, 3.0]))
    return other


def test_concurrent_builders_build_an_entry_once(tmp_path):
    path = tmp_path / "entry_shared.npz"
    builds, results = [], []
    threads = [threading.Thread(target=lambda: results.append(_get(path, builds, delay=0.3))) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(builds) == 1
    assert sorted(reused for _, reused in results) == [False, True, True]


def test_temporary_files_of_killed_runs_are_removed(tmp_path):
    old, fresh = tmp_path / ".entry_x.1234abcd.tmp.npz", tmp_path / ".entry_y.5678abcd.tmp.npz"
    old.write_bytes(b"partial")
    fresh.write_bytes(b"being written")
    os.utime(old, (time.time() - 7200, time.time() - 7200))
    assert remove_stale_temporaries(tmp_path) == 1
    assert not old.exists() and fresh.exists()


def test_an_unwritable_cache_serves_what_it_holds_and_builds_the_rest_unstored(tmp_path, monkeypatch, capsys):
    held = tmp_path / "entry_held.npz"
    builds = []
    _get(held, builds)
    capsys.readouterr()
    # permission bits do not stop root: a read-only disk is what the probe meets
    monkeypatch.setattr(cache_module, "unwritable", lambda folder: "Read-only file system")
    entry, reused = _get(held, builds)
    assert reused and len(builds) == 1
    missing = tmp_path / "entry_missing.npz"
    for _ in range(2):
        entry, reused = _get(missing, builds, value=7.0)
        assert not reused and entry.values[0] == 7.0 and not missing.exists()
    assert len(builds) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Read-only file system" in err and "for this run only" in err, err


def test_a_cache_folder_that_cannot_exist_is_named(tmp_path):
    (tmp_path / "file").write_text("not a folder")
    assert cache_module.unwritable(tmp_path / "file" / "cache")
    assert cache_module.unwritable(tmp_path / "fine") is None and (tmp_path / "fine").is_dir()
    assert not list((tmp_path / "fine").iterdir())  # the probe is gone
    with pytest.raises(PbvolError, match="file/cache: cannot write to it"):
        cache_dir(tmp_path / "file" / "cache", for_writing=True)
    assert cache_dir(tmp_path / "file" / "cache") == tmp_path / "file" / "cache"  # read-only use: no error


def test_an_uncompressed_entry_is_stored_unzipped_reused_and_rebuilt_when_altered(tmp_path, capsys):
    """compress=False (the light samples': zip saves them little and costs most of their read) stores the arrays
    as they are; the checksum still finds an altered entry."""
    import zipfile

    path = tmp_path / "entry_plain.npz"
    builds = []

    def get():
        return cached_entry(path, ("values",), Entry.from_arrays,
                            lambda: builds.append(1) or Entry([1.0, 2.0, 3.0]), compress=False)

    entry, reused = get()
    with zipfile.ZipFile(path) as z:
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_STORED}
    assert get()[1] and len(builds) == 1
    _rewrite(path, values=np.array([9.0, 2.0, 3.0]))
    entry, reused = get()
    assert not reused and entry.values[0] == 1.0 and "rebuilding" in capsys.readouterr().err


def test_light_samples_are_stored_uncompressed(tmp_path):
    import zipfile

    from conftest import medium_sphere_scene, write_scene
    from pbvol_cli import config as C
    from pbvol_cli.geometry.scene_build import build_scene
    from pbvol_cli.pipeline.samples import get_light_samples

    path = write_scene(tmp_path, medium_sphere_scene(surface_samples=300, segments_per_beam=2))
    scene = C.load_scene(path)
    r = get_light_samples(build_scene(scene, path), scene.render.pbl, 1, tmp_path / "c", 1)
    with zipfile.ZipFile(r.path) as z:
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_STORED}


def test_entries_stamped_with_sha256_are_still_read_and_still_checked(tmp_path, capsys):
    """New entries carry a CRC-32 ("crc32:" and 8 hex digits); an entry written with the former SHA-256 stamp is
    reused as it is, and rebuilt when its arrays were altered under that stamp."""
    path = tmp_path / "entry_legacy.npz"
    builds = []
    _get(tmp_path / "entry_new.npz", builds)
    with np.load(tmp_path / "entry_new.npz") as z:
        stamp = str(z[cache_module.CHECKSUM_FIELD])
    assert stamp.startswith("crc32:") and len(stamp) == 14
    values = np.array([1.0, 2.0, 3.0])
    legacy = cache_module._sha256_checksum({"values": values})
    assert len(legacy) == 64
    np.savez(path, values=values, **{cache_module.KEY_FIELD: np.array(path.name),
                                      cache_module.CHECKSUM_FIELD: np.array(legacy)})
    entry, reused = _get(path, builds)
    assert reused and len(builds) == 1 and capsys.readouterr().err == ""
    _rewrite(path, values=np.array([9.0, 2.0, 3.0]))
    entry, reused = _get(path, builds)
    assert not reused and entry.values[0] == 1.0 and "checksum mismatch" in capsys.readouterr().err
