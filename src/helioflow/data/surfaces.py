"""Heliostat geometry files: the true geometry of each configured heliostat (rule `surfaces`).

Layout (schema ``helioflow.heliostat/1``), all in the heliostat frame (right, up, normal at rest):

    position_m                (3,)      ENU position of the mirror centre / pivot, m
    facets/translation_m      (F, 3)    facet centres, m
    facets/size_m             (F, 2)    facet width, height, m
    facets/normal             (F, 3)    ideal canted unit normals
    facets/canting_error_mrad (F, 2)    tilt errors about facet right and up, mrad
    surface/control_heights_mm (F, C, C) B-spline control-point heights, mm (rows top first)
    tracking_error_mrad       (5,)      in the order of attribute `tracking_parameters`
    attributes: mount, facet_focal_length_m (NaN = flat), tracking_parameters, spec (the config),
                source (provenance of an imported heliostat, e.g. PAINT; {} for a configured one)
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, replace

import numpy as np
import torch

from helioflow.data.hdf5 import read_arrays, write_arrays
from helioflow.errors import DataError
from helioflow.physics.heliostat import TRACKING_PARAMETERS, Heliostat, ideal_heliostat, without_planes
from helioflow.schema import with_defaults

SCHEMA = "helioflow.heliostat/1"


@dataclass(frozen=True)
class HeliostatSpec:
    """A heliostat section of config: ideal geometry plus the scale and seed of its errors."""

    name: str
    position_m: tuple[float, float, float]
    mount: str
    rows: int
    cols: int
    width_m: float
    height_m: float
    gap_m: float
    canting_focal_distance_m: float | None
    facet_focal_length_m: float | None
    control_points: int
    deformation_mm: float
    tracking_error_mrad: float
    canting_error_mrad: float
    seed: int

    @staticmethod
    def from_config(name: str, d: dict) -> HeliostatSpec:
        """The spec of heliostat `name` from its config entry `d`, the optional keys the schema's defaults
        where `d` lacks them (an images dataset's inline ideal heliostat, a spec written by hand)."""
        d = with_defaults(d, "heliostats", name)
        f = d["facets"]
        return HeliostatSpec(
            name, tuple(d["position_m"]), d["mount"], f["rows"], f["cols"], f["width_m"], f["height_m"],
            f["gap_m"], d["canting_focal_distance_m"], d["facet_focal_length_m"], d["control_points"],
            d["deformation_mm"], d["tracking_error_mrad"], d["canting_error_mrad"], d["seed"],
        )

    def ideal(self) -> Heliostat:
        """The heliostat's ideal (design) geometry, without errors (float64)."""
        return ideal_heliostat(self.rows, self.cols, self.width_m, self.height_m, self.gap_m, self.position_m,
                               self.mount, self.canting_focal_distance_m, self.facet_focal_length_m,
                               self.control_points)


def true_heliostat(spec: HeliostatSpec) -> Heliostat:
    """Ideal geometry from the spec plus its seeded random errors (float64).

    Control-point heights ~ N(0, deformation_mm), each tracking parameter ~ N(0,
    tracking_error_mrad), each facet tilt ~ N(0, canting_error_mrad); one generator seeded by
    spec.seed draws them in that order. The effects are kept apart as the fits define them: each
    facet's deformation has its plane removed (a facet tilt is canting), and the facet tilts of a
    heliostat with several facets have zero mean (a common tilt is a tracking error).
    """
    ideal = spec.ideal()
    n_facets, c = ideal.n_facets, spec.control_points
    rng = np.random.default_rng(spec.seed)
    heights = rng.normal(0.0, spec.deformation_mm * 1e-3, (n_facets, c, c))
    tracking = rng.normal(0.0, spec.tracking_error_mrad * 1e-3, len(TRACKING_PARAMETERS))
    canting = rng.normal(0.0, spec.canting_error_mrad * 1e-3, (n_facets, 2))
    if n_facets > 1:
        canting = canting - canting.mean(axis=0)
    def t(a):
        return torch.as_tensor(a, dtype=torch.float64)

    return replace(ideal, control_heights=without_planes(t(heights)), canting_error=t(canting),
                   tracking_error=t(tracking))


def write_heliostat(path: str | os.PathLike, heliostat: Heliostat, spec: HeliostatSpec | None = None,
                    source: dict | None = None) -> None:
    """Write a heliostat's geometry atomically (see the module docstring for the layout).

    spec: the config section it was made from; source: JSON-able provenance of an imported one.
    """
    h = heliostat
    arrays = {
        "position_m": h.position,
        "facets/translation_m": h.facet_translation,
        "facets/size_m": h.facet_size,
        "facets/normal": h.facet_normal,
        "facets/canting_error_mrad": h.canting_error * 1e3,
        "surface/control_heights_mm": h.control_heights * 1e3,
        "tracking_error_mrad": h.tracking_error * 1e3,
    }
    attrs = {
        "mount": h.mount,
        "facet_focal_length_m": float("nan") if h.facet_focal_length is None else float(h.facet_focal_length),
        "tracking_parameters": list(TRACKING_PARAMETERS),
        "spec": asdict(spec) if spec is not None else {},
        "source": source or {},
    }
    write_arrays(path, {k: v.detach().cpu().numpy().astype(np.float64) for k, v in arrays.items()}, attrs, SCHEMA)


def read_heliostat(path: str | os.PathLike) -> Heliostat:
    """Read a heliostat geometry file (float64 tensors); DataError names the file and missing key."""
    required = ("position_m", "facets/translation_m", "facets/size_m", "facets/normal", "facets/canting_error_mrad",
                "surface/control_heights_mm", "tracking_error_mrad")
    arrays, attrs = read_arrays(path, SCHEMA, required)
    for key in ("mount", "facet_focal_length_m"):
        if key not in attrs:
            raise DataError(f"{path}: attribute {key!r} is missing; expected a heliostat geometry file from `surfaces`")
    def t(k, scale=1.0):
        return torch.as_tensor(arrays[k] * scale, dtype=torch.float64)

    focal = attrs["facet_focal_length_m"]
    return Heliostat(
        position=t("position_m"),
        mount=attrs["mount"],
        facet_translation=t("facets/translation_m"),
        facet_size=t("facets/size_m"),
        facet_normal=t("facets/normal"),
        facet_focal_length=None if np.isnan(focal) else float(focal),
        control_heights=t("surface/control_heights_mm", 1e-3),
        canting_error=t("facets/canting_error_mrad", 1e-3),
        tracking_error=t("tracking_error_mrad", 1e-3),
    )
