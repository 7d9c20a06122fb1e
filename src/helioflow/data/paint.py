"""Import PAINT calibration data: real focal-spot images, sun positions and heliostat geometry.

A PAINT directory holds ``tower-measurements.json`` (tower, calibration targets) and one folder per
heliostat with ``heliostat-properties.json`` and, per measurement ``<id>``,
``<id>-calibration-properties.json``, ``<id>-flux.png`` and ``<id>-flux-centered.png``.
`import_paint` turns one heliostat folder into a helioflow dataset (schema of ``hdf5.py``, the
same attributes as a traced dataset) and/or the heliostat's geometry file (``surfaces.py``).

Conventions (checked against the data; see tests/data/test_paint.py):

- Frame: WGS84 latitude/longitude/altitude -> local ENU metres around the tower's
  ``power_plant_properties.coordinates`` (``geometry.wgs84_to_enu``).
- Sun: ``sun_azimuth`` / ``sun_elevation`` in degrees, azimuth 0 = south, +90 = east, which is
  helioflow's convention: taken as they are. A sun at or below the horizon is an error.
- Target: a plane through the mean of its four corners; right = mean of the upper and lower
  edges (``upper_left`` -> ``upper_right``, east to west as seen from the field), up = mean of the
  side edges, normal = right x up (towards the field), width/height = their lengths (m).
  helioflow's target axes are horizontal (``geometry.plane_axes``); the corners' in-plane tilt
  (< 5 mrad, < 2 cm at the edges, below one pixel) is neglected. The image spans the corners, so
  its frame is this plane's. The heliostats aim at the target's ``center`` entry, as ARTIST (PAINT's
  reference code) aims them: on the Jülich upper and lower targets it is 9.5 mm right of and 1.4 mm
  above the corners' mean (attribute ``aim_point_m``, per image in extras ``aim_point_m``). PAINT's
  own UTIS centroids put the image frame on the corners, not on ``center``: framed on the corners'
  mean, the images' centroids lie 9 mm nearer the UTIS centroids on those targets (docs/data.md).
- Images: ``<id>-flux.png`` spans the whole target (the UTIS rectified image): row 0 is the upper
  edge, column 0 the ``upper_left``/``lower_left`` side, i.e. rows top-down and columns to the
  right as seen from the field, as helioflow's images. Its flux-weighted centroid matches PAINT's
  UTIS centroid to 1-4 cm (UTIS counts pixel corners, not centres: half a pixel). A measurement
  with a ``-flux.png`` is read from it alone; its ``-flux-centered.png`` is not used. Grey levels
  are divided by 255 (65535 for 16-bit): each PNG is normalised to its own peak, so images are
  relative flux, not W/m^2, and intensities across images are not comparable (attribute
  ``per_image_normalised``; the physics models fit them by shape). The attribute ``dni_w_m2`` is
  the nominal DNI a model traces them with (config ``dni_w_m2``): PAINT records none, and on
  relative images it sets only the unit of the traced flux. Images are resampled to the configured
  resolution by exact area averaging over the same target extent, so pixel centres keep their
  target coordinates (nothing shifts).
- Centered measurements: one with only ``<id>-flux-centered.png`` (PAINT's 2025 release) is placed
  on its target (option ``centered: place``, the default; ``skip`` leaves such measurements out).
  That image does not span the target: it spans a square window of CENTERED_WINDOW_M on a side, the
  same on every target (64 px: 6.095 m, pixel centres 6 m apart edge to edge: 95 mm pixels, against
  34 x 28 mm of the Juelich targets' 256 x 256 whole image), the spot's flux-weighted centroid at
  its middle. Fitted to the whole images of the measurements that have both, the window's side is
  6.095 m high, 6.103 m wide for AA23's 64 px centered images and 6.031, 6.039 m for the 2026
  release's 256 px ones; spanning the whole target instead, as PAINT's README reads, puts 7-28 % of
  the flux in the wrong place. The image is shifted (subpixel, exact area overlap: flux density x
  area conserved) so that its flux-weighted centroid lands on the UTIS centroid moved by half a
  UTIS pixel right and down (``utis_on_target``: UTIS counts the pixel corners of its 256 x 256
  image; without the half pixel the spots land 17-32 mm off); flux shifted beyond the target's
  edges is lost (at most 0.02 % on the sample data). So placed, the centered images of the
  measurements with both files match their whole images at 64 x 64 to 1-10 mm (centroid) and
  0.2-1.5 % misplaced flux (one outlier, AA23's 216331: 18 %; docs/data.md). Extras ``centered``
  (N,) bool say which images were placed.
- Heliostat: PAINT facets are given for the mirror lying flat, facing up, in (e, n, u); mounted,
  the mirror faces south at rest (``initial_orientation`` [0, -1, 0]), which is the rotation about
  east taking (e, n, u) to (east, up, south) = helioflow's heliostat frame (right, up, normal), as
  in ARTIST's rigid-body kinematics. So the translation vectors and the canting vectors need no
  conversion: ``canting_e`` and ``canting_n`` are the facet's half-width and half-height vectors
  in that frame, facet size = 2 |canting_e|, 2 |canting_n|, facet normal = canting_e x canting_n.
  The mount is "juelich" (first joint about east), the facets flat, the surface undeformed and
  the tracking error zero (the ideal heliostat). Where the facets sit, as ARTIST (PAINT's
  reference code) reads it: its kinematics applies the concentrator translation after both
  joints (0.175 m behind the pivot for AA39) and aims that point, the concentrator's origin, at
  the aim point; the facets stand at their ``translation_vector`` from it, 0.0402 m ahead of it
  along the normal for AA39. helioflow aims its heliostat position, so the facets keep their
  translation vectors relative to it (the aimed point) and the concentrator translation is only
  recorded (``source.concentrator_translation_enu_m``). The spot then misses the aim point by
  what the facets' 4 cm stand-off makes of the incidence angle (0.3-2.4 cm at 52 m), as
  ARTIST's does; the aimed point's own 0.175 m from the pivot moves no spot (both codes aim it
  exactly). Checked against ARTIST's centroids: tests/data/test_paint_geometry.py. Joint
  translations (all 0 in PAINT) and the actuator parameters are kinematic details the ideal
  heliostat does not use.
- Splits: every image is "train" except the configured ``holdout`` ids (or a seeded random
  share: ``holdout: {fraction: 0.25, seed: 0}``), which are
  "interpolation" when their sun position lies inside the azimuth and elevation ranges of the
  train images and "extrapolation" otherwise.
- Targets: a heliostat's measurements may be taken on several targets. The per-image target
  geometry is in the extras ``target_center_m`` (N, 3), ``target_normal`` (N, 3),
  ``target_size_m`` (N, 2) and ``target_name`` (N,); the root attributes ``target_*`` hold the
  target of most images, exact for all images only when ``mixed_targets`` is false (choose one
  with the ``targets`` option).
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from helioflow import __version__
from helioflow.data.hdf5 import CalibrationDataset, write_dataset
from helioflow.data.surfaces import write_heliostat
from helioflow.data.synthetic import CONVENTIONS, config_hash
from helioflow.errors import DataError, HelioflowError
from helioflow.physics.geometry import plane_axes, wgs84_to_enu
from helioflow.physics.heliostat import TRACKING_PARAMETERS, Heliostat, canting_focal_distance
from helioflow.physics.target import pixel_centroid

log = logging.getLogger(__name__)

TOWER_FILE = "tower-measurements.json"
PROPERTIES_FILE = "heliostat-properties.json"
CALIBRATION_SUFFIX = "-calibration-properties.json"
CORNERS = ("upper_left", "upper_right", "lower_left", "lower_right")
CONTROL_POINTS = 6  # B-spline control points per facet side of the (zero) surface deformation
CENTERED_MODES = ("place", "skip")  # option `centered`: place centered-only measurements, or leave them out
# not a schema default: `centered` is for PAINT datasets alone, and a default in the schema would give every other
# dataset the key, which its checks refuse (config._PAINT_KEYS); tests/test_config.py checks both against the schema
CENTERED_DEFAULT = "place"
REPAIR = "remove this measurement (its calibration-properties.json and PNG) or repair the image"
# side (m) of the square window a <id>-flux-centered.png spans, by its pixels per side (module docstring):
# 64 (the 2025 release) 6 m between the outer pixel centres, 6 * 64 / 63; 256 (2026) as fitted to the whole images
CENTERED_WINDOW_M = {64: 6.0 * 64 / 63, 256: 6.035}
UTIS_PIXELS = 256  # pixels per side of the UTIS image whose pixel corners PAINT's UTIS centroid counts


@dataclass(frozen=True)
class PlaneTarget:
    """A planar calibration target in ENU: centre (3,) m, unit normal (3,) towards the field,
    width and height (m) along its right and up axes, and the point (3,) m the heliostats aim at
    when it is not the centre (None)."""

    name: str
    center: np.ndarray
    normal: np.ndarray
    width: float
    height: float
    aim: np.ndarray | None = None


@dataclass(frozen=True)
class Measurement:
    """One calibration measurement: sun position (deg), target, PAINT's spot centroids (ENU m), the PNG
    the import reads and whether it is the centered one (``<id>-flux-centered.png``, no whole image)."""

    id: str
    azimuth_deg: float
    elevation_deg: float
    target_name: str
    focal_spot_utis_m: np.ndarray
    focal_spot_helios_m: np.ndarray
    motor_position: tuple[float, float]
    image_png: Path
    centered: bool = False


def read_json(path: Path) -> dict:
    """A JSON object from `path`; DataError if missing, unreadable or not an object."""
    if not path.is_file():
        raise DataError(f"{path} does not exist")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataError(f"{path}: not a readable JSON file: {exc}") from None
    if not isinstance(data, dict):
        raise DataError(f"{path}: expected a JSON object, found {type(data).__name__}")
    return data


def field(data: dict, path: Path, key: str, kind: str = "number", where: str = ""):
    """The value at dotted `key` in `data`, checked to be `kind`: "number", "vec3" (3 numbers),
    "string", "list" or "object"; DataError naming the file and the field (prefixed by `where`,
    e.g. "facet_properties.facets[2]") otherwise."""
    value = data
    parts = key.split(".")
    for i, part in enumerate(parts):
        if not isinstance(value, dict) or part not in value:
            missing = ".".join(([where] if where else []) + parts[: i + 1])
            raise DataError(f"{path}: missing field {missing!r}")
        value = value[part]
    ok = {
        "number": _is_finite_number,
        "vec3": lambda v: isinstance(v, list) and len(v) == 3 and all(_is_finite_number(x) for x in v),
        "string": lambda v: isinstance(v, str),
        "list": lambda v: isinstance(v, list),
        "object": lambda v: isinstance(v, dict),
    }[kind]
    if not ok(value):
        expected = {"number": "a finite number", "vec3": "a list of 3 finite numbers"}.get(kind, f"a {kind}")
        name = f"{where}.{key}" if where else key
        raise DataError(f"{path}: field {name!r} = {value!r}: expected {expected}")
    return value


def _is_finite_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


class ENUFrame(Protocol):
    """What reading a heliostat's properties needs of a frame (Tower, images.WGS84Origin)."""

    def enu(self, wgs84) -> np.ndarray:
        """(..., 3) WGS84 (lat deg, lon deg, alt m) -> (..., 3) ENU m."""
        ...


class SunPositioned(Protocol):
    """What split_labels reads of a measurement (Measurement, images._Held)."""

    @property
    def id(self) -> str:
        """The measurement id."""
        ...

    @property
    def azimuth_deg(self) -> float:
        """The sun's azimuth (deg)."""
        ...

    @property
    def elevation_deg(self) -> float:
        """The sun's elevation (deg)."""
        ...


class Tower:
    """tower-measurements.json: the ENU origin and the planar calibration targets."""

    def __init__(self, path: Path):
        self.path = path
        self.data = read_json(path)
        self.origin = tuple(field(self.data, path, "power_plant_properties.coordinates", "vec3"))

    def enu(self, wgs84) -> np.ndarray:
        """(..., 3) WGS84 (lat deg, lon deg, alt m) -> (..., 3) ENU m around the tower."""
        p = np.asarray(wgs84, dtype=float)
        return wgs84_to_enu(p[..., 0], p[..., 1], p[..., 2], *self.origin)

    def planar_targets(self) -> list[str]:
        """The names of the tower file's planar targets, sorted."""
        return sorted(k for k, v in self.data.items() if isinstance(v, dict) and v.get("type") == "planar")

    def target(self, name: str, used_in: Path) -> PlaneTarget:
        """The planar target `name` (DataError naming `used_in` if the tower has no such target)."""
        if name not in self.planar_targets():
            raise DataError(f"{used_in}: target_name {name!r} is not a planar target in {self.path}; "
                            f"known: {', '.join(self.planar_targets())}")
        aim = self.enu(field(self.data, self.path, f"{name}.coordinates.center", "vec3"))
        return replace(self._plane(name, ""), aim=aim)

    def _plane(self, name: str, prefix: str) -> PlaneTarget:
        """The plane through the corners `<name>.coordinates.<prefix><corner>` (CORNERS), its normal
        towards the field (`<name>.normal_vector`)."""
        corners = {c: self.enu(field(self.data, self.path, f"{name}.coordinates.{prefix}{c}", "vec3"))
                   for c in CORNERS}
        normal_hint = np.asarray(field(self.data, self.path, f"{name}.normal_vector", "vec3"), dtype=float)
        return plane_from_corners(name, corners, normal_hint)


    def receiver(self, name: str) -> PlaneTarget:
        """The receiver entry `name` of the tower file as a flat plane through its outer corners
        (``receiver_outer_<corner>``; a planar entry's own corners): the aperture of a cavity or of a
        convex cylinder such as Jülich's (4.14 m radius, 60 deg opening: a chord of 4.14 m, within
        ~0.5 m of its surface). DataError naming the file and the entry when it has no corners."""
        entry = self.data.get(name)
        if not isinstance(entry, dict):
            known = sorted(k for k, v in self.data.items() if isinstance(v, dict) and "coordinates" in v)
            raise DataError(f"{self.path}: no entry {name!r} to draw the flux map on; entries with coordinates: "
                            f"{', '.join(known)}")
        return self._plane(name, "" if entry.get("type") == "planar" else "receiver_outer_")


def plane_from_corners(name: str, corners: dict[str, np.ndarray], normal_hint: np.ndarray) -> PlaneTarget:
    """Target plane from its ENU corners (dict of CORNERS -> (3,) m); the normal's sign follows
    `normal_hint` (PAINT's ``normal_vector``, towards the field)."""
    c = corners
    right = 0.5 * ((c["upper_right"] - c["upper_left"]) + (c["lower_right"] - c["lower_left"]))
    up = 0.5 * ((c["upper_left"] - c["lower_left"]) + (c["upper_right"] - c["lower_right"]))
    normal = np.cross(right, up)
    normal /= np.linalg.norm(normal)
    if normal @ normal_hint < 0:
        normal = -normal
    center = np.mean([corners[c] for c in CORNERS], axis=0)
    return PlaneTarget(name, center, normal, float(np.linalg.norm(right)), float(np.linalg.norm(up)))


def measurement_pngs(path: Path) -> tuple[Path, Path]:
    """(``<id>-flux.png``, ``<id>-flux-centered.png``) beside the ``<id>-calibration-properties.json``
    `path`, whether they exist or not."""
    mid = path.name[: -len(CALIBRATION_SUFFIX)]
    return path.with_name(f"{mid}-flux.png"), path.with_name(f"{mid}-flux-centered.png")


def centered_only(path: Path) -> bool:
    """Whether the measurement `path` (its calibration-properties.json) has only its centered PNG;
    DataError naming the files when it has neither."""
    whole, centered = measurement_pngs(path)
    if whole.is_file():
        return False
    if centered.is_file():
        return True
    raise DataError(f"{whole} does not exist, nor does {centered.name}: each <id>{CALIBRATION_SUFFIX} needs its "
                    "<id>-flux.png (the whole target) or its <id>-flux-centered.png (the spot, placed by the UTIS "
                    "centroid)")


def read_measurement(path: Path, tower: Tower) -> Measurement:
    """One ``<id>-calibration-properties.json`` and the path of the PNG to read: ``<id>-flux.png``, or
    ``<id>-flux-centered.png`` when that is the only one (then its UTIS centroid is required)."""
    centered = centered_only(path)
    data = read_json(path)
    azimuth = float(field(data, path, "sun_azimuth"))
    elevation = float(field(data, path, "sun_elevation"))
    if not 0 < elevation <= 90:
        raise DataError(f"{path}: sun_elevation = {elevation:g} deg: the sun is below the horizon "
                        "(expected 0 < elevation <= 90)")
    if not -180 <= azimuth <= 360:
        raise DataError(f"{path}: sun_azimuth = {azimuth:g} deg: expected degrees in [-180, 360]")
    target = field(data, path, "target_name", "string")
    tower.target(target, path)
    try:
        utis = field(data, path, "focal_spot.UTIS", "vec3")
    except DataError as exc:
        if not centered:
            raise
        raise DataError(f"{exc}: {measurement_pngs(path)[1].name}, the only image of this measurement, is placed "
                        "on the target by it") from None
    return Measurement(
        id=path.name[: -len(CALIBRATION_SUFFIX)],
        azimuth_deg=(azimuth + 180.0) % 360.0 - 180.0,
        elevation_deg=elevation,
        target_name=target,
        focal_spot_utis_m=tower.enu(utis),
        focal_spot_helios_m=tower.enu(field(data, path, "focal_spot.HeliOS", "vec3")),
        motor_position=(float(field(data, path, "motor_position.axis_1_motor_position")),
                        float(field(data, path, "motor_position.axis_2_motor_position"))),
        image_png=measurement_pngs(path)[centered],
        centered=centered,
    )


def read_flux_png(path: Path) -> np.ndarray:
    """(H, W) float64 grey levels in [0, 1] of a PAINT flux PNG; DataError if missing or corrupt."""
    if not path.is_file():
        raise DataError(f"{path} does not exist (each <id>{CALIBRATION_SUFFIX} needs its <id>-flux.png)")
    return read_grey_png(path, str(path), REPAIR)[0]


def read_centered_png(path: Path) -> np.ndarray:
    """(n, n) float64 grey levels in [0, 1] of a PAINT ``<id>-flux-centered.png``, n a key of
    CENTERED_WINDOW_M; DataError if corrupt or of another size."""
    image = read_grey_png(path, str(path), REPAIR)[0]
    n = image.shape[0]
    if image.shape[1] != n or n not in CENTERED_WINDOW_M:
        sizes = " or ".join(f"{k} x {k}" for k in CENTERED_WINDOW_M)
        raise DataError(f"{path} is {image.shape[0]} x {image.shape[1]} pixels; expected a centered PAINT image "
                        f"of {sizes} pixels (the window whose size helioflow knows)")
    return image


PNG_COLOUR_TYPES = {0: "grey", 2: "RGB", 3: "palette", 4: "grey + alpha", 6: "RGBA"}  # the IHDR's colour type


def read_grey_png(path: Path, where: str, remedy: str) -> tuple[np.ndarray, float]:
    """(H, W) float64 grey levels in [0, 1] of an existing PNG and the share of its pixels at full scale.

    16-bit grey: / 65535. 8-bit grey, RGB or palette: converted to 8-bit grey by Pillow's ITU-R 601-2
    luma (L = 0.299 R + 0.587 G + 0.114 B), / 255. An alpha channel (or a transparent colour) that is
    opaque everywhere is ignored; one with transparent pixels is refused (what a transparent pixel
    measured is unknown), and so is 16-bit colour (Pillow reads it at 8 bits only). One DataError
    starting with `where` (the file, or the CSV line that names it) when it is no readable 2-D PNG of
    these kinds or shows nothing; `remedy` ends the message of an image without a spot."""
    from PIL import Image, UnidentifiedImageError  # Pillow: a dependency of matplotlib and scikit-image

    at = where if where == str(path) else f"{where}: {path}"
    try:
        with Image.open(path) as img:
            img.load()
            if img.format != "PNG":
                raise DataError(f"{at} is a {img.format} image; expected PNG")
            _check_png_kind(path, img, at)
            sixteen = img.mode.startswith("I")
            array = np.asarray(img if sixteen else img.convert("L"), dtype=np.float64)
    except (OSError, SyntaxError, ValueError, UnidentifiedImageError) as exc:
        raise DataError(f"{at} is not a readable PNG image (corrupt or truncated?): {exc}") from None
    if array.ndim != 2 or min(array.shape) < 2:
        raise DataError(f"{at} has shape {array.shape}; expected a 2-D image of at least 2 x 2 pixels")
    full = 65535.0 if sixteen else 255.0
    if array.max() <= array.min():
        level = "black (all zero)" if array.max() == 0 else f"grey level {array.max():g} in every pixel (saturated?)"
        raise DataError(f"{at}: the image is {level}: it shows no focal spot; {remedy}")
    return array / full, float((array >= full).mean())


def _check_png_kind(path: Path, img, at: str) -> None:
    """DataError for a 16-bit colour PNG or one with transparent pixels (read_grey_png)."""
    header = path.read_bytes()[:26]
    depth, colour = (header[24], header[25]) if header[12:16] == b"IHDR" else (8, 0)
    if depth == 16 and colour != 0:
        raise DataError(f"{at} is a 16-bit {PNG_COLOUR_TYPES.get(colour, 'colour')} PNG, which helioflow cannot read "
                        "at 16 bits (Pillow reduces it to 8); save it as 16-bit greyscale")
    if img.mode in ("LA", "RGBA", "PA") or "transparency" in img.info:
        alpha = np.asarray(img.convert("RGBA"))[..., 3]
        if alpha.min() < 255:
            raise DataError(f"{at} has transparent pixels ({(alpha < 255).mean():.1%} of them; alpha channel): "
                            "helioflow reads the grey level, not the alpha; save the image without transparency")


def resample_area(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) image -> `shape` (h, w) by exact area averaging over the same extent.

    Each output pixel is the area-weighted mean of the input pixels it overlaps, so a uniform
    image stays uniform, the total (times pixel area) is kept and both pixel grids span the same
    target: pixel centres keep their target coordinates (no shift; upsampling replicates).
    """
    rows = _overlap(image.shape[0], shape[0])
    cols = _overlap(image.shape[1], shape[1])
    return rows @ image @ cols.T


def _overlap(n_in: int, n_out: int, start: float = 0.0, span: float = 1.0) -> np.ndarray:
    """(n_out, n_in) weights: fraction of output pixel i covered by input pixel j, the output spanning
    [0, 1] and the input [start, start + span] (fractions of the output's extent); rows sum to 1
    where the input covers the output pixel."""
    e_in = start + span * np.arange(n_in + 1) / n_in
    e_out = np.arange(n_out + 1) / n_out
    lo = np.maximum(e_out[:-1, None], e_in[None, :-1])
    hi = np.minimum(e_out[1:, None], e_in[None, 1:])
    return np.clip(hi - lo, 0.0, None) * n_out


def utis_on_target(m: Measurement, plane: PlaneTarget) -> np.ndarray:
    """(2,) PAINT's UTIS centroid of `m` in the target coordinates of `plane` (u right, v up, m from its
    centre; ``geometry.plane_axes``), moved by half a UTIS pixel right and down: UTIS counts the pixel
    corners of its UTIS_PIXELS-square image, helioflow's centroids the pixel centres (module docstring)."""
    right, up = (a.numpy() for a in plane_axes(torch.as_tensor(plane.normal, dtype=torch.float64)))
    d = np.asarray(m.focal_spot_utis_m) - plane.center
    return np.array([d @ right + 0.5 * plane.width / UTIS_PIXELS, d @ up - 0.5 * plane.height / UTIS_PIXELS])


def place_centered(image: np.ndarray, centroid_uv: np.ndarray, plane: PlaneTarget,
                   shape: tuple[int, int]) -> np.ndarray:
    """(n, n) centered image -> (rows, cols) = `shape` image of the whole target `plane` with the flux-weighted
    centroid of `image` at `centroid_uv` (2,) (u right, v up, m from the target's centre).

    `image` spans a square window of CENTERED_WINDOW_M[n] m on a side, its axes along the target's
    right and up; it is shifted by any fraction of a pixel and area-averaged onto the target's grid by
    exact overlap, so flux density x area is kept, except what lands beyond the target's edges: lost.
    """
    n_rows, n_cols = image.shape
    side = CENTERED_WINDOW_M[n_rows]
    row, col = pixel_centroid(torch.as_tensor(image)).numpy()  # from the centre of pixel (0, 0)
    # the window's upper-left corner on the target, as fractions of its height (down) and width (right)
    top = (0.5 * plane.height - centroid_uv[1] - (row + 0.5) * side / n_rows) / plane.height
    left = (0.5 * plane.width + centroid_uv[0] - (col + 0.5) * side / n_cols) / plane.width
    return (_overlap(n_rows, shape[0], top, side / plane.height) @ image
            @ _overlap(n_cols, shape[1], left, side / plane.width).T)


def heliostat_folder(paint_dir: Path, heliostat: str) -> Path:
    """`paint_dir`/`heliostat`; DataError listing the heliostat folders if it is not there."""
    folder = paint_dir / heliostat
    if not folder.is_dir():
        known = sorted(p.name for p in paint_dir.iterdir() if p.is_dir()) if paint_dir.is_dir() else []
        where = f"heliostat folders there: {', '.join(known)}" if known else f"{paint_dir} is not a directory"
        raise DataError(f"{folder} does not exist; {where}")
    return folder


def plant_heliostats(paint_dir: str | os.PathLike, selection: str | list[str]) -> list[str]:
    """The heliostat folders of a PAINT directory that a plant entry (`heliostats:`) selects, sorted.

    Args:
        paint_dir: the PAINT directory (tower-measurements.json and one folder per heliostat).
        selection: "all" (every folder that holds a heliostat-properties.json and at least one
            calibration measurement: what can be calibrated), a glob over the folder names (e.g.
            "AA*", with the same condition), or a list of folder names (taken as given).

    Raises DataError when a glob or "all" selects no heliostat, naming the folders there.
    """
    if isinstance(selection, list):
        return list(dict.fromkeys(selection))
    import fnmatch

    root = Path(paint_dir)
    folders = sorted(p for p in root.iterdir() if p.is_dir()) if root.is_dir() else []
    pattern = "*" if selection == "all" else selection
    chosen = [f.name for f in folders if fnmatch.fnmatchcase(f.name, pattern) and (f / PROPERTIES_FILE).is_file()
              and any(f.glob(f"*{CALIBRATION_SUFFIX}"))]
    if not chosen:
        listed = ", ".join(f.name for f in folders) or "none"
        raise DataError(f"heliostats: {selection!r} selects no heliostat folder of {paint_dir} with a "
                        f"{PROPERTIES_FILE} and calibration measurements; folders there: {listed}")
    return chosen


def read_heliostat_properties(path: Path, tower: ENUFrame) -> tuple[Heliostat, dict]:
    """The ideal heliostat (float64) of a heliostat-properties.json and its provenance attributes."""
    if not path.is_file():
        found = len(list(path.parent.glob(f"*{CALIBRATION_SUFFIX}")))
        raise DataError(f"{path} does not exist: the heliostat's position and facets are missing "
                        f"({found} measurements found in {path.parent}, not importable without them)")
    data = read_json(path)
    position = tower.enu(field(data, path, "heliostat_position", "vec3"))
    facets = field(data, path, "facet_properties.facets", "list")
    if not facets:
        raise DataError(f"{path}: field 'facet_properties.facets' is empty; expected at least one facet")
    translation, half_e, half_n = (_facet_vectors(facets, path, key)
                                   for key in ("translation_vector", "canting_e", "canting_n"))
    kin = field(data, path, "kinematics_properties", "object")
    concentrator = np.array([float(field(kin, path, f"concentrator_translation_{a}")) for a in "enu"])
    # the facets stand where PAINT puts them relative to the concentrator's origin, the point the
    # kinematics aims (ARTIST's rigid body); helioflow aims its heliostat position, which therefore
    # stands for that origin: the concentrator translation (e, n, u at rest) is recorded, not applied
    normal = np.cross(half_e, half_n)
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    if not (length > 0).all():
        bad = int(np.flatnonzero(length[:, 0] <= 0)[0])
        raise DataError(f"{path}: facet_properties.facets[{bad}]: canting_e and canting_n are zero or "
                        "parallel; expected the facet's half-width and half-height vectors")
    normal /= length
    size = 2.0 * np.stack((np.linalg.norm(half_e, axis=-1), np.linalg.norm(half_n, axis=-1)), axis=-1)
    n, f64 = len(translation), torch.float64
    heliostat = Heliostat(
        position=torch.as_tensor(position, dtype=f64), mount="juelich",
        facet_translation=torch.as_tensor(translation, dtype=f64), facet_size=torch.as_tensor(size, dtype=f64),
        facet_normal=torch.as_tensor(normal, dtype=f64), facet_focal_length=None,
        control_heights=torch.zeros(n, CONTROL_POINTS, CONTROL_POINTS, dtype=f64),
        canting_error=torch.zeros(n, 2, dtype=f64),
        tracking_error=torch.zeros(len(TRACKING_PARAMETERS), dtype=f64),
    )
    source = {"source": "PAINT", "heliostat_properties": str(path),
              "concentrator_translation_enu_m": concentrator.tolist(),
              "canting_type": data.get("facet_properties", {}).get("canting_type"),
              "renovation": data.get("renovation")}
    return heliostat, source


def _facet_vectors(facets: list, path: Path, key: str) -> np.ndarray:
    """(F, 3) the vector `key` of every facet."""
    rows = []
    for i, f in enumerate(facets):
        where = f"facet_properties.facets[{i}]"
        if not isinstance(f, dict):
            raise DataError(f"{path}: {where} = {f!r}: expected an object")
        rows.append(field(f, path, key, "vec3", where=where))
    return np.array(rows, dtype=float)


def _sort_key(mid: str):
    return (not mid.isdigit(), int(mid) if mid.isdigit() else 0, mid)


def measurement_targets(paint_dir: str | os.PathLike, heliostat: str,
                        centered: str = CENTERED_DEFAULT) -> dict[str, str]:
    """{measurement id: target name} of a heliostat folder (numeric ids first, in order), read from
    each <id>-calibration-properties.json alone: what splitting a dataset into folds needs
    (`helioflow.workflow.expand_leave_one_out`); the import checks everything else. `centered`:
    "skip" leaves out the measurements without an <id>-flux.png."""
    folder = heliostat_folder(Path(paint_dir), heliostat)
    paths = sorted(folder.glob(f"*{CALIBRATION_SUFFIX}"), key=lambda p: _sort_key(p.name[: -len(CALIBRATION_SUFFIX)]))
    paths = [p for p in paths if centered == "place" or measurement_pngs(p)[0].is_file()]
    return {p.name[: -len(CALIBRATION_SUFFIX)]: field(read_json(p), p, "target_name", "string") for p in paths}


def read_measurements(folder: Path, tower: Tower, targets: list[str] | None,
                      centered: str = CENTERED_DEFAULT) -> list[Measurement]:
    """Every measurement of a heliostat folder (numeric ids first, in order), optionally only
    those on `targets`; with `centered` "skip" without those that have only their centered PNG
    (not read at all); DataError if there are none."""
    paths = sorted(folder.glob(f"*{CALIBRATION_SUFFIX}"),
                   key=lambda p: _sort_key(p.name[: -len(CALIBRATION_SUFFIX)]))
    if not paths:
        geometry = ("its heliostat-properties.json is there: import the geometry alone (--heliostat-output)"
                    if (folder / PROPERTIES_FILE).is_file() else "and no heliostat-properties.json either")
        raise DataError(f"{folder} has no measurements (no *{CALIBRATION_SUFFIX}); {geometry}")
    if centered == "skip":
        paths = [p for p in paths if not centered_only(p)]
        if not paths:
            raise DataError(f"{folder}: every measurement has only its <id>-flux-centered.png, which centered: skip "
                            "leaves out; import them with centered: place")
    measurements = [read_measurement(p, tower) for p in paths]
    if targets is not None:
        unknown = sorted(set(targets) - set(tower.planar_targets()))
        if unknown:
            raise DataError(f"targets {unknown} are not planar targets in {tower.path}; "
                            f"known: {', '.join(tower.planar_targets())}")
        measurements = [m for m in measurements if m.target_name in targets]
        if not measurements:
            raise DataError(f"{folder}: no measurement on targets {targets}")
    return measurements


def held_out(ids: list[str], holdout: Sequence[str] | dict) -> list[str]:
    """The held-out ids: `holdout` itself (a list of ids), or a seeded random share of `ids`
    ({fraction, seed}: round(fraction * N) of them, at least one, never all)."""
    if not isinstance(holdout, dict):
        return list(holdout)
    count = min(max(1, round(holdout["fraction"] * len(ids))), len(ids) - 1)
    chosen = set(np.random.default_rng(holdout.get("seed", 0)).choice(len(ids), count, replace=False).tolist())
    return [i for k, i in enumerate(ids) if k in chosen]


def split_labels(measurements: Sequence[SunPositioned], holdout: Sequence[str] | dict, folder: Path) -> np.ndarray:
    """(N,) split labels: train, or for held-out ids interpolation/extrapolation (module docstring);
    `holdout`: ids, or {fraction, seed} (`held_out`)."""
    ids = [m.id for m in measurements]
    holdout = held_out(ids, holdout)
    unknown = [h for h in holdout if h not in ids]
    if unknown:
        raise DataError(f"holdout ids {unknown} are not measurements in {folder}; "
                        f"measurements: {', '.join(ids)}")
    train = [m for m in measurements if m.id not in holdout]
    if not train:
        raise DataError(f"holdout holds every measurement of {folder}; at least one must stay for training")
    az = [m.azimuth_deg for m in train]
    el = [m.elevation_deg for m in train]

    def label(m: SunPositioned) -> str:
        if m.id not in holdout:
            return "train"
        inside = min(az) <= m.azimuth_deg <= max(az) and min(el) <= m.elevation_deg <= max(el)
        return "interpolation" if inside else "extrapolation"

    return np.array([label(m) for m in measurements])


NEIGHBOUR_RADIUS_M = 30.0  # heliostats whose pivots lie this close (horizontally) can shade or block each other


def neighbour_positions(paint_dir: Path, tower: Tower, heliostat: str, position: np.ndarray,
                        radius_m: float = NEIGHBOUR_RADIUS_M) -> list[list[float]]:
    """ENU pivots (m) of the other heliostats of a PAINT directory within `radius_m` (horizontal) of
    `position`: the folders beside the heliostat's with a heliostat-properties.json. A neighbour's
    unreadable file is skipped with a warning (it is not this import's input)."""
    out = []
    for path in sorted(Path(paint_dir).glob(f"*/{PROPERTIES_FILE}")):
        if path.parent.name == heliostat:
            continue
        try:
            pivot = tower.enu(field(read_json(path), path, "heliostat_position", "vec3"))
        except DataError as exc:
            log.warning("neighbour skipped: %s", exc)
            continue
        if math.hypot(*(np.asarray(pivot) - np.asarray(position))[:2]) <= radius_m:
            out.append([round(float(x), 4) for x in pivot])
    return out


def import_paint(
    paint_dir: str | os.PathLike,
    heliostat: str,
    dataset_path: str | os.PathLike | None = None,
    heliostat_path: str | os.PathLike | None = None,
    resolution: tuple[int, int] = (64, 64),
    holdout: Sequence[str] | dict = (),
    targets: list[str] | None = None,
    dataset: str | None = None,
    dni_w_m2: float = 1000.0,
    centered: str = CENTERED_DEFAULT,
) -> CalibrationDataset | None:
    """Import one PAINT heliostat folder (conventions in the module docstring).

    Everything is read and checked before anything is written; each output is written atomically
    and a failure removes what this call wrote, so bad input leaves no output file.

    Args:
        paint_dir: the PAINT directory (tower-measurements.json and heliostat folders).
        heliostat: the heliostat folder's name, e.g. "AA39".
        dataset_path: where to write the dataset (datasets/{dataset}.h5); None = don't.
        heliostat_path: where to write the ideal geometry (surfaces/{heliostat}.h5); None = don't.
            The geometry alone needs no measurements.
        resolution: (rows, columns) of the dataset images.
        holdout: measurement ids held out of training, or {fraction, seed} (module docstring: Splits).
        targets: import only measurements on these targets; None = all.
        dataset: the dataset's name (attribute); default the heliostat's.
        dni_w_m2: the nominal DNI (W/m^2) of the dataset's attribute (module docstring: Images).
        centered: "place" the measurements that have only their centered PNG on the target by their
            UTIS centroid, or "skip" them (module docstring: Centered measurements).

    Returns:
        The dataset written to `dataset_path`, or None when only the geometry was asked for.
    """
    if dataset_path is None and heliostat_path is None:
        raise HelioflowError("import_paint: nothing to write; give a dataset path, a heliostat path or both")
    if centered not in CENTERED_MODES:
        raise HelioflowError(f"import_paint: centered = {centered!r}; expected one of {', '.join(CENTERED_MODES)}")
    paint_dir = Path(paint_dir)
    tower = Tower(paint_dir / TOWER_FILE)
    folder = heliostat_folder(paint_dir, heliostat)
    measurements = read_measurements(folder, tower, targets, centered) if dataset_path is not None else []
    geometry, source = read_heliostat_properties(folder / PROPERTIES_FILE, tower)
    ds = None
    if dataset_path is not None:
        spec = {"paint_dir": str(paint_dir), "targets": targets, "dni_w_m2": float(dni_w_m2), "centered": centered}
        ds = build_paint_dataset(measurements, tower, geometry, (resolution[0], resolution[1]), holdout, folder,
                           dataset or heliostat, heliostat, spec)
        ds.attrs["neighbours_enu_m"] = neighbour_positions(paint_dir, tower, heliostat, geometry.position.numpy())
    write_imported(dataset_path, ds, heliostat_path, geometry, source=source)
    return ds


def write_imported(dataset_path: str | os.PathLike | None, ds: CalibrationDataset | None,
                   heliostat_path: str | os.PathLike | None, geometry: Heliostat, spec=None,
                   source: dict | None = None) -> None:
    """Write an import's dataset and heliostat (each path optional), both or neither: a failure
    in the second removes the first, so no half of an import looks complete."""
    written: list[Path] = []
    try:
        if dataset_path is not None:
            assert ds is not None  # a dataset path comes with its dataset
            write_dataset(dataset_path, ds)
            written.append(Path(dataset_path))
        if heliostat_path is not None:
            write_heliostat(heliostat_path, geometry, spec, source=source)
    except BaseException:
        for path in written:
            path.unlink(missing_ok=True)
        raise


def relative_flux_attrs(geometry: Heliostat, target: PlaneTarget, dni_w_m2: float, source_shape, ids: list[str],
                        params: dict) -> dict:
    """The dataset attributes that imported camera images (PAINT, own images) share: relative flux, each
    image normalised to its own peak; the target and heliostat geometry; the ids; the parameters' hash."""
    return {
        "conventions": CONVENTIONS.replace("flux in W/m^2 for the DNI in attribute dni_w_m2",
                                           "relative flux (see units)"),
        "per_image_normalised": True,
        "dni_w_m2": float(dni_w_m2),
        "source_image_shape": list(source_shape),
        "target_center_m": np.asarray(target.center).tolist(),
        "target_normal": np.asarray(target.normal).tolist(),
        "target_size_m": [target.width, target.height],
        **({} if target.aim is None else {"aim_point_m": np.asarray(target.aim).tolist()}),
        "heliostat_position_m": geometry.position.cpu().numpy().tolist(),
        "heliostat_mount": geometry.mount,
        "canting_focal_distance_m": canting_focal_distance(geometry),
        "measurement_ids": ids,
        "config_hash": config_hash(params),
        "helioflow_version": __version__,
    }


def build_paint_dataset(measurements: list[Measurement], tower: Tower, geometry: Heliostat,
                  resolution: tuple[int, int], holdout: Sequence[str] | dict, folder: Path, dataset: str,
                  heliostat: str, spec: dict) -> CalibrationDataset:
    """The CalibrationDataset of a heliostat's measurements (images resampled to `resolution`, centered
    ones placed on their targets)."""
    planes = [tower.target(m.target_name, folder) for m in measurements]
    raw = [read_centered_png(m.image_png) if m.centered else read_flux_png(m.image_png) for m in measurements]
    images = np.stack([place_centered(img, utis_on_target(m, p), p, resolution) if m.centered
                       else resample_area(img, resolution)
                       for img, m, p in zip(raw, measurements, planes)]).astype(np.float32)
    whole = [img.shape for img, m in zip(raw, measurements) if not m.centered]  # source_image_shape: theirs
    names = [p.name for p in planes]
    main = max(sorted(set(names)), key=names.count)
    ref = planes[names.index(main)]
    mixed = len(set(names)) > 1
    if mixed:
        log.warning("%s: measurements on %d targets (%s); root attributes target_* describe %s, "
                    "per-image geometry is in extras/target_*", folder, len(set(names)),
                    ", ".join(sorted(set(names))), main)
    params = {"dataset": dataset, "heliostat": heliostat, "resolution": list(resolution), "holdout": holdout,
              **spec}
    attrs = {
        "dataset": dataset,
        "heliostat": heliostat,
        "source": "PAINT calibration measurements (helioflow import-paint)",
        "paint_dir": spec["paint_dir"],
        "units": {"images": "relative (PNG grey level / 255, each image normalised to its peak)",
                  "angles": "deg", "lengths": "m"},
        **relative_flux_attrs(geometry, ref, spec["dni_w_m2"], whole[0] if whole else (UTIS_PIXELS, UTIS_PIXELS),
                              [m.id for m in measurements], params),
        "target_name": main,
        "targets": sorted(set(names)),
        "mixed_targets": mixed,
    }
    extras = {
        "measurement_id": np.array([m.id for m in measurements]),
        "target_name": np.array(names),
        "target_center_m": np.stack([p.center for p in planes]),
        "target_normal": np.stack([p.normal for p in planes]),
        "target_size_m": np.array([[p.width, p.height] for p in planes]),
        "aim_point_m": np.stack([p.center if p.aim is None else p.aim for p in planes]),
        "focal_spot_enu_m": np.stack([m.focal_spot_utis_m for m in measurements]),
        "focal_spot_helios_enu_m": np.stack([m.focal_spot_helios_m for m in measurements]),
        "motor_position": np.array([m.motor_position for m in measurements]),
        "centered": np.array([m.centered for m in measurements]),
    }
    return CalibrationDataset(
        images=images,
        azimuth_deg=np.array([m.azimuth_deg for m in measurements]),
        elevation_deg=np.array([m.elevation_deg for m in measurements]),
        split=split_labels(measurements, holdout, folder),
        attrs=attrs,
        extras=extras,
    )
