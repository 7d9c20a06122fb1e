"""Label sun positions as train / interpolation / extrapolation.

Extrapolation positions lie outside the training range by a configured criterion; interpolation
positions are a seeded random subset of the rest chosen strictly inside the training range, so a
model is tested both between and beyond the sun positions it was trained on.
"""

from __future__ import annotations

import numpy as np

from helioflow.data.hdf5 import SPLITS
from helioflow.errors import ConfigError

_SPEC_KEYS = {
    "extrapolation": {"elevation_above_deg", "elevation_below_deg", "azimuth_outside_deg"},
    "interpolation": {"fraction", "elevation_bands_deg"},
}


def _check_spec(spec: dict) -> None:
    """Raise ConfigError for unknown keys or values of the wrong type/range in a split spec."""
    for section, entries in spec.items():
        if section not in _SPEC_KEYS:
            raise ConfigError(f"unknown split spec key {section!r}; expected one of {sorted(_SPEC_KEYS)}")
        for key in entries or {}:
            if key not in _SPEC_KEYS[section]:
                raise ConfigError(
                    f"unknown split spec key {section}.{key!r}; expected one of {sorted(_SPEC_KEYS[section])}"
                )
    extrap = spec.get("extrapolation") or {}
    for key in ("elevation_above_deg", "elevation_below_deg"):
        value = extrap.get(key)
        if value is not None and not isinstance(value, (int, float)):
            raise ConfigError(
                f"split spec extrapolation.{key} = {value!r}; expected a number of degrees or null"
            )
    window = extrap.get("azimuth_outside_deg")
    if window is not None and not (
        isinstance(window, (list, tuple))
        and len(window) == 2
        and all(isinstance(v, (int, float)) for v in window)
        and window[0] <= window[1]
    ):
        raise ConfigError(
            f"split spec extrapolation.azimuth_outside_deg = {window!r}; expected null or [min, max] degrees"
        )
    bands = (spec.get("interpolation") or {}).get("elevation_bands_deg") or []
    if not all(isinstance(b, (list, tuple)) and len(b) == 2 and b[0] < b[1] for b in bands):
        raise ConfigError(
            f"split spec interpolation.elevation_bands_deg = {bands!r}; expected a list of [low, high] degrees"
        )
    fraction = (spec.get("interpolation") or {}).get("fraction", 0.0)
    if not isinstance(fraction, (int, float)) or not 0 <= fraction < 1:
        raise ConfigError(f"split spec interpolation.fraction = {fraction!r}; expected a number in [0, 1)")


def assign_splits(azimuth_deg: np.ndarray, elevation_deg: np.ndarray, spec: dict, seed: int) -> np.ndarray:
    """Split label (N,) str, one of SPLITS, for each sun position (azimuth, elevation) in degrees.

    ``spec`` example::

        {"extrapolation": {"elevation_above_deg": 70.0, "elevation_below_deg": None,
                           "azimuth_outside_deg": None},
         "interpolation": {"fraction": 0.1}}

    A position is "extrapolation" if any given criterion holds: elevation > elevation_above_deg,
    elevation < elevation_below_deg, or azimuth outside the closed interval azimuth_outside_deg
    ([a, b]; azimuth is compared linearly, without wrap-around). Of the remaining M positions,
    round(fraction * M) (at least 1 if fraction > 0 and M >= 2) are drawn with ``seed`` as
    "interpolation", only among positions strictly inside the remaining azimuth and elevation
    ranges (a coordinate that does not vary, like the azimuth of an elevation scan, constrains
    nothing); the rest are "train". ``interpolation.elevation_bands_deg`` ([[low, high], ...])
    additionally holds out every remaining position whose elevation lies in a band: contiguous
    gaps inside the training range, which test interpolation across more than one sample step.
    Raises ConfigError for an invalid spec, too few interior positions for the requested fraction,
    or no train position left.
    """
    azimuth = np.asarray(azimuth_deg, dtype=np.float64)
    elevation = np.asarray(elevation_deg, dtype=np.float64)
    if azimuth.ndim != 1 or azimuth.shape != elevation.shape:
        raise ValueError(f"azimuth {azimuth.shape} and elevation {elevation.shape} must both be (N,)")
    _check_spec(spec)
    extrap = spec.get("extrapolation") or {}
    fraction = (spec.get("interpolation") or {}).get("fraction", 0.0)

    outside = np.zeros(azimuth.shape, dtype=bool)
    if extrap.get("elevation_above_deg") is not None:
        outside |= elevation > extrap["elevation_above_deg"]
    if extrap.get("elevation_below_deg") is not None:
        outside |= elevation < extrap["elevation_below_deg"]
    if extrap.get("azimuth_outside_deg") is not None:
        low, high = extrap["azimuth_outside_deg"]
        outside |= (azimuth < low) | (azimuth > high)

    labels = np.full(azimuth.shape, "train", dtype=f"<U{max(map(len, SPLITS))}")
    labels[outside] = "extrapolation"
    rest = np.flatnonzero(~outside)
    if rest.size == 0:
        raise ConfigError(
            f"all {azimuth.size} sun positions are extrapolation under split spec {extrap}; "
            "no training position left (loosen the extrapolation criteria)"
        )

    bands = (spec.get("interpolation") or {}).get("elevation_bands_deg") or []
    in_band = np.zeros(rest.size, dtype=bool)
    for low, high in bands:
        in_band |= (elevation[rest] >= low) & (elevation[rest] <= high)
    if in_band.any():
        if in_band[np.argmin(elevation[rest])] or in_band[np.argmax(elevation[rest])]:
            raise ConfigError(
                f"interpolation.elevation_bands_deg = {bands}: a band holds the lowest or highest training "
                "elevation, so it is not inside the training range"
            )
        labels[rest[in_band]] = "interpolation"
        rest = rest[~in_band]
    n_interp = int(np.floor(fraction * rest.size + 0.5))
    if fraction > 0 and rest.size >= 2:
        n_interp = max(n_interp, 1)
    if n_interp:
        az, el = azimuth[rest], elevation[rest]
        interior = rest[_strictly_inside(az) & _strictly_inside(el)]
        if interior.size < n_interp:
            raise ConfigError(
                f"interpolation.fraction = {fraction} asks for {n_interp} of {rest.size} non-extrapolation "
                f"positions, but only {interior.size} lie strictly inside their azimuth/elevation range; "
                "lower the fraction or add calibration images"
            )
        # The extreme positions are never drawn, so train keeps the full range.
        labels[np.random.default_rng(seed).choice(interior, size=n_interp, replace=False)] = "interpolation"
    return labels


def _strictly_inside(values: np.ndarray) -> np.ndarray:
    """(N,) bool: value strictly between the min and max; all True when the values do not vary."""
    if values.min() == values.max():
        return np.ones(values.shape, dtype=bool)
    return (values > values.min()) & (values < values.max())


def evenly(items: list, n: int) -> list:
    """Up to n of `items`, evenly across the list (the first and the last among them): the
    heliostats a plant fit takes (workflow.plant_shared_spec, diagnosis.shared)."""
    if len(items) <= n:
        return list(items)
    return [items[round(i * (len(items) - 1) / (n - 1))] for i in range(n)] if n > 1 else [items[0]]
