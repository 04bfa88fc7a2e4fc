"""Image comparison: error metrics, a false-colour error map and a text report.

Convention: ``a`` is the image under test, ``b`` is the reference.
"""

from __future__ import annotations

import math

import numpy as np

from pbvol_cli.errors import PbvolError
from pbvol_cli.imageio import write_png

__all__ = ["image_metrics", "error_image_png", "format_report", "REL_MSE_EPS"]

#: Regulariser in the relative MSE denominator, (a - b)^2 / (b^2 + REL_MSE_EPS).
REL_MSE_EPS = 1e-2

# viridis sampled at 8 equally spaced points (0, 1/7, ..., 1), sRGB 8-bit.
_RAMP = np.array(
    [
        (0x44, 0x01, 0x54),
        (0x46, 0x33, 0x7E),
        (0x36, 0x5C, 0x8D),
        (0x27, 0x7F, 0x8E),
        (0x1F, 0xA1, 0x87),
        (0x4A, 0xC1, 0x6D),
        (0x9F, 0xDA, 0x3A),
        (0xFD, 0xE7, 0x25),
    ],
    dtype=np.float64,
)
_RAMP_POS = np.linspace(0.0, 1.0, len(_RAMP))


def _channel_names(c: int) -> list[str]:
    if c == 3:
        return ["R", "G", "B"]
    if c == 4:
        return ["R", "G", "B", "A"]
    if c == 1:
        return ["Y"]
    return [f"C{i}" for i in range(c)]


def _size(x: np.ndarray) -> str:
    return f"{x.shape[1]}x{x.shape[0]}"


def _nonfinite(x: np.ndarray, label: str) -> str | None:
    nan_px = np.isnan(x).any(axis=2)
    inf_px = np.isinf(x).any(axis=2)
    n_bad = int((nan_px | inf_px).sum())
    if n_bad == 0:
        return None
    return f"{label} has {n_bad} non-finite pixel(s) ({int(nan_px.sum())} NaN, {int(inf_px.sum())} inf)"


def _check_pair(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Validate and convert to float64 (H, W, C). a = test image, b = reference."""
    arrs = []
    for label, x in (("A", a), ("B", b)):
        x = np.asarray(x, dtype=np.float64)
        if x.ndim == 2:
            x = x[:, :, None]
        if x.ndim != 3 or x.shape[0] == 0 or x.shape[1] == 0 or x.shape[2] == 0:
            raise PbvolError(f"image {label} has unusable shape {np.shape(x)}; expected HxWx3")
        arrs.append(x)
    a, b = arrs
    if a.shape[:2] != b.shape[:2]:
        raise PbvolError(f"image sizes differ: A is {_size(a)}, B is {_size(b)}")
    if a.shape[2] != b.shape[2]:
        raise PbvolError(f"channel counts differ: A has {a.shape[2]}, B has {b.shape[2]}")
    problems = [p for p in (_nonfinite(a, "A"), _nonfinite(b, "B")) if p]
    if problems:
        raise PbvolError("non-finite input: " + "; ".join(problems))
    return a, b


def _psnr(mse: float, peak: float) -> float | str:
    if mse == 0.0:
        return "inf"
    return float(10.0 * math.log10(peak * peak / mse))


def flip_map(a, b) -> np.ndarray:
    """The HDR-FLIP error (Andersson et al. 2021, OpenImageIO's FLIP_diff) of test image a against reference b,
    both (H, W, 3) linear radiance: (H, W), 0 (identical) to 1, perceptual; the exposure range up to the
    reference's largest luminance (at least 1)."""
    import OpenImageIO as oiio

    def buf(x):
        x = np.ascontiguousarray(x, dtype=np.float32)
        ib = oiio.ImageBuf(oiio.ImageSpec(x.shape[1], x.shape[0], 3, oiio.FLOAT))
        ib.set_pixels(oiio.ROI(), x)
        return ib

    lum = 0.2126 * b[..., 0] + 0.7152 * b[..., 1] + 0.0722 * b[..., 2]
    peak = max(float(lum.max()), 1.0)  # FLIP's exposures span median 0.18 to the peak: at least 1 (a dim image
    # is judged as seen at unit exposure)
    out = oiio.ImageBufAlgo.FLIP_diff(buf(b), buf(a), hdr=1, maxluminance=peak)
    if out.has_error:
        raise PbvolError(f"FLIP: {out.geterror()}")
    return out.get_pixels(oiio.FLOAT)[..., 0].astype(np.float64)


def image_metrics(a, b, pixel_threshold: float | None = None) -> dict:
    """Error metrics of image ``a`` (test) against the reference ``b``; both (H, W, 3), finite.

    Definitions (mean over all pixels, and over channels for the overall values):

    * ``mse``     = mean((a - b)^2)
    * ``rel_mse`` = mean((a - b)^2 / (b^2 + 1e-2)), the relative MSE as used in pbrt/Mitsuba-style
      rendering papers; ``b`` (the reference) is in the denominator, per pixel and channel, and
      the 1e-2 keeps dark pixels from dominating.
    * ``psnr``    = 10 log10(peak^2 / mse) in dB, with ``peak`` = the maximum value of the
      reference over all channels (the same peak is used for the per-channel PSNRs); if the
      reference is entirely <= 0, peak = 1. ``"inf"`` (a string) when mse is 0.

    * ``flip``    = the mean HDR-FLIP error (flip_map; RGB images only, else absent);
    * with ``pixel_threshold``, idiff-style: ``pixels_over`` = how many pixels differ by more than it in some
      channel, ``pixels_over_percent`` = their share of the image (%).

    Returns a JSON-serialisable dict::

        {"width", "height", "channels", "peak", "mse", "rel_mse", "psnr", "max_abs_error", "flip",
         "per_channel": {"R": {"mse", "rel_mse", "psnr", "max_abs_error"}, "G": ..., "B": ...}}

    Raises PbvolError on a size mismatch ("image sizes differ: A is 256x256, B is 128x128",
    width x height) or non-finite input (pixel counts of NaN/inf and which image).
    """
    a, b = _check_pair(a, b)
    h, w, c = a.shape
    diff = a - b
    sq = diff * diff
    rel = sq / (b * b + REL_MSE_EPS)
    absd = np.abs(diff)

    peak = float(b.max())
    if not peak > 0.0:
        peak = 1.0

    mse = float(sq.mean())
    out: dict = {
        "width": int(w),
        "height": int(h),
        "channels": int(c),
        "peak": peak,
        "mse": mse,
        "rel_mse": float(rel.mean()),
        "psnr": _psnr(mse, peak),
        "max_abs_error": float(absd.max()),
        "per_channel": {},
    }
    if c == 3:
        out["flip"] = float(flip_map(a, b).mean())
    if pixel_threshold is not None:
        over = int((absd > pixel_threshold).any(axis=2).sum())
        out["pixel_threshold"] = float(pixel_threshold)
        out["pixels_over"] = over
        out["pixels_over_percent"] = 100.0 * over / (h * w)
    for i, name in enumerate(_channel_names(c)):
        cm = float(sq[:, :, i].mean())
        out["per_channel"][name] = {
            "mse": cm,
            "rel_mse": float(rel[:, :, i].mean()),
            "psnr": _psnr(cm, peak),
            "max_abs_error": float(absd[:, :, i].max()),
        }
    return out


def _colormap(t: np.ndarray) -> np.ndarray:
    """Map t in [0, 1] (H, W) to uint8 (H, W, 3) along the viridis-like ramp."""
    t = np.clip(t, 0.0, 1.0)
    rgb = np.stack([np.interp(t, _RAMP_POS, _RAMP[:, k]) for k in range(3)], axis=-1)
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)


def error_image_png(a, b, path) -> float:
    """Write a false-colour PNG of the per-pixel absolute error |a - b| (mean over channels).

    The error is divided by its 99th percentile (falling back to the maximum if that is 0) so
    that the 99th percentile maps to the top (yellow) of a viridis-like ramp and larger errors
    saturate. Returns that scale (the error value shown as full yellow; 0.0 for identical images,
    which come out uniformly dark purple). Raises PbvolError like :func:`image_metrics`, or if
    the PNG cannot be written.
    """
    a, b = _check_pair(a, b)
    err = np.abs(a - b).mean(axis=2)
    scale = float(np.percentile(err, 99.0))
    if not scale > 0.0:
        scale = float(err.max())
    t = err / scale if scale > 0.0 else np.zeros_like(err)
    write_png(path, _colormap(t))
    return scale


def _fmt(v) -> str:
    if isinstance(v, str):
        return v
    if v == 0.0:
        return "0"
    return f"{v:.4e}"


def _fmt_psnr(v) -> str:
    if isinstance(v, str):
        return v
    return f"{v:.2f}"


def format_report(metrics: dict, name_a: str, name_b: str) -> str:
    """A human-readable table of :func:`image_metrics` output (``name_b`` is the reference)."""
    lines = [
        f"A (test):      {name_a}",
        f"B (reference): {name_b}",
        f"size: {metrics['width']}x{metrics['height']}, {metrics['channels']} channels, "
        f"PSNR peak {metrics['peak']:.6g}",
        "",
        f"{'channel':<8}{'MSE':>12}{'relMSE':>12}{'PSNR [dB]':>11}{'max |A-B|':>12}",
    ]

    def row(label, m):
        return (
            f"{label:<8}{_fmt(m['mse']):>12}{_fmt(m['rel_mse']):>12}"
            f"{_fmt_psnr(m['psnr']):>11}{_fmt(m['max_abs_error']):>12}"
        )

    lines.append(row("all", metrics))
    for name, m in metrics.get("per_channel", {}).items():
        lines.append(row(name, m))
    if "flip" in metrics:
        lines.append(f"\nFLIP (HDR, mean): {metrics['flip']:.4f}")
    if "pixels_over" in metrics:
        lines.append(f"pixels differing by more than {metrics['pixel_threshold']:g}: {metrics['pixels_over']} "
                     f"({metrics['pixels_over_percent']:.3g} %)")
    return "\n".join(lines)
