"""Import a plant's or lab's own calibration images: a folder of PNGs and a CSV (``source: images``).

Built like the PAINT import (``paint.py``), whose pieces it reuses (area resampling, the target
plane, heliostat-properties.json, the held-out splits, the dataset attributes), and written by
``hdf5.write_dataset`` with the same attributes, so every downstream rule works unchanged.

Input (docs/data.md, "Your own images"):

- ``csv``: one row per image; header row with the columns ``file`` (relative to ``images_dir``),
  optionally ``id`` (default: ``file`` without its extension; the id ``holdout`` names), and the sun
  as ``azimuth_deg`` and ``elevation_deg`` (helioflow's convention: azimuth 0 = south, +90 = east,
  -90 = west; elevation above the horizon), or as ``timestamp`` (ISO 8601 with a timezone, e.g.
  2023-06-01T10:30:00+02:00 or ...Z) with the site given once in the config (``site``). When both
  are there the angles are used and the timestamps kept (extras ``timestamp``). Blank lines are
  skipped; the file may start with a UTF-8 byte order mark (as spreadsheets write it).
- Sun from timestamps: astropy's ``get_sun`` in ``AltAz`` at the site (``EarthLocation``, WGS84), with
  the IERS tables astropy bundles (no download; a time beyond them takes UT1 - UTC as 0, which moves
  the sun by less than 0.004 deg, with a warning in the log). The elevation is the apparent one: refracted by a
  standard atmosphere (pressure of the standard atmosphere at the site's altitude, 15 degC, dry air,
  550 nm), as the sunlight reaching the heliostat comes from there (refraction lifts the sun by
  0.06 deg at 15 deg elevation, 0.01 deg at 60 deg). astropy's azimuth (0 = north, 90 = east)
  becomes helioflow's as 180 - azimuth (0 = south, +90 = east), wrapped to [-180, 180).
- Images: PNG, 8- or 16-bit greyscale (grey level / 255 or / 65535); colour images (RGB, RGBA,
  palette) are converted to grey by Pillow's luma (ITU-R 601). Each image shows the whole target
  (``target``: centre, normal towards the field, width and height), row 0 its upper edge and column 0
  its left edge as seen from the field (as the camera in the field sees it, not mirrored): the
  orientation of helioflow's images (geometry.plane_axes). Any size is accepted, the same for every
  image of a dataset (an image of another size is an error naming it: a crop or another camera
  setting); it is resampled to ``resolution`` by exact area averaging over the target
  (paint.resample_area: pixel centres keep their target coordinates). Pixels need not be square: a
  width : height ratio of the image other than the target's only gets a warning in the log.
- Intensities: a camera gives relative grey levels whose scale changes with exposure, gain, filters
  and the DNI from image to image; so each image is divided by its own peak (after resampling) and
  the dataset is marked ``per_image_normalised`` (as PAINT's): the physics models fit the images by
  shape, not in W/m^2. The source image's peak grey level (extras ``raw_peak``) and the share of its
  pixels at full scale (``saturated_fraction``; a warning when any) are kept: a saturated camera
  clips the spot's top. No background is subtracted (the models' camera effect can fit one).
- Heliostat: either inline (``heliostat``: the keys of a ``heliostats`` entry; the ideal geometry,
  the error keys must be 0: the errors are what the models fit) or a PAINT-style
  heliostat-properties.json (``heliostat_properties``, read by paint.read_heliostat_properties),
  whose WGS84 positions become ENU metres around ``origin_wgs84`` [lat, lon, alt] (the origin of the
  target's coordinates, e.g. the tower base). The geometry file is the dataset's heliostat:
  surfaces/<dataset>.h5 (surfaces/<dataset>.h5 of the parent for leave-one-out folds).
- A plant in one CSV: a ``heliostat`` column names each image's heliostat; the config entry's
  ``heliostats`` (all, a glob or a list of its values) becomes one dataset per heliostat
  (workflow.expand_plants), each reading only its heliostat's rows (``csv_heliostat``) and its own
  geometry (``heliostat_properties`` with ``{heliostat}`` in the path).
- Splits: ``splits`` (the rules of a traced dataset, data.splits.assign_splits), or ``holdout``
  (image ids, labelled as PAINT's: paint.split_labels), or neither (every image trains).

Errors are one DataError naming the file, the CSV line and the value (the CSV's header is line 1):
a missing, unreadable or wrongly sized image, missing columns, a bad number or timestamp, a
timestamp without a timezone, a sun below the horizon. Everything is read and checked before
anything is written; a failed write removes what the call wrote.

This module imports torch and astropy only where an import needs them: the workflow reads the CSV
(image_files, image_ids) when snakemake builds its DAG.
"""

from __future__ import annotations

import csv
import fnmatch
import logging
import math
import os
import warnings
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np

from helioflow.data.hdf5 import CalibrationDataset
from helioflow.data.paint import (
    PlaneTarget,
    read_grey_png,
    read_heliostat_properties,
    relative_flux_attrs,
    resample_area,
    split_labels,
    write_imported,
)
from helioflow.data.splits import assign_splits
from helioflow.data.surfaces import HeliostatSpec
from helioflow.errors import DataError, HelioflowError
from helioflow.physics.geometry import wgs84_to_enu

log = logging.getLogger(__name__)

FILE, ID, AZIMUTH, ELEVATION, TIMESTAMP = "file", "id", "azimuth_deg", "elevation_deg", "timestamp"
HELIOSTAT = "heliostat"  # the column naming each image's heliostat in a plant's CSV
HELIOSTAT_PLACEHOLDER = "{heliostat}"  # in a plant's heliostat_properties path: each heliostat's name
ERROR_KEYS = ("deformation_mm", "tracking_error_mrad", "canting_error_mrad")  # must be 0 inline
TARGET_NAME = "target"  # the one target of an images dataset (attribute target_name)
ASPECT_TOLERANCE = 0.02  # image and target width : height ratios differing by more: a warning
STANDARD_TEMPERATURE_C = 15.0
OBSERVED_WAVELENGTH_UM = 0.55
# a site without altitude_m stands at sea level: the schema's default of datasets.<name>.site.altitude_m, which
# tests/test_config.py checks it against; here too for the sites the schema fills nothing into (plan.site, a
# dataset file's recorded site), as a schema default for plan.site would change the plan rule's parameters
SITE_ALTITUDE_M = 0.0


@dataclass(frozen=True)
class Row:
    """One CSV row: its line, image id and path, sun position (deg) and timestamp text ('' if none)."""

    line: int
    id: str
    file: str
    path: Path
    azimuth_deg: float
    elevation_deg: float
    timestamp: str


# --- the CSV (also read by snakemake's input functions) ------------------------------------------


def read_table(csv_path: str | os.PathLike,
               heliostat: str | None = None) -> tuple[list[str], list[tuple[int, dict[str, str]]]]:
    """(columns, [(line, {column: value})]) of a CSV with a header row, names and values stripped;
    with `heliostat`, only the rows whose `heliostat` column names it. DataError if it is missing,
    unreadable, has no header, no `file` column or no rows (of that heliostat)."""
    path = Path(csv_path)
    if not path.is_file():
        raise DataError(f"{path} does not exist (expected the CSV of the calibration images)")
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            reader = csv.reader(f)
            header = next(reader, None)
            rows = [(reader.line_num, cells) for cells in reader if any(c.strip() for c in cells)]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DataError(f"{path}: not a readable CSV file: {exc}") from None
    columns = [c.strip() for c in header or []]
    if FILE not in columns:
        found = ", ".join(repr(c) for c in columns if c) or "none"
        raise DataError(f"{path}: no column {FILE!r} (columns found: {found}); expected a header row with "
                        f"{FILE} and {AZIMUTH}, {ELEVATION} or {TIMESTAMP}")
    duplicated = sorted({c for c in columns if c and columns.count(c) > 1})
    if duplicated:
        raise DataError(f"{path}: column {duplicated[0]!r} appears twice in the header row")
    if not rows:
        raise DataError(f"{path} has a header row but no images (one row per image expected)")
    table = []
    for line, cells in rows:
        if len(cells) > len(columns):
            raise DataError(f"{path} line {line}: {len(cells)} values, but the header has {len(columns)} columns")
        table.append((line, {c: (cells[i].strip() if i < len(cells) else "") for i, c in enumerate(columns)}))
    if heliostat is None:
        return columns, table
    if HELIOSTAT not in columns:
        raise DataError(f"{path}: no column {HELIOSTAT!r} (columns found: {', '.join(columns)}); a plant's CSV names "
                        "each image's heliostat there")
    mine = [(line, row) for line, row in table if row[HELIOSTAT] == heliostat]
    if not mine:
        raise DataError(f"{path}: no image of heliostat {heliostat!r} in column {HELIOSTAT!r}")
    return columns, mine


def csv_heliostats(csv_path: str | os.PathLike, selection) -> list[str]:
    """The heliostats a plant entry takes from its CSV's `heliostat` column, in the order they first
    appear: `all`, a glob over the names, or a list of them (in its order); DataError naming the
    column or the name when the column is missing or blank in a row, or the selection finds none."""
    path = Path(csv_path)
    columns, table = read_table(path)
    if HELIOSTAT not in columns:
        raise DataError(f"{path}: no column {HELIOSTAT!r} (columns found: {', '.join(columns)}); a plant's CSV "
                        "names each image's heliostat there")
    for line, row in table:
        if not row[HELIOSTAT]:
            raise DataError(f"{path} line {line}: column {HELIOSTAT!r} is empty; expected the image's heliostat")
    names = list(dict.fromkeys(row[HELIOSTAT] for _, row in table))
    if isinstance(selection, list):
        missing = [h for h in selection if h not in names]
        if missing:
            raise DataError(f"{path}: no image of heliostat {missing[0]!r} in column {HELIOSTAT!r} "
                            f"(heliostats there: {', '.join(names)})")
        return list(dict.fromkeys(selection))
    chosen = names if selection == "all" else [h for h in names if fnmatch.fnmatchcase(h, selection)]
    if not chosen:
        raise DataError(f"{path}: {selection!r} selects no heliostat of column {HELIOSTAT!r} "
                        f"(heliostats there: {', '.join(names)})")
    return chosen


def _ids(csv_path: Path, table) -> list[tuple[int, str, str]]:
    """[(line, id, file)] of the rows; DataError on an empty file name or a repeated id."""
    seen: dict[str, int] = {}
    out = []
    for line, row in table:
        name = row[FILE]
        if not name:
            raise DataError(f"{csv_path} line {line}: column {FILE!r} is empty; expected the image's path "
                            "relative to images_dir")
        mid = row.get(ID) or Path(name).with_suffix("").as_posix()
        if mid in seen:
            raise DataError(f"{csv_path} line {line}: id {mid!r} is also the id of line {seen[mid]}; "
                            f"every image needs its own id (column {ID!r}, default the file name without extension)")
        seen[mid] = line
        out.append((line, mid, name))
    return out


def check_files(csv_path: str | os.PathLike, images_dir: str | os.PathLike, heliostat: str | None = None) -> None:
    """DataError naming the CSV line when a row's file lies outside images_dir once '..' and links
    are resolved (an absolute path, '../', a link to elsewhere: nothing outside the folder is opened),
    or when two rows name the same file (one image, two sun positions); of one heliostat's rows
    when given (read_table)."""
    csv_path = Path(csv_path)
    _check_paths(csv_path, images_dir, _ids(csv_path, read_table(csv_path, heliostat)[1]))


def _check_paths(csv_path: Path, images_dir: str | os.PathLike, ids: list[tuple[int, str, str]]) -> None:
    """check_files on the rows' [(line, id, file)] (_ids)."""
    folder = Path(images_dir).resolve()
    seen: dict[Path, int] = {}
    for line, _, name in ids:
        path = (folder / name).resolve()
        if not path.is_relative_to(folder):
            raise DataError(f"{csv_path} line {line}: {FILE} {name!r} is {path}, outside images_dir {folder}; "
                            "every image must lie inside images_dir (after resolving '..' and links)")
        if path in seen:
            raise DataError(f"{csv_path} lines {seen[path]} and {line} both name the image {path}; each image is "
                            "one measurement at one sun position: remove one of the lines")
        seen[path] = line


def image_ids(csv_path: str | os.PathLike, heliostat: str | None = None) -> list[str]:
    """The image ids of a CSV (of one heliostat's rows when given), in its order (what holdout and
    leave-one-out name)."""
    return [mid for _, mid, _ in _ids(Path(csv_path), read_table(csv_path, heliostat)[1])]


def image_files(csv_path: str | os.PathLike, images_dir: str | os.PathLike, heliostat: str | None = None) -> list[str]:
    """The image paths a CSV lists (images_dir/file; of one heliostat's rows when given), in its
    order; [] when the CSV cannot be read (the import then reports why)."""
    try:
        table = read_table(csv_path, heliostat)[1]
    except DataError:
        return []
    return [str(Path(images_dir) / row[FILE]) for _, row in table if row[FILE]]


# --- the sun -------------------------------------------------------------------------------------


def parse_timestamp(text: str, where: str) -> datetime:
    """An ISO 8601 time with a timezone; DataError naming `where` otherwise."""
    try:
        stamp = datetime.fromisoformat(text)
    except ValueError:
        raise DataError(f"{where}: {TIMESTAMP} = {text!r} is not an ISO 8601 time; expected e.g. "
                        "2023-06-01T10:30:00+02:00") from None
    if stamp.tzinfo is None or stamp.utcoffset() is None:
        raise DataError(f"{where}: {TIMESTAMP} = {text!r} has no timezone; expected an offset or Z, e.g. "
                        f"{text}+02:00 or {text}Z (local time is ambiguous)")
    return stamp


def sun_position(timestamps: list[datetime], site: dict) -> tuple[np.ndarray, np.ndarray]:
    """(azimuth_deg, elevation_deg), each (N,), of the sun at timezone-aware `timestamps` seen from
    `site` {latitude_deg, longitude_deg, altitude_m (default SITE_ALTITUDE_M)}: helioflow's azimuth
    (0 = south, +90 = east) and the apparent (refracted) elevation (module docstring)."""
    import astropy.units as u
    from astropy.utils import iers

    iers.conf.auto_download = False  # no network: the IERS tables astropy bundles suffice
    iers.conf.auto_max_age = None  # ... however old their predictions are (else an error 30 days on)
    # a time outside those tables (before 1962, or past their predictions) takes UT1 - UTC as 0 (< 0.9 s:
    # < 0.004 deg of sun) and the mean polar motion, with a warning, instead of an error
    iers.conf.iers_degraded_accuracy = "warn"
    from astropy.coordinates import AltAz, EarthLocation, get_sun
    from astropy.time import Time

    altitude = float(site.get("altitude_m", SITE_ALTITUDE_M))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        location = EarthLocation.from_geodetic(lon=site["longitude_deg"] * u.deg, lat=site["latitude_deg"] * u.deg,
                                               height=altitude * u.m)
        times = Time(list(timestamps))
        pressure = 101.325 * (1.0 - 2.25577e-5 * altitude) ** 5.25588  # standard atmosphere, kPa
        frame = AltAz(obstime=times, location=location, pressure=pressure * u.kPa,
                      temperature=STANDARD_TEMPERATURE_C * u.deg_C, relative_humidity=0.0,
                      obswl=OBSERVED_WAVELENGTH_UM * u.micron)
        sun = get_sun(times).transform_to(frame)
    if caught:
        log.warning("sun positions: some times lie outside astropy's bundled IERS tables (%s to %s given); their "
                    "sun is good to about 0.004 deg (astropy: %s)", min(timestamps).isoformat(),
                    max(timestamps).isoformat(), str(caught[0].message).splitlines()[0][:200])
    azimuth = (180.0 - np.asarray(sun.az.deg, dtype=float) + 180.0) % 360.0 - 180.0
    return azimuth, np.asarray(sun.alt.deg, dtype=float)


def _csv_number(csv_path: Path, line: int, row: dict, column: str) -> float:
    text = row[column]
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise DataError(f"{csv_path} line {line}: {column} = {text!r}: expected a finite number of degrees")
    return value


def read_rows(csv_path: str | os.PathLike, images_dir: str | os.PathLike,
              site: dict | None = None, heliostat: str | None = None) -> tuple[list[Row], str]:
    """Every CSV row (of one heliostat when given) with its sun position, and where the sun came from
    (words); DataError naming the file and line of the first bad value (module docstring). Does not
    open the images."""
    csv_path, images_dir = Path(csv_path), Path(images_dir)
    columns, table = read_table(csv_path, heliostat)
    angles = [c for c in (AZIMUTH, ELEVATION) if c in columns]
    if len(angles) == 1:
        other = ELEVATION if angles[0] == AZIMUTH else AZIMUTH
        raise DataError(f"{csv_path}: column {angles[0]!r} without {other!r}; give both, or {TIMESTAMP!r}")
    if not angles and TIMESTAMP not in columns:
        raise DataError(f"{csv_path}: no sun position: expected the columns {AZIMUTH} and {ELEVATION}, or "
                        f"{TIMESTAMP} (columns found: {', '.join(columns)})")
    ids = _ids(csv_path, table)
    _check_paths(csv_path, images_dir, ids)
    rows = [row for _, row in table]
    if angles:
        az = np.array([_csv_number(csv_path, line, row, AZIMUTH) for (line, _, _), row in zip(ids, rows)])
        el = np.array([_csv_number(csv_path, line, row, ELEVATION) for (line, _, _), row in zip(ids, rows)])
        for (line, _, _), a in zip(ids, az):
            if not -180 <= a <= 360:
                raise DataError(f"{csv_path} line {line}: {AZIMUTH} = {a:g}: expected degrees in [-180, 360] "
                                "(0 = south, +90 = east, -90 = west)")
        az = (az + 180.0) % 360.0 - 180.0
        source = f"columns {AZIMUTH}, {ELEVATION}"
    else:
        if not site:
            raise DataError(f"{csv_path}: the sun is given by {TIMESTAMP}, which needs the site: give the dataset's "
                            "site {latitude_deg, longitude_deg, altitude_m}")
        stamps = [parse_timestamp(row[TIMESTAMP], f"{csv_path} line {line}") for (line, _, _), row in zip(ids, rows)]
        az, el = sun_position(stamps, site)
        source = (f"column {TIMESTAMP} at latitude {site['latitude_deg']:g} deg, longitude "
                  f"{site['longitude_deg']:g} deg: astropy get_sun in AltAz, apparent (refracted) elevation")
    for (line, mid, _), row, e in zip(ids, rows, el):
        when = "" if angles else f" at {row[TIMESTAMP]}"
        if e <= 0:
            raise DataError(f"{csv_path} line {line} (image {mid}): sun elevation {e:.2f} deg{when}: the sun is "
                            "below the horizon; expected 0 < elevation <= 90")
        if e > 90:
            raise DataError(f"{csv_path} line {line} (image {mid}): {ELEVATION} = {e:g}: expected 0 < elevation <= 90")
    return [Row(line, mid, name, images_dir / name, float(a), float(e), row.get(TIMESTAMP, ""))
            for (line, mid, name), row, a, e in zip(ids, rows, az, el)], source


# --- the images ------------------------------------------------------------------------------------


# --- the heliostat -----------------------------------------------------------------------------------


def check_ideal(heliostat: dict, where: str) -> None:
    """HelioflowError when an inline heliostat sets an error scale other than 0."""
    for key in ERROR_KEYS:
        if heliostat.get(key, 0.0):
            raise HelioflowError(f"{where}.{key} = {heliostat[key]!r}: an imported dataset's heliostat is the "
                                 "ideal one (its errors are what the models fit); remove the key or set it to 0")


class WGS84Origin:
    """The ENU frame around a WGS84 point [lat deg, lon deg, alt m]: what paint.read_heliostat_properties
    needs of PAINT's tower file."""

    def __init__(self, origin):
        self.origin = tuple(float(x) for x in origin)

    def enu(self, wgs84) -> np.ndarray:
        """(..., 3) WGS84 (lat deg, lon deg, alt m) -> (..., 3) ENU m around the origin."""
        p = np.asarray(wgs84, dtype=float)
        return wgs84_to_enu(p[..., 0], p[..., 1], p[..., 2], *self.origin)


def read_geometry(spec: dict):
    """(the ideal Heliostat (float64), its provenance) of an images dataset's spec: inline
    (`heliostat_geometry`) or from `heliostat_properties` around `origin_wgs84`."""
    name = spec["heliostat"]
    if spec.get("heliostat_geometry") is not None:
        section = spec["heliostat_geometry"]
        check_ideal(section, f"datasets.{spec.get('dataset', name)}.heliostat")
        s = HeliostatSpec.from_config(name, section)
        return s.ideal(), {"source": "config (ideal)", "spec": section}, s
    path = spec.get("heliostat_properties")
    if path is None:
        raise HelioflowError("import-images: the spec has neither heliostat_geometry nor heliostat_properties")
    path = Path(path)
    if not path.is_file():
        raise DataError(f"heliostat_properties: {path} does not exist (expected a PAINT-style "
                        "heliostat-properties.json)")
    if spec.get("origin_wgs84") is None:
        raise HelioflowError(f"heliostat_properties {path}: its positions are WGS84; give origin_wgs84 "
                             "[latitude, longitude, altitude], the origin of the ENU frame of the target")
    heliostat, source = read_heliostat_properties(path, WGS84Origin(spec["origin_wgs84"]))
    source = {**source, "source": "heliostat-properties.json", "origin_wgs84": list(spec["origin_wgs84"])}
    return heliostat, source, None


# --- the import ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Held:
    """What paint.split_labels reads of a measurement."""

    id: str
    azimuth_deg: float
    elevation_deg: float


def import_images(spec: dict, dataset_path: str | os.PathLike | None = None,
                  heliostat_path: str | os.PathLike | None = None):
    """Import a folder of calibration images (conventions in the module docstring).

    Args:
        spec: the rule's parameters (helioflow.workflow.import_images_params): dataset, heliostat (the
            geometry file's name), images_dir, csv, resolution, target {center_m, normal, width_m,
            height_m}, site, heliostat_geometry or heliostat_properties + origin_wgs84, splits,
            holdout, seed, dni_w_m2. The geometry alone (images_heliostat_params) needs only
            heliostat and the geometry's keys.
        dataset_path: where to write the dataset (datasets/{dataset}.h5); None = don't.
        heliostat_path: where to write the ideal geometry (surfaces/{heliostat}.h5); None = don't.

    Returns:
        The dataset written to `dataset_path`, or None when only the geometry was asked for.
    """
    if dataset_path is None and heliostat_path is None:
        raise HelioflowError("import_images: nothing to write; give a dataset path, a heliostat path or both")
    geometry, source, heliostat_spec = read_geometry(spec)
    ds = build_image_dataset(spec, geometry) if dataset_path is not None else None
    write_imported(dataset_path, ds, heliostat_path, geometry, heliostat_spec, source=source)
    return ds


def target_plane(target: dict, where: str = "target"):
    """paint.PlaneTarget of a dataset's `target` section (normal made unit)."""

    normal = np.asarray(target["normal"], dtype=float)
    length = np.linalg.norm(normal)
    if not length > 0:
        raise HelioflowError(f"{where}.normal = {target['normal']}: expected a non-zero vector")
    return PlaneTarget(TARGET_NAME, np.asarray(target["center_m"], dtype=float), normal / length,
                       float(target["width_m"]), float(target["height_m"]))


def build_image_dataset(spec: dict, geometry):
    """The CalibrationDataset of the images a spec names (resampled, each divided by its peak)."""

    csv_path = Path(spec["csv"])
    rows, sun_from = read_rows(csv_path, spec["images_dir"], spec.get("site"), spec.get("csv_heliostat"))
    resolution = tuple(spec["resolution"])
    plane = target_plane(spec["target"], f"datasets.{spec['dataset']}.target")
    position = geometry.position.numpy()
    if float(np.dot(position - plane.center, plane.normal)) <= 0:
        raise DataError(f"datasets.{spec['dataset']}: the heliostat at {np.round(position, 3).tolist()} m is not in "
                        f"front of the target (center_m {spec['target']['center_m']}, "
                        f"normal {spec['target']['normal']}, "
                        "which points towards the heliostat): it cannot see it")
    missing = [r for r in rows if not r.path.is_file()]
    if missing:
        r = missing[0]
        more = f" ({len(missing)} of {len(rows)} images are missing)" if len(missing) > 1 else ""
        raise DataError(f"{csv_path} line {r.line} (image {r.id}): {FILE} {r.file!r}: {r.path} does not exist{more}")
    raw, saturated = [], []
    shape: tuple[int, ...] | None = None
    for r in rows:
        where = f"{csv_path} line {r.line} (image {r.id})"
        image, full = read_grey_png(r.path, where, "remove its row or repair the image")
        if shape is None:
            shape = image.shape
        elif image.shape != shape:
            raise DataError(f"{where}: {r.path} is {image.shape[1]} x {image.shape[0]} pixels (width x height), the "
                            f"images before it {shape[1]} x {shape[0]}; every image must show the whole target at "
                            "the same size (each is then resampled to the resolution)")
        raw.append(image)
        saturated.append(full)
    assert shape is not None  # rows is not empty
    aspect_image, aspect_target = shape[1] / shape[0], plane.width / plane.height
    if abs(aspect_image / aspect_target - 1.0) > ASPECT_TOLERANCE:
        log.warning("%s: the images are %d x %d pixels (width : height %.3f), the target %.3f m x %.3f m (%.3f): "
                    "their pixels are not square on the target; check target.width_m and height_m", csv_path,
                    shape[1], shape[0], aspect_image, plane.width, plane.height, aspect_target)
    clipped = [r.id for r, s in zip(rows, saturated) if s > 0]
    if clipped:
        log.warning("%s: %d images have pixels at full scale (saturated: the spot's top is clipped): %s", csv_path,
                    len(clipped), ", ".join(clipped[:10]))
    images = np.stack([resample_area(img, resolution) for img in raw])
    images = (images / images.max(axis=(1, 2), keepdims=True)).astype(np.float32)
    az = np.array([r.azimuth_deg for r in rows])
    el = np.array([r.elevation_deg for r in rows])
    holdout, splits = spec.get("holdout") or [], spec.get("splits")
    if holdout and splits:
        raise HelioflowError(f"datasets.{spec['dataset']}: give splits (rules) or holdout (image ids), not both")
    if holdout:
        labels = split_labels([_Held(r.id, r.azimuth_deg, r.elevation_deg) for r in rows], holdout, csv_path)
    elif splits:
        labels = assign_splits(az, el, splits, spec.get("seed", 0))
    else:
        labels = np.full(len(rows), "train")
    timestamps = any(r.timestamp for r in rows)
    attrs = {
        "dataset": spec["dataset"],
        "heliostat": spec["heliostat"],
        "source": "own calibration images (helioflow import-images)",
        "images_dir": str(spec["images_dir"]),
        "csv": str(csv_path),
        **({"csv_heliostat": spec["csv_heliostat"]} if spec.get("csv_heliostat") else {}),
        "sun_from": sun_from,
        "site": spec.get("site"),
        "units": {"images": "relative (grey level / full scale, each image divided by its own peak)",
                  "angles": "deg", "lengths": "m"},
        **relative_flux_attrs(geometry, plane, spec.get("dni_w_m2", 1000.0), shape, [r.id for r in rows], spec),
        "target_name": TARGET_NAME,
        "targets": [TARGET_NAME],
        "mixed_targets": False,
    }
    extras = {
        "measurement_id": np.array([r.id for r in rows]),
        "file": np.array([r.file for r in rows]),
        "raw_peak": np.array([img.max() for img in raw]),
        "saturated_fraction": np.array(saturated),
    }
    if timestamps:
        extras["timestamp"] = np.array([r.timestamp for r in rows])
    return CalibrationDataset(images=images, azimuth_deg=az, elevation_deg=el, split=labels, attrs=attrs,
                              extras=extras)
