"""HDF5 file schema: the one place that reads and writes helioflow's ``.h5`` files.

Calibration datasets (schema ``helioflow.dataset/1``) are laid out as::

    images             (N, H, W) float32, flux in W/m^2, gzip, one chunk per image
    sun/azimuth_deg    (N,) float64, degrees
    sun/elevation_deg  (N,) float64, degrees, in (0, 90]
    split              (N,) UTF-8 strings from SPLITS
    extras/<name>      (N, ...) optional per-image arrays
    root attributes    the dataset's attrs plus ``schema``

Other file kinds use the generic ``write_arrays`` / ``read_arrays`` with their own schema string.
Every write is atomic (helioflow.io.write_atomic); every read failure caused by a
missing, corrupt or malformed file raises one ``DataError`` naming the file and what was expected.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from helioflow.errors import DataError
from helioflow.io import write_atomic

SPLITS = ("train", "interpolation", "extrapolation")
DATASET_SCHEMA = "helioflow.dataset/1"

_JSON_PREFIX = "json:"
_UNITS = {"images": "W/m^2", "sun/azimuth_deg": "deg", "sun/elevation_deg": "deg"}


def _encode_attr(key: str, value):
    """Attribute value as stored: str/bool/int/float as-is, anything else as ``json:<JSON>``."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, (bool, int, float)) or (
        isinstance(value, str) and not value.startswith(_JSON_PREFIX)
    ):
        return value
    try:
        return _JSON_PREFIX + json.dumps(value)
    except TypeError as exc:
        raise DataError(f"attribute {key!r} = {value!r} is not JSON-serialisable: {exc}") from None


def _decode_attr(value):
    """Inverse of ``_encode_attr``; numpy scalars and arrays become Python values."""
    if isinstance(value, bytes):
        value = value.decode("utf-8")
    if isinstance(value, str):
        return json.loads(value[len(_JSON_PREFIX):]) if value.startswith(_JSON_PREFIX) else value
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    return value


def write_arrays(
    path: str | os.PathLike,
    arrays: dict[str, np.ndarray],
    attrs: dict,
    schema: str,
    units: dict[str, str] | None = None,
) -> None:
    """Atomically write named arrays and root attributes to ``path``.

    Keys may contain '/' to place arrays in groups. String arrays are stored as variable-length
    UTF-8; numeric arrays are gzip-compressed, arrays of ndim >= 3 chunked one leading index
    (e.g. one image) per chunk. ``attrs`` values must be JSON-able; ``schema`` is stored as the
    root attribute ``schema``; ``units`` maps array keys to a ``units`` attribute on that array.
    """
    if "schema" in attrs:
        raise DataError(f"{path}: attribute name 'schema' is reserved; rename that attribute")
    write_atomic(path, lambda tmp: _write_h5(tmp, arrays, attrs, schema, units))


def _write_h5(path: Path, arrays: dict[str, np.ndarray], attrs: dict, schema: str,
              units: dict[str, str] | None) -> None:
    with h5py.File(path, "w") as f:
        for key, value in arrays.items():
            arr = np.asarray(value)
            if arr.dtype.kind in "UO":
                f.create_dataset(key, data=arr.astype(object), dtype=h5py.string_dtype("utf-8"))
            elif arr.ndim == 0 or arr.size == 0:
                f.create_dataset(key, data=arr)
            else:
                chunks = (1, *arr.shape[1:]) if arr.ndim >= 3 else True
                f.create_dataset(key, data=arr, compression="gzip", chunks=chunks)
        for key, unit in (units or {}).items():
            f[key].attrs["units"] = unit
        for key, value in attrs.items():
            f.attrs[key] = _encode_attr(key, value)
        f.attrs["schema"] = schema


def read_arrays(
    path: str | os.PathLike, schema: str, required: Iterable[str] = ()
) -> tuple[dict[str, np.ndarray], dict]:
    """Read every array and the root attributes of a file written by ``write_arrays``.

    Returns ``(arrays, attrs)``: arrays keyed by their full '/'-joined path (string arrays as
    numpy ``str`` arrays), attrs decoded and without ``schema``. Raises DataError if the file is
    missing or unreadable, its ``schema`` attribute is not ``schema``, or a ``required`` key is
    absent.
    """
    if not Path(path).is_file():
        raise DataError(f"{path} does not exist (expected an HDF5 file with schema {schema!r})")
    try:
        with h5py.File(path, "r") as f:
            found = f.attrs.get("schema")
            if found is None:
                raise DataError(
                    f"{path} has no 'schema' attribute; expected schema {schema!r} "
                    "(not a helioflow file?)"
                )
            if _decode_attr(found) != schema:
                raise DataError(f"{path} has schema {_decode_attr(found)!r}, expected {schema!r}")
            for key in required:
                if not isinstance(f.get(key), h5py.Dataset):
                    raise DataError(f"{path} is missing the array {key!r} (required for {schema!r})")
            names: list[str] = []
            f.visititems(lambda name, obj: names.append(name) if isinstance(obj, h5py.Dataset) else None)
            arrays = {name: _read_dataset(f[name]) for name in names}
            attrs = {k: _decode_attr(v) for k, v in f.attrs.items() if k != "schema"}
    except OSError as exc:
        raise DataError(f"{path} is not a readable HDF5 file (truncated or corrupt?): {exc}") from None
    return arrays, attrs


def _read_dataset(dset: h5py.Dataset) -> np.ndarray:
    if h5py.check_string_dtype(dset.dtype) is not None:
        return np.asarray(dset.asstr()[()], dtype=str)
    return dset[()]


@dataclass
class CalibrationDataset:
    """Calibration images of one heliostat's focal spot and the sun positions they were taken at.

    images:        (N, H, W) float32, flux density on the target in W/m^2, finite and >= 0.
    azimuth_deg:   (N,) float64, sun azimuth in degrees.
    elevation_deg: (N,) float64, sun elevation in degrees, in (0, 90].
    split:         (N,) str, each one of SPLITS.
    attrs:         JSON-able metadata (nested dicts and lists allowed).
    extras:        optional per-image arrays with leading dimension N, e.g.
                   "fill_fraction" (N,) or "centroid_m" (N, 2).
    """

    images: np.ndarray
    azimuth_deg: np.ndarray
    elevation_deg: np.ndarray
    split: np.ndarray
    attrs: dict = field(default_factory=dict)
    extras: dict[str, np.ndarray] = field(default_factory=dict)

    def indices(self, split: str) -> np.ndarray:
        """Indices (K,) int of the images labelled ``split``."""
        if split not in SPLITS:
            raise ValueError(f"unknown split {split!r}; expected one of {SPLITS}")
        return np.flatnonzero(np.asarray(self.split) == split)


def _validate(ds: CalibrationDataset, path) -> None:
    """Raise DataError naming ``path`` if ``ds`` has inconsistent shapes or out-of-range values."""
    images = np.asarray(ds.images)
    if images.ndim != 3:
        raise DataError(f"{path}: images has shape {images.shape}, expected (N, H, W)")
    if images.dtype.kind not in "fiu":
        raise DataError(f"{path}: images has dtype {images.dtype}, expected float flux in W/m^2")
    n = images.shape[0]
    for name in ("azimuth_deg", "elevation_deg", "split"):
        shape = np.shape(getattr(ds, name))
        if shape != (n,):
            raise DataError(f"{path}: {name} has shape {shape}, expected ({n},) to match images")
    for name, arr in ds.extras.items():
        shape = np.shape(arr)
        if shape[:1] != (n,):
            raise DataError(f"{path}: extras/{name} has shape {shape}, expected leading dimension {n}")
    _check_images(images, path, ds)
    if not np.isfinite(ds.azimuth_deg).all():
        raise DataError(f"{path}: azimuth_deg contains NaN or infinite values")
    elevation = np.asarray(ds.elevation_deg)
    bad = ~((elevation > 0) & (elevation <= 90))
    if bad.any():
        raise DataError(
            f"{path}: elevation_deg {elevation[bad][0]!r} at index {np.flatnonzero(bad)[0]} "
            "is outside (0, 90] degrees"
        )
    unknown = sorted(set(np.asarray(ds.split).tolist()) - set(SPLITS))
    if unknown:
        raise DataError(f"{path}: unknown split labels {unknown}; expected only {SPLITS}")


def _check_images(images: np.ndarray, path, ds: CalibrationDataset) -> None:
    """Every image holds finite, non-negative flux that is not the same in every pixel (all zero,
    or saturated): such an image carries no focal spot and would only flatter the scores."""
    flat = images.reshape(len(images), -1)

    def where(i: int) -> str:
        return (f"image {i} (split {ds.split[i]}, sun azimuth {float(ds.azimuth_deg[i]):.2f} deg, "
                f"elevation {float(ds.elevation_deg[i]):.2f} deg)")

    finite = np.isfinite(flat).all(1)
    low, high = flat.min(1, initial=np.inf), flat.max(1, initial=-np.inf)
    for bad, problem in ((~finite, "holds NaN or infinite flux; expected finite W/m^2"),
                         (finite & (low < 0), "holds negative flux; expected >= 0")):
        if bad.any():
            raise DataError(f"{path}: {where(int(np.flatnonzero(bad)[0]))} {problem} ({int(bad.sum())} such image(s))")
    uniform = high <= low
    if uniform.any():
        i = int(np.flatnonzero(uniform)[0])
        what = "is all zero" if high[i] == 0 else f"is {high[i]:g} W/m^2 in every pixel (saturated?)"
        raise DataError(f"{path}: {where(i)} {what}: it shows no focal spot ({int(uniform.sum())} such image(s), "
                        f"indices {np.flatnonzero(uniform)[:10].tolist()}); remove it or repair the measurement")


def write_dataset(path: str | os.PathLike, ds: CalibrationDataset) -> None:
    """Validate ``ds`` and write it atomically to ``path`` (layout in the module docstring)."""
    _validate(ds, path)
    arrays: dict[str, np.ndarray] = {
        "images": np.asarray(ds.images, dtype=np.float32),
        "sun/azimuth_deg": np.asarray(ds.azimuth_deg, dtype=np.float64),
        "sun/elevation_deg": np.asarray(ds.elevation_deg, dtype=np.float64),
        "split": np.asarray(ds.split, dtype=str),
    }
    arrays.update({f"extras/{name}": np.asarray(arr) for name, arr in ds.extras.items()})
    write_arrays(path, arrays, ds.attrs, DATASET_SCHEMA, units=_UNITS)


def read_dataset(path: str | os.PathLike) -> CalibrationDataset:
    """Read and validate a calibration dataset written by ``write_dataset``."""
    arrays, attrs = read_arrays(
        path, DATASET_SCHEMA, required=("images", "sun/azimuth_deg", "sun/elevation_deg", "split")
    )
    ds = CalibrationDataset(
        images=arrays.pop("images"),
        azimuth_deg=arrays.pop("sun/azimuth_deg"),
        elevation_deg=arrays.pop("sun/elevation_deg"),
        split=arrays.pop("split"),
        attrs=attrs,
        extras={key.removeprefix("extras/"): arr for key, arr in arrays.items() if key.startswith("extras/")},
    )
    _validate(ds, path)
    ds.images = ds.images.astype(np.float32, copy=False)
    return ds
