"""Image files: float32 EXR output with metadata and extra layers, EXR/any-format input, PNG previews.

All OpenImageIO calls go through here. OIIO does not raise on failure (it returns False/None and
keeps the message in ``geterror()``), so every return value is checked and turned into a
one-line :class:`~pbvol_cli.errors.PbvolError` naming the file. Writes are atomic: the image is
written to a temporary file in the destination directory and moved into place with
:func:`os.replace`, so a crash or failure never leaves a truncated image under the final name.

Metadata
--------
``write_exr`` stores each metadata entry as an EXR header attribute ``pbvol:<key>`` (string, int
or float, visible with ``oiiotool --info -v``). Two OIIO/EXR limitations are worked around so
that ``read_exr`` returns exactly what was written:

* float attributes are stored as float32 and the Python bindings cannot set double attributes,
  and ints outside the int32 range cannot be stored at all;
* the EXR writer silently drops empty string attributes.

For such values an additional string attribute ``pbvol.exact:<key>`` holding ``"float:<repr>"``,
``"int:<value>"`` or ``"str:<value>"`` is written (next to the float32 approximation where one
exists), and ``read_exr`` prefers it. Booleans are stored as ints (0/1).
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from pbvol_cli.errors import PbvolError

__all__ = [
    "write_exr",
    "read_exr",
    "read_layers",
    "tonemap_srgb",
    "write_png",
    "write_preview_png",
]

META_PREFIX = "pbvol:"
EXACT_PREFIX = "pbvol.exact:"
_MAIN = ("R", "G", "B")
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1


# --------------------------------------------------------------------------------------------
# helpers


def _one_line(msg: str) -> str:
    msg = " ".join(str(msg).split())
    return msg or "unknown OpenImageIO error"


def _temp_path(path: Path) -> Path:
    # Same directory (so os.replace is atomic), same extension (OIIO picks the writer by it).
    return path.with_name(f".{path.stem}.{uuid.uuid4().hex[:12]}.tmp{path.suffix}")


def _remove_quietly(p: Path) -> None:
    try:
        p.unlink()
    except OSError:
        pass


def _write_atomic(path, pixels: np.ndarray, spec: oiio.ImageSpec, what: str) -> None:
    """Write C-contiguous ``pixels`` with ``spec`` to ``path`` via a temp file + os.replace."""
    path = Path(path)
    tmp = _temp_path(path)
    out = oiio.ImageOutput.create(str(tmp))
    if out is None:
        raise PbvolError(f"cannot write {what} {path}: {_one_line(oiio.geterror())}")
    ok = False
    try:
        if not out.open(str(tmp), spec):
            raise PbvolError(f"cannot write {what} {path}: {_one_line(out.geterror())}")
        if not out.write_image(pixels):
            err = out.geterror()
            out.close()
            raise PbvolError(f"cannot write {what} {path}: {_one_line(err)}")
        if not out.close():
            raise PbvolError(f"cannot write {what} {path}: {_one_line(out.geterror())}")
        try:
            os.replace(tmp, path)
        except OSError as e:
            raise PbvolError(f"cannot write {what} {path}: {e.strerror or e}") from None
        ok = True
    finally:
        if not ok:
            _remove_quietly(tmp)


def _as_rgb_float(image, name: str) -> np.ndarray:
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"{name} must have shape (H, W, 3), got {arr.shape}")
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{name} is empty: shape {arr.shape}")
    return arr


def _set_metadata(spec: oiio.ImageSpec, metadata: dict) -> None:
    for key, value in metadata.items():
        if not isinstance(key, str) or not key:
            raise ValueError(f"metadata keys must be non-empty strings, got {key!r}")
        name = META_PREFIX + key
        exact_name = EXACT_PREFIX + key
        if isinstance(value, (bool, np.bool_)):
            value = int(value)
        if isinstance(value, np.integer):
            value = int(value)
        elif isinstance(value, np.floating):
            value = float(value)
        elif isinstance(value, np.str_):
            value = str(value)

        if isinstance(value, str):
            if value:
                spec.attribute(name, value)
            else:  # the EXR writer drops empty strings
                spec.attribute(exact_name, "str:")
        elif isinstance(value, int):
            if _INT32_MIN <= value <= _INT32_MAX:
                spec.attribute(name, value)
            else:
                spec.attribute(exact_name, f"int:{value}")
        elif isinstance(value, float):
            spec.attribute(name, "float", value)
            with np.errstate(over="ignore"):
                f32 = np.float32(value)
            if not (float(f32) == value):  # also true for NaN: keep its exact repr
                spec.attribute(exact_name, f"float:{value!r}")
        else:
            raise TypeError(
                f"metadata value for {key!r} must be str, int or float, got {type(value).__name__}"
            )


def _decode_exact(text: str):
    kind, _, rest = text.partition(":")
    if kind == "float":
        return float(rest)
    if kind == "int":
        return int(rest)
    if kind == "str":
        return rest
    return None


def _read_all(path) -> tuple[np.ndarray, oiio.ImageSpec]:
    """Read subimage 0 of any OIIO-readable file as float32 (H, W, C) plus its spec."""
    path = Path(path)
    if not path.exists():
        raise PbvolError(f"cannot read image {path}: no such file")
    if path.is_dir():
        raise PbvolError(f"cannot read image {path}: is a directory")
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise PbvolError(f"cannot read image {path}: {_one_line(oiio.geterror())}")
    try:
        spec = inp.spec()
        px = inp.read_image(oiio.FLOAT)
        if px is None:
            raise PbvolError(f"cannot read image {path}: {_one_line(inp.geterror())}")
    finally:
        inp.close()
    px = np.asarray(px, dtype=np.float32)
    if px.ndim == 2:  # defensive: some bindings return (H, W) for 1 channel
        px = px[:, :, None]
    if px.ndim != 3 or px.shape[2] != spec.nchannels:
        raise PbvolError(f"cannot read image {path}: unexpected pixel layout {px.shape}")
    return px, spec


# --------------------------------------------------------------------------------------------
# EXR


def write_exr(
    path,
    image: np.ndarray,
    metadata: dict[str, str | int | float] | None = None,
    layers: dict[str, np.ndarray] | None = None,
    date_time: str | None = None,
) -> None:
    """Write a float32, zip-compressed RGB EXR, atomically.

    ``image`` is (H, W, 3) (any float dtype, any memory layout). ``metadata`` entries become
    ``pbvol:<key>`` header attributes. ``layers`` maps a layer name to an (H, W, 3) image written
    as channels ``<layer>.R``, ``<layer>.G``, ``<layer>.B`` after the main ``R``, ``G``, ``B``.
    ``date_time`` ("YYYY:MM:DD HH:MM:SS") replaces the writing time that OpenImageIO otherwise stamps, so that
    the same pixels and metadata give the same bytes.
    Raises PbvolError (one line, naming the file) if OpenImageIO fails; ValueError/TypeError for
    malformed arguments.
    """
    img = _as_rgb_float(image, "image")
    h, w = img.shape[:2]
    planes = [img]
    names = list(_MAIN)
    for lname, limg in (layers or {}).items():
        if not isinstance(lname, str) or not lname or lname != lname.strip() or lname.endswith("."):
            raise ValueError(f"invalid layer name {lname!r}")
        larr = _as_rgb_float(limg, f"layer {lname!r}")
        if larr.shape[:2] != (h, w):
            raise ValueError(
                f"layer {lname!r} is {larr.shape[1]}x{larr.shape[0]}, main image is {w}x{h}"
            )
        planes.append(larr)
        names += [f"{lname}.{c}" for c in _MAIN]
    pixels = np.ascontiguousarray(
        np.concatenate(planes, axis=2) if len(planes) > 1 else img, dtype=np.float32
    )

    spec = oiio.ImageSpec(w, h, pixels.shape[2], oiio.FLOAT)
    spec.channelnames = tuple(names)
    spec.attribute("compression", "zip")
    if date_time is not None:
        spec.attribute("DateTime", date_time)
    _set_metadata(spec, metadata or {})
    _write_atomic(path, pixels, spec, "EXR")


def _rgb_indices(names: list[str], prefix: str = "") -> list[int] | None:
    try:
        return [names.index(prefix + c) for c in _MAIN]
    except ValueError:
        return None


def read_exr(path) -> tuple[np.ndarray, dict]:
    """Read the main RGB image and the ``pbvol:`` metadata of any OIIO-readable file.

    Returns ``(image, metadata)``: image is (H, W, 3) float32 (channels ``R, G, B`` by name when
    present; a 1- or 2-channel (Y / YA) file is replicated to RGB; otherwise the first three
    channels, so an alpha channel is dropped). Integer formats such as PNG come back normalised to
    [0, 1] with no colour conversion. ``metadata`` maps keys (prefix removed) to str/int/float.
    Raises PbvolError (one line naming the file) if the file is missing or unreadable.
    """
    px, spec = _read_all(path)
    names = list(spec.channelnames)
    idx = _rgb_indices(names)
    if idx is None:
        if "Y" in names:
            idx = [names.index("Y")] * 3
        elif px.shape[2] < 3:
            idx = [0, 0, 0]
        else:
            idx = [0, 1, 2]
    image = np.ascontiguousarray(px[:, :, idx], dtype=np.float32)

    meta: dict = {}
    exact: dict = {}
    for p in spec.extra_attribs:
        if p.name.startswith(META_PREFIX):
            meta[p.name[len(META_PREFIX):]] = p.value
        elif p.name.startswith(EXACT_PREFIX) and isinstance(p.value, str):
            v = _decode_exact(p.value)
            if v is not None:
                exact[p.name[len(EXACT_PREFIX):]] = v
    meta.update(exact)
    return image, meta


def read_layers(path) -> dict[str, np.ndarray]:
    """Read the extra layers of a file as ``{layer: (H, W, 3) float32}``.

    A layer is the channel-name prefix before the last dot (``albedo.R`` -> ``albedo``). Layers
    with ``R``, ``G``, ``B`` channels are returned as such; a single-channel layer (``depth.Z``)
    is replicated to three channels; layers with any other channel set are skipped.
    Raises PbvolError (one line naming the file) if the file is missing or unreadable.
    """
    px, spec = _read_all(path)
    names = list(spec.channelnames)
    groups: dict[str, list[int]] = {}
    for i, n in enumerate(names):
        if "." in n:
            groups.setdefault(n.rsplit(".", 1)[0], []).append(i)
    result: dict[str, np.ndarray] = {}
    for lname, chans in groups.items():
        if not lname:
            continue
        idx = _rgb_indices(names, lname + ".")
        if idx is None:
            if len(chans) != 1:
                continue
            idx = chans * 3
        result[lname] = np.ascontiguousarray(px[:, :, idx], dtype=np.float32)
    return result


# --------------------------------------------------------------------------------------------
# PNG / tone mapping


def tonemap_srgb(image: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """Linear radiance -> 8-bit sRGB.

    Multiplies by ``2**exposure``, clamps to [0, 1] (NaN -> 0, +inf -> 1, -inf -> 0), applies the
    exact piecewise sRGB OETF (12.92 x for x <= 0.0031308, else 1.055 x^(1/2.4) - 0.055) and
    rounds to the nearest uint8. The output has the input's shape (normally (H, W, 3)).
    """
    x = np.asarray(image, dtype=np.float64) * (2.0 ** float(exposure))
    x = np.nan_to_num(x, nan=0.0, posinf=1.0, neginf=0.0)
    x = np.clip(x, 0.0, 1.0)
    y = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return np.clip(np.rint(y * 255.0), 0, 255).astype(np.uint8)


def write_png(path, image_uint8: np.ndarray) -> None:
    """Write an 8-bit (H, W, 3) (or (H, W), (H, W, 1), (H, W, 4)) image as PNG, atomically.

    Raises PbvolError (one line naming the file) if OpenImageIO fails.
    """
    arr = np.asarray(image_uint8)
    if arr.dtype != np.uint8:
        raise TypeError(f"write_png expects a uint8 array, got {arr.dtype}")
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or arr.shape[2] not in (1, 3, 4) or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"write_png expects shape (H, W, 3), got {np.asarray(image_uint8).shape}")
    pixels = np.ascontiguousarray(arr)
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, oiio.UINT8)
    _write_atomic(path, pixels, spec, "PNG")


def write_preview_png(path, image: np.ndarray, exposure: float = 0.0) -> None:
    """Tone-map a linear (H, W, 3) image with :func:`tonemap_srgb` and write it as PNG."""
    write_png(path, tonemap_srgb(image, exposure))
