"""numba's cached kernels kept in step with the whole package's source.

numba keys a cached kernel to the file that defines it, but a kernel's machine code also holds what it calls from
other modules, inlined or linked (physics/sampling.stratified_depth inside gather._segment and
radiance_cache._scattered_points), and the module constants it reads, frozen at compile time. After a change to
such a callee or constant alone (an edit, a `git pull` over the editable install, an upgrade in place), numba would
load the callers' old machine code and render with the old callee, silently. So every pbvol kernel's cache entry is
stamped here with a hash of all the package's source files as well: any change to them compiles the kernels again
on first use (a minute or two on 2 cores), then they are cached again."""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent


@functools.cache
def package_stamp() -> str:
    """sha256 of the package's source files (their paths within it and their bytes), hex."""
    h = hashlib.sha256()
    for path in sorted(PACKAGE.rglob("*.py")):
        h.update(path.relative_to(PACKAGE).as_posix().encode())
        h.update(b"\0")
        h.update(path.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def in_package(py_file: str) -> bool:
    """Whether the source file py_file lies in this package."""
    try:
        return Path(py_file).resolve().is_relative_to(PACKAGE)
    except (OSError, ValueError):
        return False


def install() -> bool:
    """Puts the package-stamped locator first in numba's cache locators (once per process; the kernels defined
    after this take it). Returns False where numba's caching internals are not as expected (the kernels are then
    cached as numba does by itself)."""
    try:
        from numba.core import caching

        impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl  # (the name of numba >= 0.61, and before)
        locators = impl._locator_classes
        base = caching._CacheLocator
    except (ImportError, AttributeError):
        return False
    if any(getattr(cls, "pbvol_package_stamp", False) for cls in locators):
        return True
    inner_classes = list(locators)

    class PackageStampedLocator(base):
        """numba's own locator for the function (the same place for its files), with the package's stamp added to
        the source file's: an entry written under another stamp reads as stale and is compiled and written anew."""

        pbvol_package_stamp = True

        def __init__(self, inner):
            self._inner = inner

        def ensure_cache_path(self):
            self._inner.ensure_cache_path()

        def get_cache_path(self):
            return self._inner.get_cache_path()

        def get_source_stamp(self):
            return self._inner.get_source_stamp(), package_stamp()

        def get_disambiguator(self):
            return self._inner.get_disambiguator()

        @classmethod
        def from_function(cls, py_func, py_file):
            if not in_package(py_file):
                return None
            for inner_cls in inner_classes:
                inner = inner_cls.from_function(py_func, py_file)
                if inner is not None:
                    return cls(inner)
            return None

    locators.insert(0, PackageStampedLocator)
    return True
