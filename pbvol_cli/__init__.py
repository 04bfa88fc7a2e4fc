"""pbvol: rendering participating media behind refractive boundaries."""

__version__ = "0.1.0"
