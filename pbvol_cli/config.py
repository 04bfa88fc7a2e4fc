"""Scene and material files: Pydantic models, TOML in, and one-line errors (docs/scene-format.md is generated
from these models: config_reference.py).

Conventions:
- Lengths are in scene units; a scene states what one unit is (``unit = "mm"`` etc.).
- A material gives, per RGB channel, either (albedo, mean_free_path), (sigma_a, sigma_s), or
  (sigma_s_reduced, sigma_a) as in Jensen et al. 2001, where sigma_s = sigma_s_reduced / (1 - g).
  Its ``length_unit`` says what length its coefficients refer to ("scene" takes them as they are);
  ``scale`` multiplies sigma_a and sigma_s (a density scale).
- Colours and coefficients accept a single number (grey) or three (RGB).
"""

from __future__ import annotations

import math
import os
import tomllib
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, Union

import numpy as np
from pydantic import Strict as NoCoercion
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PlainValidator,
    ValidationError,
    WithJsonSchema,
    field_validator,
    model_validator,
)

from pbvol_cli.errors import ConfigError

# Lengths of the units a scene or a material may be expressed in, in metres.
UNIT_METRES = {"mm": 1e-3, "cm": 1e-2, "m": 1.0, "um": 1e-6, "in": 0.0254}


def _rgb(value: Any) -> Any:
    """Accept a scalar (grey) or a length-3 sequence."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return [float(value)] * 3
    return value


def _rgb_schema(**bounds) -> WithJsonSchema:
    """The JSON schema of a colour field: one number (grey) or three (RGB), each within bounds."""
    number = {"type": "number", **bounds}
    return WithJsonSchema({"anyOf": [number, {"type": "array", "items": number, "minItems": 3, "maxItems": 3}],
                           "description": "one number (grey: the same for R, G and B) or [R, G, B]"})


# Numbers as TOML writes them: a bool is not a number (`fov = true` is refused, not read as 1), an integer is a
# float; NaN and infinity are refused by the models' config (allow_inf_nan).
Num = Annotated[float, NoCoercion()]
Int = Annotated[int, NoCoercion()]
Bool = Annotated[bool, NoCoercion()]
RGB = Annotated[tuple[Num, Num, Num], BeforeValidator(_rgb), _rgb_schema()]



def _auto_or_positive(value: Any) -> float | str:
    if value == "auto":
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ValueError(f'expected a number > 0 or "auto", got {value!r}')
    return float(value)


# A setting that is a positive number or "auto" (chosen per medium): one error message for both.
AutoOrPositive = Annotated[float | Literal["auto"], PlainValidator(_auto_or_positive),
                           WithJsonSchema({"anyOf": [{"type": "number", "exclusiveMinimum": 0}, {"const": "auto"}]})]

# Geometry's numbers (positions, sizes, scale factors) within +-MAX_COORD: beyond it the single-precision geometry
# the ray tracer holds has no precision left (and at 3e38 it overflows).
MAX_COORD = 1e9
Coord = Annotated[float, NoCoercion(), Field(ge=-MAX_COORD, le=MAX_COORD)]
Vec3 = tuple[Coord, Coord, Coord]


def _albedo(v):
    if not all(0.0 <= a <= 1.0 for a in v):
        raise ValueError(f"expected albedo in [0, 1] per channel, got {list(v)}")
    return v


def _positive_lengths(v):
    if not all(math.isfinite(x) and x > 0 for x in v):
        raise ValueError(f"expected positive lengths, got {list(v)}")
    return v


def _positive_sizes(v):
    if not all(math.isfinite(x) and 0 < x <= MAX_COORD for x in v):
        raise ValueError(f"expected positive sizes up to {MAX_COORD:g}, got {list(v)}")
    return v


def _non_negative(v):
    if not all(math.isfinite(x) and x >= 0 for x in v):
        raise ValueError(f"expected non-negative values, got {list(v)}")
    return v


def _eta(v):
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"expected eta > 0, got {v}")
    return v


# Constrained types, one place per rule.
Albedo = Annotated[RGB, AfterValidator(_albedo), _rgb_schema(minimum=0, maximum=1)]
Lengths3 = Annotated[RGB, AfterValidator(_positive_lengths), _rgb_schema(exclusiveMinimum=0)]
Sizes3 = Annotated[RGB, AfterValidator(_positive_sizes), _rgb_schema(exclusiveMinimum=0, maximum=MAX_COORD)]
Coefficients = Annotated[RGB, AfterValidator(_non_negative), _rgb_schema(minimum=0)]
Emission = Coefficients  # a light's radiance, intensity, irradiance or power: a negative one would subtract light
Eta = Annotated[float, AfterValidator(_eta), WithJsonSchema({"type": "number", "exclusiveMinimum": 0})]


def _finite(v: tuple[float, ...], what: str) -> tuple[float, ...]:
    if not all(math.isfinite(x) for x in v):
        raise ValueError(f"expected finite {what}, got {list(v)}")
    return v


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


# --------------------------------------------------------------------------- materials


class GridDensity(Strict):
    """A density grid (seed 003, "VolumeGridDensity"): the voxels of a 3D array stretched over a box, trilinear
    between voxel centres, 0 outside the box."""

    type: Literal["grid"]
    file: str = Field(description="an .npz file, relative to the scene file, holding a 3D float array `density` "
                      "(x, y, z order; values >= 0); OpenVDB .vdb files are not read (no maintained Python reader "
                      "on PyPI: convert them to .npz)")
    bounds: tuple[Vec3, Vec3] = Field(description="the box [[x0, y0, z0], [x1, y1, z1]] the grid spans, scene units")
    scale: Num = Field(1.0, ge=0, le=MAX_COORD, description="multiplies the grid's values")
    emission_key: str | None = Field(None, description="a second array in the file, the same shape, scaling "
                                     "`emission` voxel by voxel (a flame's temperature); default: emission is "
                                     "uniform")

    @model_validator(mode="after")
    def _box(self):
        if not all(a < b for a, b in zip(*self.bounds)):
            raise ValueError(f"bounds: expected [[x0, y0, z0], [x1, y1, z1]] with x0 < x1, y0 < y1, z0 < z1, got "
                             f"{[list(v) for v in self.bounds]}")
        return self


class ExponentialDensity(Strict):
    """Density a e^(-b h), h the height above `origin` along `up` (seed 003, "ExponentialDensity"): fog that thins
    with height."""

    type: Literal["exponential"]
    a: Num = Field(ge=0, le=MAX_COORD, description="the density at height 0")
    b: Num = Field(ge=-1e6, le=1e6, description="how fast it falls with height, per scene unit")
    up: Vec3 = Field((0.0, 1.0, 0.0), description="the direction heights are measured along (need not be unit)")
    origin: Vec3 = Field((0.0, 0.0, 0.0), description="where the height is 0, scene units")

    @field_validator("up")
    @classmethod
    def _nz(cls, v):
        if np.linalg.norm(v) == 0:
            raise ValueError("expected a non-zero direction")
        return v


Density = Annotated[Union[GridDensity, ExponentialDensity], Field(discriminator="type")]


class Material(Strict):
    """A participating medium, homogeneous unless it has a `density`. Give exactly one pair of coefficients, per
    RGB channel: (albedo, mean_free_path), (sigma_a, sigma_s), or (sigma_s_reduced, sigma_a) as in Jensen et al.
    2001."""

    name: str | None = Field(None, description="a label for messages and metadata")
    source: str | None = Field(None, description="where the numbers come from (free text)")
    length_unit: Literal["scene", "mm", "cm", "m", "um", "in"] = Field(
        "scene", description="the length the coefficients are per: 'scene' takes them as they are; a physical unit "
        "converts them to the scene's `unit`")
    albedo: Albedo | None = Field(None, description="single-scattering albedo sigma_s / sigma_t, in [0, 1]; "
                                  "with mean_free_path")
    mean_free_path: Lengths3 | None = Field(None, description="1 / sigma_t, in length_unit; with albedo")
    sigma_a: Coefficients | None = Field(None, description="absorption coefficient, 1/length_unit; with sigma_s "
                                         "or sigma_s_reduced")
    sigma_s: Coefficients | None = Field(None, description="scattering coefficient, 1/length_unit; with sigma_a")
    sigma_s_reduced: Coefficients | None = Field(None, description="reduced scattering coefficient (1 - g) sigma_s, "
                                                 "1/length_unit; with sigma_a (sigma_s = sigma_s_reduced / (1 - g))")
    g: Num = Field(0.0, description="mean cosine of the phase function, -1 < g < 1 (0: isotropic)",
                     json_schema_extra={"exclusiveMinimum": -1, "exclusiveMaximum": 1})
    phase: Literal["isotropic", "hg", "schlick", "rayleigh", "mie_hazy", "mie_murky"] = Field(
        "hg", description="phase function: Henyey-Greenstein, Schlick's approximation of it (both with g), "
        "isotropic, Rayleigh, or the hazy / murky Mie lobes of Nishita et al.")
    eta: Eta = Field(1.0, description="refractive index of the medium, the default index of a dielectric shape "
                     "holding it")
    scale: Num = Field(1.0, description="density: multiplies sigma_a and sigma_s",
                         json_schema_extra={"exclusiveMinimum": 0})
    diffuse_reflectance: Albedo | None = Field(None, description="informational only (Jensen et al. 2001's "
                                               "measured R_d); not used by the renderer")
    density: Density | None = Field(None, description="a spatially varying density multiplying sigma_a and "
                                    "sigma_s (`type` grid or exponential); only `volpath` renders it")
    emission: Emission | None = Field(None, description="emitted radiance L_e, RGB: the medium adds sigma_a(x) "
                                      "L_e per unit length (so it scales with the density; a thick absorbing body "
                                      "of it glows with radiance L_e); only `volpath` renders it")

    @field_validator("g")
    @classmethod
    def _g(cls, v):
        if not (math.isfinite(v) and -1.0 < v < 1.0):
            raise ValueError(f"expected |g| < 1, got {v}")
        return v

    @field_validator("scale")
    @classmethod
    def _scale(cls, v):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"expected scale > 0, got {v}")
        return v

    # The accepted parameterisations, each a pair of fields.
    FORMS: ClassVar[dict[str, tuple[str, str]]] = {
        "albedo": ("albedo", "mean_free_path"),
        "sigma": ("sigma_a", "sigma_s"),
        "reduced": ("sigma_s_reduced", "sigma_a"),
    }

    def _form(self) -> str | None:
        """Which parameterisation is complete (sigma_s_reduced takes precedence over sigma_s)."""
        if self.sigma_s_reduced is not None and self.sigma_a is not None:
            return "reduced"
        for key, (a, b) in self.FORMS.items():
            if getattr(self, a) is not None and getattr(self, b) is not None:
                return key
        return None

    @model_validator(mode="after")
    def _one_form(self):
        names = ", ".join(f"({a}, {b})" for a, b in self.FORMS.values())
        form = self._form()
        if form is None:
            raise ValueError(f"expected exactly one of {names}")
        used = set(self.FORMS[form])
        stray = [f for f in ("albedo", "mean_free_path", "sigma_a", "sigma_s", "sigma_s_reduced")
                 if f not in used and getattr(self, f) is not None]
        if stray:
            raise ValueError(f"{', '.join(stray)} cannot be combined with {self.FORMS[form]}; "
                             f"expected exactly one of {names}")
        _finite_coefficients(*self.coefficients(self.length_unit))
        return self

    def coefficients(self, scene_unit: str = "scene") -> tuple[np.ndarray, np.ndarray]:
        """(sigma_a, sigma_s) per RGB channel, in 1/scene-unit (float64 arrays of 3; infinite where they overflow,
        which the validators refuse)."""
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            return self._coefficients(scene_unit)

    def _coefficients(self, scene_unit: str) -> tuple[np.ndarray, np.ndarray]:
        form = self._form()
        if form == "albedo":
            alb = np.asarray(self.albedo, float)
            st = 1.0 / np.asarray(self.mean_free_path, float)
            sa, ss = st * (1.0 - alb), st * alb
        elif form == "reduced":
            sa = np.asarray(self.sigma_a, float)
            ss = np.asarray(self.sigma_s_reduced, float) / (1.0 - self.g)
        else:
            sa, ss = np.asarray(self.sigma_a, float), np.asarray(self.sigma_s, float)
        factor = self.scale * length_conversion(self.length_unit, scene_unit)
        return sa * factor, ss * factor


def _finite_coefficients(sigma_a: np.ndarray, sigma_s: np.ndarray):
    """Refuse coefficients that overflow (a mean free path of 1e-320, a huge scale): sigma_t would be infinite
    and the albedo NaN."""
    if not (np.all(np.isfinite(sigma_a)) and np.all(np.isfinite(sigma_s)) and np.all(np.isfinite(sigma_a + sigma_s))):
        raise ValueError(f"coefficients overflow: sigma_a {[float(x) for x in sigma_a]}, sigma_s "
                         f"{[float(x) for x in sigma_s]}; expected finite values (a mean free path or scale out of "
                         "range)")


def length_conversion(material_unit: str, scene_unit: str) -> float:
    """Factor turning a coefficient per material_unit into one per scene_unit."""
    if material_unit == "scene" or scene_unit == "scene":
        if material_unit != scene_unit and material_unit != "scene":
            raise ValueError(
                f"material coefficients are per {material_unit} but the scene has no physical unit; "
                "set the scene's 'unit'"
            )
        return 1.0
    # sigma [1/mat] -> [1/scene]: one scene unit is UNIT[scene]/UNIT[mat] material units.
    return UNIT_METRES[scene_unit] / UNIT_METRES[material_unit]


# --------------------------------------------------------------------------- camera, settings


# Bounds the command line's options share with the scene's fields.
MAX_SPP = 1 << 24
MAX_DEPTH = 10_000_000
MAX_SEED = 2**32 - 1
MAX_THREADS = 1024
MAX_RESOLUTION = 16384


class Camera(Strict):
    """A pinhole camera."""

    position: Vec3 = Field(description="the eye, scene units")
    look_at: Vec3 = Field(description="the point at the image's centre, scene units")
    up: Vec3 = Field((0.0, 1.0, 0.0), description="the direction that is up in the image (not parallel to the "
                     "viewing direction)")
    fov: Num = Field(40.0, description="full vertical field of view, degrees",
                       json_schema_extra={"exclusiveMinimum": 0, "exclusiveMaximum": 180})
    resolution: tuple[Int, Int] = Field((256, 256), description="[width, height] in pixels, 1 to 16384 each")

    @field_validator("fov")
    @classmethod
    def _fov(cls, v):
        if not 0.0 < v < 180.0:
            raise ValueError(f"expected a field of view in (0, 180) degrees, got {v}")
        return v

    @field_validator("resolution")
    @classmethod
    def _res(cls, v):
        if not all(1 <= x <= MAX_RESOLUTION for x in v):
            raise ValueError(f"expected [width, height] between 1 and {MAX_RESOLUTION}, got {list(v)}")
        return v

    @model_validator(mode="after")
    def _geometry(self):
        _finite(self.position, "position")
        d = np.subtract(self.look_at, self.position)
        if np.linalg.norm(d) == 0:
            raise ValueError("look_at must differ from position")
        if np.linalg.norm(np.cross(d, self.up)) < 1e-9 * np.linalg.norm(d) * max(np.linalg.norm(self.up), 1e-30):
            raise ValueError("up must not be parallel to the viewing direction")
        return self


class VolpathSettings(Strict):
    """The reference path tracer (`--method volpath`)."""

    rr_depth: Int = Field(8, ge=0, le=MAX_DEPTH, description="bounce count from which Russian roulette applies")
    split_depth: Int = Field(3, ge=0, le=16, description="interactions of a path that has not scattered yet at "
                             "which a smooth boundary's reflection and refraction are both followed (0: one of the two "
                             "chosen)")
    split_rule: Literal["auto", "all", "lights"] = Field(
        "auto", description="which of those interactions split: \"lights\" only where the reflection points at a "
        "light (its mirror image); \"all\" every one (also the light's glints inside a glass body, for a path per "
        "branch); \"auto\": \"lights\" in scenes with triangle meshes (each branch segment a ray cast), \"all\" "
        "in the others")
    batch_paths: Int = Field(1 << 19, ge=1024, le=1 << 24,
                             description="paths traced per wavefront batch (memory vs. overhead)")


class LutSettings(Strict):
    """The multiple-scattering table (precompute-lut). Lengths in mean free paths."""

    particles: Int | None = Field(None, ge=1000, description="particles simulated per table (default: as many as "
                                  "the collision budget allows)")
    collision_budget: Int = Field(80_000_000, ge=100_000, le=10**12, description="collisions simulated per table when "
                                  "particles is not given")
    seed: Int = Field(0, ge=0, le=MAX_SEED, description="the simulation's random seed")
    extent: AutoOrPositive = Field(
        "auto", description="table half-size, mean free paths (light diffusing beyond it is lost to pbl); "
        "\"auto\": per medium, what its body needs, from 40 (two diffusion lengths or the body's smallest side, "
        "whichever is less, up to 320: multiple_scattering/extent.py)")
    sh_order: Int = Field(12, ge=2, le=24, description="spherical-harmonics order of the stored lobes")
    merge_tol: Num = Field(0.05, ge=0, description="relative difference of lobe shapes below which neighbouring "
                             "cells share one (quadtree merge)")



class PblSettings(Strict):
    """The point-based method: light samples and their use along camera rays (defaults: what the benchmark uses)."""

    surface_samples: Int = Field(20000, ge=16, le=10**8,
                                 description="light surface samples (blue noise) on the outer layers "
                                 "of the medium-holding shapes, about")
    segments_per_beam: Int = Field(16, ge=1, le=1024, description="volume samples per beam and internal reflection")
    max_internal_reflections: Int = Field(8, ge=0, le=64, description="internal reflections a beam is followed through")
    max_layers: Int = Field(8, ge=1, le=64, description="transparent interfaces a beam may cross to reach the medium")
    beam_width: Num = Field(2.0, ge=0.5, description="single scattering's kernel radius over the beam's radius "
                              "(wider: less noise from the light samples, more blur)")
    kmax: Int = Field(2, ge=1, le=64,
                      description="points per camera-ray segment in a medium for single scattering (eq. 9; the "
                      "paper's 4 cost more than their lower noise is worth: docs/pbl.md)")
    kmax_scattered: Int = Field(4, ge=1, le=64,
                                description="points per segment at most for double, multiple and bounced light "
                                "(smooth along rays): one per mean free path of the segment's least dense channel, "
                                "at least one (dense media: their depth was most of the noise; docs/pbl.md)")
    cache_cell: Num = Field(0.5, ge=0, description="double, multiple and bounced light are evaluated once per "
                            "cell and direction bin, at a random camera point of it, and shared by the others (a blur "
                            "of about a cell): the cells' depth below the boundary, mean free paths of the densest "
                            "channel; 0: at every point")
    cache_lateral: Num = Field(2.0, ge=0, description="the cells' width along the boundary, mean free paths (at "
                               "least cache_cell, at most an eighth of the medium's size; wider cells are cut in "
                               "slices cache_cell deep below the boundary, where the terms change fastest)")
    cache_directions: Int = Field(8, ge=1, le=64, description="direction bins per cube-map face for cache_cell "
                                  "(8: about 11 degrees wide)")
    bounced_bins: Num = Field(1.0, ge=1, le=8, description="the bounced light's bins this many times the "
                              "lights' in depth, width and direction: fewer evaluations and more blur, worth it where "
                              "the bounced light is a small share of the image (the oil sphere: 2; docs/pbl.md)")
    term_shares: Bool = Field(True, description="a bin evaluates the lesser of double and multiple scattering (by "
                              "its second moment in the pass so far) at a random share of the bins, weighted by its "
                              "inverse: unbiased, less time for the same noise (docs/pbl.md); false: every bin both")
    bin_splits: Num = Field(0.0, ge=0, le=8, description="a pass evaluates its smooth terms' bins once each and this "
                            "share of their number again, dealt to the bins whose noise weighs most in the image (by "
                            "their points' weights per pixel; unbiased). Pays where the image's noise is the smooth "
                            "terms' (milk, wax: 0.5), costs where it is the surfaces' (docs/pbl.md); 0: once each")
    diffuse_shares: Bool = Field(True, description="the camera rays after a diffuse bounce evaluate the medium's "
                                 "smooth terms on a share of them from the third pass on, by the splitting optimum of "
                                 "their measured second moment against the pass's variance, weighted by its inverse "
                                 "(unbiased; docs/pbl.md), with surface_paths = 0 (auto: a pass follows the passes "
                                 "before); false, or a fixed surface_paths: all of them")
    diffuse_filter: Num = Field(4.0, ge=0, le=64, description="the medium's light that camera paths find after their "
                                "first diffuse bounce, pooled among the first diffuse vertices of a pass in cubes "
                                "this many pixel footprints wide (path-space filtering: the glow of a medium on a "
                                "table converges with the medium, blurred over about a cell; the milk glass's "
                                "error halved at two and eight passes; docs/pbl.md); 0: each path's own")
    similarity: Literal["none", "truncated", "delta-eddington"] = Field(
        "none", description="a strong forward lobe (g near 0.9) under a large light is sampled by few beam directions "
        "and gives pbl spikes; these fold its forward peak into the beams as unscattered light. truncated: each "
        "Henyey-Greenstein medium of g > 0 has its lobe capped at its value 26 degrees off its axis and renormalised "
        "(sigma_s x 0.30 at g 0.9), the phase function exact beyond: a bias from light deflected by less than that, "
        "half the delta-Eddington transform's on the bumpy sphere at eight passes, a little more noise at one. "
        "delta-eddington: a forward delta of weight g^2 (sigma_s x (1 - g^2), g / (1 + g); the transport coefficient "
        "kept), the least noise, a bias of 5-10 % over a body a few mean free paths across (docs/pbl.md, section 2). "
        "Either way the layers are then no longer the scattering orders. none: the medium as given")
    peak_deflections: Bool = Field(False, description="with similarity = \"truncated\": camera paths and caustic "
                                   "photons inside such a medium are turned by the truncated peak's small deflections "
                                   "(drawn from the peak at its rate, f sigma_s, the channels' least) instead of going "
                                   "straight: most of the truncation's bias goes where sigma_s is grey (the bumpy "
                                   "sphere at eight passes: 8 x 8-block error 0.00055 -> 0.00013, relMSE 0.00150 -> "
                                   "0.00123, for 1.35 times the time; a first pass noisier, 0.0122 against 0.0077). "
                                   "Worth it for long renders, where that bias is most of the error (docs/pbl.md, "
                                   "section 2)")
    peak_deflections_from: Int = Field(0, ge=0, le=1_000_000, description="with peak_deflections: the first pass "
                                       "(from 0, in the scene's sequence of passes) that takes the deflections; the "
                                       "passes before it go straight, cheaper and less noisy, and the deflected "
                                       "passes after them bring the truncation's bias down as they add up (the bumpy "
                                       "sphere sets 8: its first eight passes as without the deflections, sixteen "
                                       "at 1.1 times volpath's time to equal error instead of 1.8; docs/pbl.md, "
                                       "section 2)")
    cut_size: Int = Field(8, ge=0, le=64, description="octree refinements per point for double and multiple scattering "
                          "(stochastic light cut: more = less noise, more time)")
    cut_size_diffuse: Int = Field(2, ge=0, le=64, description="double scattering's cut_size at the camera paths' "
                                  "points after a diffuse bounce, whose spread comes from their random depth and "
                                  "cosine-drawn direction more than from the cut; the multiple term keeps "
                                  "cut_size's (the bumpy sphere at eight passes: "
                                  "2 against 8, a fifth less time, relMSE 0.00159 against 0.00150; docs/pbl.md, "
                                  "section 9)")
    cut_roulette: Num = Field(0.01, ge=0, le=1, description="the light cut's nodes whose importance at a point is "
                              "under this share of the cut's (and whose power is under five times it) are evaluated "
                              "by Russian roulette, in proportion to the larger share, unbiased: most of a cut's "
                              "nodes hold a hundredth of its light or less (0: every node evaluated)")
    clamp: Num = Field(0.02, ge=0, description="smallest radius a source's 1/r^2 is averaged over (double "
                         "scattering), scene units")
    max_split_depth: Int = Field(8, ge=1, le=32,
                                 description="surfaces a camera path meets before it ends (it splits in "
                                 "two at every smooth interface)")
    diffuse_bounces: Int = Field(3, ge=0, le=64, description="diffuse bounces of camera paths (indirect light)")
    kmax_diffuse: Int = Field(1, ge=1, le=64, description="random points per medium segment after a diffuse bounce")
    light_sets: Int = Field(0, ge=0, le=4096, description="independent light-sample sets the spp passes cycle through "
                            "(0: a new set every pass; 1: the cached set only)")
    bounced_passes: Int = Field(4, ge=1, le=4096, description="passes that share one set of bounced samples, built "
                                "from the light samples of the first of them (1: every pass its own)")
    roulette: Num = Field(0.3, ge=0, description="camera branches of weight below this evaluate the medium's "
                          "smooth terms (double, multiple, bounced; in a ray-marched medium every term) with "
                          "probability weight / roulette (0: always)")
    roulette_single: Num = Field(0.02, ge=0, description="camera branches of weight below this evaluate single "
                                 "scattering with probability weight / roulette_single (0: always)")
    surface_roulette: Num = Field(0.01, ge=0, description="camera branches of weight below this (a glass's "
                                  "repeated reflections) are followed with probability weight / surface_roulette, "
                                  "their weight divided by it (0: every branch above 1e-5)")
    surface_paths: Int = Field(0, ge=0, le=4096, description="camera paths per pixel and pass: the surfaces (path "
                               "traced, cheap) take them all, the medium one of them chosen at random (weighted: "
                               "unbiased); 0: auto, 8 for the first two passes, then per pass from the surfaces' and "
                               "the medium's measured noise")
    pilot_paths: Int = Field(4, ge=0, le=64, description="with surface_paths 0 (auto): surface-only camera paths "
                             "per pixel traced before the first pass, not in the image; the first two passes' "
                             "paths (first_paths a pixel on average) follow their noise (0: first_paths in every "
                             "pixel)")
    pilot_pool: Bool = Field(False, description="the pilot's variance and mean of each pixel taken over the paths "
                             "of its 3 x 3 neighbourhood: one path a pixel then finds a small light's mirror image "
                             "as four did (the oil sphere; on the wax candle it lost a little)")
    first_paths: Int = Field(8, ge=1, le=128, description="with surface_paths 0 (auto): camera paths per pixel on "
                             "average in the first two passes, before the passes' own noise sets the counts")
    bounce_samples: Int = Field(1000, ge=16, le=10**7,
                                description="boundary points gathering the scattered light that the "
                                "medium's boundary reflects back (sec. 3.10, the bounced layer)")
    bounce_generations: Int = Field(3, ge=0, le=64, description="reflections of scattered light followed (0: none)")
    bounce_near_sources: Num = Field(0.0, ge=0, le=0.95, description="share of the boundary points shot from the "
                                     "scattered light's sources instead of spread as blue noise, in a convex "
                                     "medium (others keep blue noise): steadier generations, the wax sphere's "
                                     "bounced layer a quarter less noisy per pass, for a sixth to three tenths "
                                     "more time (docs/pbl.md, section 8)")
    caustic_photons: Num = Field(4.0, ge=0, le=1024, description="photons a pass traces per pixel from the sphere "
                                 "and quad lights through the smooth surfaces to the diffuse ones, where camera paths "
                                 "gather them (a small light's caustic beside a glass, smooth instead of fireflies; "
                                 "biased by the kernel's blur, which fades with the passes; docs/pbl.md); 0: the "
                                 "camera paths find caustics by chance, as volpath's")
    caustic_radius: Num = Field(4.0, gt=0, le=64, description="the caustic kernel's radius in pass 0, pixel "
                                "footprints at the distance a camera path travelled to the surface; pass p's is "
                                "(p + 1)^(-1/6) times that")
    components: tuple[Literal["single", "double", "multiple", "bounced"], ...] = Field(
        ("single", "double", "multiple", "bounced"), description="the medium's terms rendered (each is a layer of the "
        "EXR; the command line's --components overrides)")


class DipoleSettings(Strict):
    """The dipole diffusion BSSRDF with hierarchical evaluation (`--method dipole`; Jensen & Buhler 2002). Single
    scattering and the light that enters through glass come from the point-based method's light samples
    ([render.pbl])."""

    spacing: Num = Field(0.5, gt=0, le=MAX_COORD, description="irradiance samples' spacing on the translucent "
                         "shapes, in reduced mean free paths 1/sigma'_t of the densest channel")
    min_samples: Int = Field(4096, ge=16, le=10**8, description="irradiance samples at least (a small object "
                             "gets them closer than `spacing`)")
    max_samples: Int = Field(200_000, ge=16, le=10**8, description="irradiance samples at most (the spacing is "
                             "widened to fit, with a note)")
    max_error: Num = Field(0.05, ge=0, le=MAX_COORD, description="solid angle (sr) below which an octree node stands "
                           "for its samples in the hierarchical sum (0: every sample summed)")


class RaymarchSettings(Strict):
    """The ray-marching integrator of pbrt-v2 (`--method raymarch`): emission and single scattering from the lights,
    marched in steps along camera rays, a shadow ray per step marched too. Biased by the step."""

    step: Num = Field(0.0, ge=0, le=MAX_COORD, description="step along camera rays in scene units (0: auto, "
                      "`step_mfp` mean free paths of the medium at its densest, or its density's majorant cell if "
                      "that is smaller)")
    step_mfp: Num = Field(0.5, gt=0, le=100, description="the auto step, in mean free paths 1/sigma_t of the densest "
                          "channel at the medium's largest density")
    shadow_step_factor: Num = Field(4.0, ge=1, le=100, description="shadow rays march in steps this many times "
                                    "longer (pbrt-v2's 4)")
    max_steps: Int = Field(512, ge=1, le=1 << 16, description="steps per segment at most (a longer segment takes "
                           "longer steps)")
    shadows_through_dielectrics: Bool = Field(False, description="shadow rays cross smooth dielectric "
                                              "boundaries in a straight line, weighted by their Fresnel "
                                              "transmittance: ignores refraction, right for thin flat glass (a box's "
                                              "walls); false: they are blocked, as in pbrt-v2")


class VplSettings(Strict):
    """Instant multiple scattering with virtual point lights (`--method vpl`; Engelhardt, Novák and Dachsbacher
    2010): random walks from the lights leave VPLs in the media and on diffuse surfaces, new ones each pass; camera
    rays gather them at stratified points, on top of the ray marcher's single scattering ([render.raymarch])."""

    walks: Int = Field(256, ge=1, le=10**7, description="random walks from the lights per pass")
    gather_points: Int = Field(8, ge=1, le=4096, description="points per camera segment in a medium that gather "
                               "the VPLs (stratified)")
    walks_per_point: Int = Field(8, ge=1, le=10**6, description="walks whose VPLs each point gathers, chosen at "
                                 "random (each stands for walks / walks_per_point of them: unbiased)")
    clamp: Bool = Field(True, description="bound the VPLs' 1/d^2 by 1/clamp_distance^2 (no spikes; loses the light "
                        "of near VPLs unless compensated)")
    clamp_distance: Num = Field(0.0, ge=0, le=MAX_COORD, description="clamping radius in scene units (0: auto, "
                                "clamp_mfp mean free paths of the densest medium)")
    clamp_mfp: Num = Field(0.5, gt=0, le=1000, description="the auto clamping radius, in mean free paths 1/sigma_t "
                           "at the densest medium's majorant")
    compensate: Bool = Field(True, description="add back the clamped light (one compensation vertex per gather "
                             "point, connected to the VPLs with the clamp of compensation_clamp)")
    compensation_clamp: Num = Field(0.2, ge=0, le=1, description="the compensation vertices' own clamping radius "
                                    "over clamp_distance (0: unclamped, unbiased but with rare bright spots; the "
                                    "seed's GPU variant clamps them a little)")
    max_depth: Int = Field(256, ge=1, le=MAX_DEPTH, description="scattering events and surface bounces of a walk "
                           "at most")


class RenderSettings(Strict):
    """How to render (the command line's options override spp, seed, threads, time_limit and max_depth)."""

    spp: Int = Field(64, ge=1, le=MAX_SPP, description="samples (volpath) or passes (pbl, dipole, raymarch, vpl) "
                     "per pixel")
    max_depth: Int = Field(1000, ge=1, le=MAX_DEPTH, description="maximum number of scattering events and surface "
                           "bounces")
    seed: Int = Field(0, ge=0, le=MAX_SEED, description="random seed: the same seed and settings give the same image")
    threads: Int | None = Field(None, ge=1, le=MAX_THREADS, description="worker threads (default: all cores)")
    time_limit: Num | None = Field(None, gt=0, description="seconds; stops after the pass that passes it")
    volpath: VolpathSettings = Field(VolpathSettings(), description="[render.volpath]")
    lut: LutSettings = Field(LutSettings(), description="[render.lut]")
    pbl: PblSettings = Field(PblSettings(), description="[render.pbl]")
    dipole: DipoleSettings = Field(DipoleSettings(), description="[render.dipole]")
    raymarch: RaymarchSettings = Field(RaymarchSettings(), description="[render.raymarch]")
    vpl: VplSettings = Field(VplSettings(), description="[render.vpl]")


# --------------------------------------------------------------------------- lights


def _finite_emission(light):
    """Refuse a power that overflows into radiance (a tiny light of huge power)."""
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        radiance = light.emitted_radiance()
    if not np.all(np.isfinite(radiance)):
        raise ValueError(f"power {list(light.power)} over this light's area overflows its radiance; expected a "
                         "finite radiance")


class PointLight(Strict):
    """A point light: a delta light, so volpath cannot reach it through a refracting boundary (pbl can)."""

    type: Literal["point"]
    position: Vec3 = Field(description="scene units")
    intensity: Emission = Field(description="radiant intensity, W/sr")


class DirectionalLight(Strict):
    """Parallel light from infinitely far: a delta light, like the point light."""

    type: Literal["directional"]
    direction: Vec3 = Field(description="the direction the light travels (need not be unit length)")
    irradiance: Emission = Field(description="irradiance on a surface facing the light, W per scene unit^2")

    @field_validator("direction")
    @classmethod
    def _nz(cls, v):
        if np.linalg.norm(v) == 0:
            raise ValueError("expected a non-zero direction")
        return v


class SphereLight(Strict):
    """A sphere emitting uniformly outward from its surface. Give radiance or power, not both."""

    type: Literal["sphere"]
    center: Vec3 = Field(description="scene units")
    radius: Num = Field(gt=0, le=MAX_COORD, description="scene units")
    radiance: Emission | None = Field(None, description="emitted radiance, W sr^-1 per scene unit^2")
    power: Emission | None = Field(None, description="total emitted flux, W (radiance = power / (pi x 4 pi radius^2))")

    @model_validator(mode="after")
    def _one(self):
        if (self.radiance is None) == (self.power is None):
            raise ValueError("give exactly one of radiance, power")
        _finite_emission(self)
        return self

    def emitted_radiance(self) -> np.ndarray:
        if self.radiance is not None:
            return np.asarray(self.radiance, float)
        return np.asarray(self.power, float) / (math.pi * 4.0 * math.pi * self.radius**2)


class QuadLight(Strict):
    """A parallelogram corner + s edge1 + t edge2 (s, t in [0, 1]) emitting on the side edge1 x edge2 points to
    (both sides with two_sided). Give radiance or power, not both."""

    type: Literal["quad"]
    corner: Vec3 = Field(description="scene units")
    edge1: Vec3 = Field(description="scene units")
    edge2: Vec3 = Field(description="scene units; edge1 x edge2 is the emitting side's normal")
    radiance: Emission | None = Field(None, description="emitted radiance, W sr^-1 per scene unit^2")
    power: Emission | None = Field(None, description="total emitted flux, W (radiance = power / (pi x area x sides))")
    two_sided: Bool = Field(False, description="emit on both sides")

    @model_validator(mode="after")
    def _one(self):
        if (self.radiance is None) == (self.power is None):
            raise ValueError("give exactly one of radiance, power")
        if np.linalg.norm(np.cross(self.edge1, self.edge2)) == 0:
            raise ValueError("edge1 and edge2 must span a non-zero area")
        _finite_emission(self)
        return self

    def area(self) -> float:
        return float(np.linalg.norm(np.cross(self.edge1, self.edge2)))

    def emitted_radiance(self) -> np.ndarray:
        if self.radiance is not None:
            return np.asarray(self.radiance, float)
        sides = 2.0 if self.two_sided else 1.0
        return np.asarray(self.power, float) / (math.pi * self.area() * sides)


class EnvironmentLight(Strict):
    """Constant radiance arriving from every direction (a uniform sky)."""

    type: Literal["environment"]
    radiance: Emission = Field(description="radiance, W sr^-1 per scene unit^2")


Light = Annotated[
    Union[PointLight, DirectionalLight, SphereLight, QuadLight, EnvironmentLight],
    Field(discriminator="type"),
]


# --------------------------------------------------------------------------- shapes

MediumRef = Union[str, Material]


class Transform(Strict):
    """Applied as scale, then rotate (Euler angles in degrees about x, then y, then z), then translate."""

    translate: Vec3 = Field((0.0, 0.0, 0.0), description="scene units")
    rotate: Vec3 = Field((0.0, 0.0, 0.0), description="Euler angles about x, y, z, degrees")
    scale: Sizes3 = Field((1.0, 1.0, 1.0), description="one factor or one per axis [x, y, z], positive (a sphere "
                          "takes one)")

    def matrix(self) -> np.ndarray:
        """4x4 homogeneous matrix."""
        rx, ry, rz = np.radians(self.rotate)
        cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
        Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
        Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        M = np.eye(4)
        M[:3, :3] = Rz @ Ry @ Rx @ np.diag(self.scale)
        M[:3, 3] = self.translate
        return M


class ShapeBase(Strict):
    """Fields every shape takes. A shape's surface separates its interior from its exterior."""

    name: str | None = Field(None, description="a label for messages")
    interface: Literal["diffuse", "dielectric", "mirror", "null"] = Field(
        "diffuse", description="the surface: Lambertian (opaque), smooth dielectric (refracts and reflects by "
        "Fresnel), mirror, or null (index-matched: light passes unchanged into the medium)")
    albedo: Albedo = Field((0.8, 0.8, 0.8), description="diffuse albedo, or mirror reflectance")
    eta: Eta | None = Field(None, description="interior refractive index of a dielectric (default: the medium's "
                            "eta, else 1.5)")
    medium: MediumRef | None = Field(None, description="interior medium: a preset name (`pbvol materials`), a "
                                     "material file relative to the scene, a name in [materials], or an inline "
                                     "table")
    exterior_medium: MediumRef | None = Field(None, description="the medium outside (default: vacuum)")
    exterior_eta: Eta = Field(1.0, description="the refractive index outside")
    transform: Transform | None = Field(None, description="scale, rotate, then translate the shape")


class SphereShape(ShapeBase):
    """A sphere, intersected analytically: refracts like a true sphere."""

    type: Literal["sphere"]
    center: Vec3 = Field((0.0, 0.0, 0.0), description="scene units")
    radius: Num = Field(1.0, gt=0, le=MAX_COORD, description="scene units")


class BumpySphereShape(ShapeBase):
    """A sphere displaced radially by smooth noise: r = radius * (1 + amplitude * n(w)), |n| <= 1."""

    type: Literal["bumpy_sphere"]
    center: Vec3 = Field((0.0, 0.0, 0.0), description="scene units")
    radius: Num = Field(1.0, gt=0, le=MAX_COORD, description="scene units")
    amplitude: Num = Field(0.1, ge=0, lt=1, description="relative height of the bumps")
    frequency: Num = Field(3.0, gt=0, description="bumps' spatial frequency over the sphere")
    seed: Int = Field(0, ge=0, le=MAX_SEED, description="the noise's random seed")
    subdivisions: Int = Field(6, ge=1, le=8, description="icosphere subdivisions (20 x 4^n triangles)")


class BoxShape(ShapeBase):
    """An axis-aligned box (use a transform to turn it)."""

    type: Literal["box"]
    center: Vec3 = Field((0.0, 0.0, 0.0), description="scene units")
    size: Sizes3 = Field((1.0, 1.0, 1.0), description="edge lengths [x, y, z] (or one for a cube), scene units")


class CylinderShape(ShapeBase):
    """Closed cylinder along +y, its base centred at ``center``."""

    type: Literal["cylinder"]
    center: Vec3 = Field((0.0, 0.0, 0.0), description="centre of the base, scene units")
    radius: Num = Field(1.0, gt=0, le=MAX_COORD, description="scene units")
    height: Num = Field(1.0, gt=0, le=MAX_COORD, description="scene units")
    segments: Int = Field(256, ge=8, le=65536, description="facets around (smooth normals interpolated)")


class QuadShape(ShapeBase):
    """A rectangle in the xz plane centred at ``center``, normal +y (use a transform to turn it)."""

    type: Literal["quad"]
    center: Vec3 = Field((0.0, 0.0, 0.0), description="scene units")
    size: Annotated[tuple[Num, Num], AfterValidator(_positive_sizes)] = Field(
        (1.0, 1.0), description="[x, z] side lengths, scene units")


class CupShape(ShapeBase):
    """An open-top glass along +y (base centred at ``center``), optionally partly filled with a liquid.

    The glass itself is a dielectric of index ``eta`` (default 1.5) holding ``medium`` (usually none).
    With ``fill`` > 0 it generates the liquid's surfaces too: the glass-liquid interface (relative index)
    and the liquid's free surface, so that the three-interface case is one shape.
    """

    type: Literal["cup"]
    center: Vec3 = Field((0.0, 0.0, 0.0), description="centre of the base, scene units")
    radius: Num = Field(1.0, gt=0, le=MAX_COORD, description="outer radius, scene units")
    height: Num = Field(2.0, gt=0, le=MAX_COORD, description="scene units")
    wall: Num = Field(0.1, gt=0, le=MAX_COORD, description="wall thickness, scene units")
    bottom: Num = Field(0.2, gt=0, le=MAX_COORD, description="bottom thickness, scene units")
    fill: Num = Field(0.0, ge=0, le=1, description="liquid level as a fraction of the inner height")
    liquid: MediumRef | None = Field(None, description="the liquid's medium (as `medium`); needed when fill > 0")
    liquid_eta: Eta | None = Field(None, description="the liquid's refractive index (default: its medium's eta, "
                                   "else 1.33)")
    segments: Int = Field(256, ge=8, le=65536, description="facets around (smooth normals interpolated)")

    @model_validator(mode="after")
    def _dims(self):
        if self.wall >= self.radius:
            raise ValueError(f"wall ({self.wall}) must be thinner than the radius ({self.radius})")
        if self.bottom >= self.height:
            raise ValueError(f"bottom ({self.bottom}) must be thinner than the height ({self.height})")
        if self.fill > 0 and self.liquid is None:
            raise ValueError("fill > 0 needs a liquid")
        return self


class MeshShape(ShapeBase):
    """A mesh file read by trimesh (OBJ, PLY, STL, glTF/GLB), relative to the scene file."""

    type: Literal["mesh"]
    file: str = Field(description="the mesh file, relative to the scene file; a closed mesh to hold a medium, its "
                      "normals pointing out")
    smooth: Bool = Field(True, description="interpolate vertex normals (split at creases sharper than 60 degrees)")


Shape = Annotated[
    Union[SphereShape, BumpySphereShape, BoxShape, CylinderShape, QuadShape, CupShape, MeshShape],
    Field(discriminator="type"),
]


class Scene(Strict):
    """A scene file: camera, render settings, lights, shapes and named materials."""

    unit: Literal["scene", "mm", "cm", "m", "um", "in"] = Field(
        "scene", description="what one scene unit is; materials given per physical length convert to it")
    camera: Camera = Field(description="[camera]")
    render: RenderSettings = Field(RenderSettings(), description="[render]")
    lights: list[Light] = Field(default_factory=list, description="[[lights]], at least one; `type` selects the kind")
    shapes: list[Shape] = Field(default_factory=list, description="[[shapes]]; `type` selects the kind")
    materials: dict[str, Material] = Field(default_factory=dict, description="[materials.NAME]: materials the "
                                           "shapes name")

    @model_validator(mode="after")
    def _has_light(self):
        if not self.lights:
            raise ValueError("expected at least one light in 'lights'")
        return self


# --------------------------------------------------------------------------- loading


def _format_loc(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            # Pydantic puts the discriminator value / union member name in the location: keep it readable.
            out += ("." if out else "") + str(part)
    return out or "(top level)"


def _describe(err: ValidationError) -> tuple[str, str]:
    """(field, message) for a ValidationError, pydantic's noise removed: the first error's field, and a message
    that lists every error (the others as "; field: message"), on one line.

    For a medium given inline (the str | Material union), the Material branch's errors are the ones the user
    needs, not "should be a valid string".
    """
    errors = err.errors(include_url=False)
    inline = {tuple(e["loc"][:i]) for e in errors for i, p in enumerate(e["loc"]) if "Material" in str(p)}
    shown, seen = [], set()
    for e in errors:
        if any(p == "str" and tuple(e["loc"][:i]) in inline for i, p in enumerate(e["loc"])):
            continue
        loc = _format_loc(tuple(p for p in e["loc"] if p not in PYDANTIC_UNION_TAGS and "Material" not in str(p)))
        msg = _message(e)
        if (loc, msg) not in seen:
            seen.add((loc, msg))
            shown.append((loc, msg))
    (loc, msg), others = shown[0], shown[1:]
    return loc, msg + "".join(f"; {o_loc}: {o_msg}" for o_loc, o_msg in others)


def _message(e: dict) -> str:
    """One pydantic error's message in the README's words."""
    if e["type"] == "extra_forbidden":
        return "unknown field"
    if e["type"] == "missing":
        return "required field is missing"
    if e["type"] == "union_tag_invalid":
        return f"unknown type {e['ctx'].get('tag')!r}; expected one of {e.get('ctx', {}).get('expected_tags', '')}"
    if e["type"] == "union_tag_not_found":
        return "missing 'type' field"
    if e["type"] == "finite_number":
        return f"expected a finite number, got {e.get('input')!r}"
    if e["type"] in ("float_type", "int_type", "bool_type") and isinstance(e.get("input"), bool):
        return f"expected a {e['type'].removesuffix('_type').replace('float', 'number')}, got {e['input']!r}"
    return e["msg"].removeprefix("Value error, ")


# Tags that Pydantic inserts into error locations for discriminated and plain unions.
PYDANTIC_UNION_TAGS = {
    "point", "directional", "sphere", "quad", "environment", "bumpy_sphere", "box", "cylinder",
    "cup", "mesh", "str", "Material",
}


def read_toml(path: Path) -> dict:
    path = Path(path)
    if not path.exists():
        raise ConfigError(path, None, "file not found")
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(path, None, f"TOML syntax error: {e}") from None
    except UnicodeDecodeError:
        raise ConfigError(path, None, "not a TOML text file (binary content); expected a scene or material file")
    except OSError as e:
        raise ConfigError(path, None, f"cannot read file: {e.strerror or e}") from None


def load_material(path: Path) -> Material:
    path = Path(path)
    data = read_toml(path)
    try:
        return Material.model_validate(data)
    except ValidationError as e:
        raise ConfigError(path, *_describe(e)) from None


def load_scene(path: Path) -> Scene:
    """The validated scene of a TOML file (ConfigError naming the file and the field otherwise)."""
    path = Path(path)
    return scene_from_data(read_toml(path), path)


def scene_from_data(data: dict, path: Path) -> Scene:
    """The validated scene of a scene file's contents (a dict as TOML gives it); path: where its relative files
    are found and how errors name it."""
    path = Path(path)
    try:
        scene = Scene.model_validate(data)
    except ValidationError as e:
        raise ConfigError(path, *_describe(e)) from None
    # Resolve every medium reference now, so that a bad name fails here with its field.
    scene_media(scene, path)
    for i, shape in enumerate(scene.shapes):
        if isinstance(shape, MeshShape):
            mesh_path = (path.parent / shape.file)
            if not mesh_path.exists():
                raise ConfigError(path, f"shapes[{i}].file", f"mesh file not found: {mesh_path}")
    for name, m in scene.materials.items():
        try:
            _finite_coefficients(*m.coefficients(scene.unit))
        except ValueError as e:
            raise ConfigError(path, f"materials.{name}.length_unit", str(e)) from None
    return scene


def materials_dir() -> Path:
    """Where the preset material files live: $PBVOL_MATERIALS, else the package's materials/ (installed with it;
    the repository's top-level materials/ links to it)."""
    env = os.environ.get("PBVOL_MATERIALS")
    if env:
        return Path(env)
    return Path(__file__).resolve().parent / "materials"


def preset_names() -> list[str]:
    d = materials_dir()
    return sorted(p.stem for p in d.glob("*.toml")) if d.is_dir() else []


def resolve_medium(ref: MediumRef, scene: Scene, scene_path: Path, field: str) -> tuple[Material, str]:
    """Turn a medium reference into (Material, label).

    A string is, in this order: a name in the scene's [materials] table, a path to a material file
    (relative to the scene file), or a preset name from materials/.
    """
    if isinstance(ref, Material):
        mat, label = ref, ref.name or "inline"
    elif ref in scene.materials:
        mat, label = scene.materials[ref], ref
    elif ref.endswith(".toml") or "/" in ref:
        p = Path(scene_path).parent / ref
        if not p.exists():
            raise ConfigError(scene_path, field, f"material file not found: {p}")
        mat, label = load_material(p), ref
    else:
        p = materials_dir() / f"{ref}.toml"
        if not p.exists():
            names = ", ".join(preset_names()) or "(none found)"
            raise ConfigError(scene_path, field, f"unknown material {ref!r}; expected one of: {names}")
        mat, label = load_material(p), ref
    try:
        _finite_coefficients(*mat.coefficients(scene.unit))
    except ValueError as e:
        raise ConfigError(scene_path, field, str(e)) from None
    return mat, label


MEDIUM_FIELDS = ("medium", "exterior_medium", "liquid")  # the shape fields that name a medium


def medium_key(material: Material) -> str:
    """Two references to materials with the same key are one medium."""
    return material.model_dump_json()


def scene_media(scene: Scene, scene_path: Path) -> list[tuple[str, Material]]:
    """Every distinct medium of a scene as (label, material), in the order the shapes first name them."""
    seen, out = set(), []
    for i, shape in enumerate(scene.shapes):
        for fld in MEDIUM_FIELDS:
            ref = getattr(shape, fld, None)
            if ref is None:
                continue
            mat, label = resolve_medium(ref, scene, scene_path, f"shapes[{i}].{fld}")
            if medium_key(mat) not in seen:
                seen.add(medium_key(mat))
                out.append((label, mat))
    return out
