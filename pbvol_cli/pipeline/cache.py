"""The on-disk cache: where it is, keys, and atomic writes.

Location: --cache-dir, else $PBVOL_CACHE_DIR, else $XDG_CACHE_HOME/pbvol (default ~/.cache/pbvol).
Entries are written to a temporary file in the same directory and moved into place with os.replace, so a
reader never sees half a file; an entry that fails to load is treated as missing and rebuilt.
"""

from __future__ import annotations

import hashlib
import json
import os
import uuid
from pathlib import Path

import numpy as np


def cache_dir(explicit: str | os.PathLike | None = None) -> Path:
    if explicit:
        d = Path(explicit)
    elif os.environ.get("PBVOL_CACHE_DIR"):
        d = Path(os.environ["PBVOL_CACHE_DIR"])
    else:
        base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        d = Path(base) / "pbvol"
    d.mkdir(parents=True, exist_ok=True)
    return d


def key_of(**parts) -> str:
    """Stable short hash of the JSON of the given parts (the inputs that determine an entry)."""
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def save_npz_atomic(path: Path, **arrays) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{uuid.uuid4().hex[:8]}.tmp.npz")
    try:
        np.savez_compressed(tmp, **arrays)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def cached_entry(path: Path, required: tuple[str, ...], from_arrays, build, force: bool = False):
    """(entry, reused): the entry at path rebuilt from its arrays by from_arrays, or, when it is missing, damaged
    (from_arrays raises ValueError, KeyError or TypeError) or force is set, build()'s, whose .arrays() are then
    stored atomically."""
    if not force:
        data = load_npz(path, required)
        if data is not None:
            try:
                return from_arrays(data), True
            except (ValueError, KeyError, TypeError):
                pass  # damaged: rebuilt below
    entry = build()
    save_npz_atomic(path, **entry.arrays())
    return entry, False


def load_npz(path: Path, required: tuple[str, ...] = ()) -> dict | None:
    """The entry's arrays, or None when it is missing or damaged (truncated, unreadable, incomplete)."""
    path = Path(path)
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception:
        return None
    if any(k not in data for k in required):
        return None
    return data
