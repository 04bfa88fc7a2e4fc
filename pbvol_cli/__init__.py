"""pbvol: rendering participating media behind refractive boundaries."""

from pbvol_cli.kernel_cache import install as _stamp_kernel_caches

__version__ = "0.1.0"

_stamp_kernel_caches()  # before any kernel is defined: cached kernels follow the whole package's source
