"""The on-disk cache: where it is, keys, and atomic writes.

Location: --cache-dir, else $PBVOL_CACHE_DIR, else $XDG_CACHE_HOME/pbvol (default ~/.cache/pbvol).
Entries are written to a temporary file in the same directory and moved into place with os.replace, so a
reader never sees half a file. Each entry carries its own file name (which holds its key) and a checksum of its
arrays: an entry that fails to load, was renamed, was altered or holds NaN is rebuilt, with a line on stderr saying
so. Builders of one entry take a lock, so that two processes build it once; temporary files that a killed run left
behind are removed. A cache that cannot be written (a read-only folder or disk) still serves the entries it holds;
what is missing is built for the run only, with one line on stderr per folder.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import sys
import time
import uuid
import zlib
from pathlib import Path

import numpy as np

from pbvol_cli.errors import PbvolError


def cache_dir(explicit: str | os.PathLike | None = None, for_writing: bool = False) -> Path:
    """The cache folder, created when missing. for_writing (the commands whose job is to fill the cache): refuse
    a folder that cannot be written, naming it; else (render) an unwritable cache is used read-only."""
    if explicit:
        d = Path(explicit)
    elif os.environ.get("PBVOL_CACHE_DIR"):
        d = Path(os.environ["PBVOL_CACHE_DIR"])
    else:
        base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        d = Path(base) / "pbvol"
    problem = unwritable(d)
    if problem and for_writing:
        raise PbvolError(f"cache {d}: cannot write to it ({problem}); choose another with --cache-dir or "
                         f"$PBVOL_CACHE_DIR")
    return d


def unwritable(folder: Path) -> str | None:
    """Why a file cannot be created in folder (made when missing), or None when it can: tried, not guessed
    (permission bits say nothing to root or about a read-only disk)."""
    try:
        Path(folder).mkdir(parents=True, exist_ok=True)
        probe = Path(folder) / f".{uuid.uuid4().hex[:8]}.tmp.probe"  # removed as stale if a kill leaves it
        probe.touch()
        probe.unlink()
    except OSError as e:
        return e.strerror or type(e).__name__
    return None


_REPORTED: set[str] = set()  # unwritable folders already reported (one line per folder and process)


def _report_unwritable(folder: Path, why: str):
    if str(folder) not in _REPORTED:
        _REPORTED.add(str(folder))
        print(f"cache: {folder} cannot be written ({why}): what it lacks is built for this run only",
              file=sys.stderr)


def key_of(**parts) -> str:
    """Stable short hash of the JSON of the given parts (the inputs that determine an entry)."""
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


KEY_FIELD, CHECKSUM_FIELD = "entry_key", "entry_checksum"  # stored beside an entry's arrays
STALE_TEMP_S = 3600.0  # a temporary file this old was left by a killed run (a live writer's is seconds old)


CRC_PREFIX = "crc32:"  # an entry's checksum: "crc32:" and 8 hex digits; older entries hold 64 hex digits (SHA-256)


def checksum(arrays: dict) -> str:
    """CRC-32 of the arrays' names, dtypes, shapes and bytes, in name order, as "crc32:xxxxxxxx". It guards
    against damage, not against tampering: three times faster than SHA-256, whose 22 ms of the oil sphere's 46-MB
    light samples were 2 % of its warm pass (docs/pbl.md, section 12)."""
    crc = 0
    for name, data in _checked_bytes(arrays):
        crc = zlib.crc32(data, zlib.crc32(name, crc))
    return f"{CRC_PREFIX}{crc:08x}"


def _sha256_checksum(arrays: dict) -> str:
    """The checksum of entries written before CRC-32 (SHA-256 of the same bytes, hex): still read."""
    h = hashlib.sha256()
    for name, data in _checked_bytes(arrays):
        h.update(name)
        h.update(data)
    return h.hexdigest()


def _checked_bytes(arrays: dict):
    """(header, bytes) of each array in name order: the header its name, dtype and shape."""
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        header = f"{name}:{a.dtype.str}:{a.shape}".encode()
        try:  # the array's bytes as they lie (tobytes copied 180 MB of light samples first)
            yield header, memoryview(a).cast("B")
        except (TypeError, ValueError):  # (a 0-d array or a dtype a buffer cannot show: the same bytes, copied)
            yield header, a.tobytes()


def checksum_matches(stored: str, arrays: dict) -> bool:
    """Whether the arrays have the checksum stored beside them (either kind)."""
    stored = str(stored)
    return stored == (checksum(arrays) if stored.startswith(CRC_PREFIX) else _sha256_checksum(arrays))


def save_npz_atomic(path: Path, compress: bool = True, **arrays) -> None:
    """Store arrays at path (atomically), with the file's name and the arrays' checksum; zip-compressed unless
    compress is False (np.load reads either)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{uuid.uuid4().hex[:8]}.tmp.npz")
    try:
        stamp = {KEY_FIELD: np.array(path.name), CHECKSUM_FIELD: np.array(checksum(arrays))}
        (np.savez_compressed if compress else np.savez)(tmp, **arrays, **stamp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


_RECORDERS: list[set] = []  # the open entries_used() sets


class entries_used:
    """A context that collects the paths of the cache entries read or built inside it (cached_entry's): what a
    render needs, to ship to machines that do not share this cache (pipeline/distributed.py)."""

    def __enter__(self) -> set:
        self.paths = set()
        _RECORDERS.append(self.paths)
        return self.paths

    def __exit__(self, *exc):
        _RECORDERS.remove(self.paths)


def install_entry(path: Path, data: bytes) -> bool:
    """Put an entry's file, shipped as bytes, at path unless an intact one is there (atomically). Returns whether
    it was written."""
    path = Path(path)
    if _load(path, ())[0] is not None:
        return False
    path.parent.mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(path, data)
    return True


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write data to path through a temporary file in the same folder (.NAME.XXXXXXXX.tmp.SUFFIX, which
    remove_stale_temporaries recognises), renamed over it: a reader never sees half a file."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{uuid.uuid4().hex[:8]}.tmp{path.suffix}")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def cached_entry(path: Path, required: tuple[str, ...], from_arrays, build, force: bool = False,
                 compress: bool = True):
    """(entry, reused): the entry at path rebuilt from its arrays by from_arrays, or, when it is missing, damaged
    (load_npz's reasons, or from_arrays raises ValueError, KeyError or TypeError) or force is set, build()'s, whose
    .arrays() are then stored atomically (compressed unless compress is False: save_npz_atomic). A process that
    finds another building the entry waits for it and takes its result. In a folder that cannot be written the
    entry is read when intact and otherwise built unstored."""
    path = Path(path)
    for used in _RECORDERS:
        used.add(path)
    why = unwritable(path.parent)
    if why:
        _report_unwritable(path.parent, why)
        return _reuse_or_build(path, required, from_arrays, build, force, False, compress)
    remove_stale_temporaries(path.parent)
    with open(path.with_name(f".{path.name}.lock"), "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, also when the process is killed
        return _reuse_or_build(path, required, from_arrays, build, force, True, compress)


def _reuse_or_build(path, required, from_arrays, build, force, store, compress):
    if not force:
        data, problem = _load(path, required)
        if data is not None:
            try:
                return from_arrays(data), True
            except (ValueError, KeyError, TypeError) as e:
                problem = f"unusable ({e})"
        if problem:
            print(f"cache: {path}: {problem}; {'rebuilding it' if store else 'building it for this run'}",
                  file=sys.stderr)
    entry = build()
    if store:
        try:
            save_npz_atomic(path, compress, **entry.arrays())
        except OSError as e:  # the disk filled up or was made read-only during the build: keep the result
            _report_unwritable(path.parent, e.strerror or type(e).__name__)
    return entry, False


def remove_stale_temporaries(folder: Path, age_s: float = STALE_TEMP_S) -> int:
    """Removes the temporary files (.*.tmp.*) in folder older than age_s; returns how many."""
    removed = 0
    now = time.time()
    for tmp in Path(folder).glob(".*.tmp.*"):
        try:
            if now - tmp.stat().st_mtime > age_s:
                tmp.unlink()
                removed += 1
        except OSError:
            pass  # another process removed it, or it cannot be: harmless
    return removed


def load_npz(path: Path, required: tuple[str, ...] = ()) -> dict | None:
    """The entry's arrays, or None when it is missing or damaged (load's reasons)."""
    return _load(Path(path), required)[0]


def _load(path: Path, required: tuple[str, ...]) -> tuple[dict | None, str | None]:
    """(arrays, None), or (None, why not): missing (why None), unreadable, incomplete, stored under another name,
    altered (its checksum) or holding NaN."""
    if not path.exists():
        return None, None
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as e:  # numpy raises many kinds for a truncated or foreign file
        return None, f"unreadable ({type(e).__name__})"
    key, check = data.pop(KEY_FIELD, None), data.pop(CHECKSUM_FIELD, None)
    if key is None or check is None:
        return None, "written by an older version (no checksum)"
    if str(key) != path.name:
        return None, f"holds the entry {str(key)!r}, not this one"
    if any(k not in data for k in required):
        return None, "incomplete"
    if not checksum_matches(check, data):
        return None, "altered or damaged (checksum mismatch)"
    if any(np.issubdtype(a.dtype, np.floating) and np.isnan(a).any() for a in data.values()):
        return None, "holds NaN"
    return data, None
