"""The plant table: one row per calibrated heliostat of a plant entry (config `datasets.<name>.heliostats`).

Columns of results/<experiment>/plant/heliostats.csv:

- plant, heliostat, dataset: the plant entry, the PAINT folder and its generated dataset;
- east_m, north_m: the heliostat's pivot (ENU, m; the tower at the origin), from its dataset;
- images: calibration images of the dataset;
- heldout_error_ideal, heldout_error_calibrated: the diagnosis' held-out error (misplaced flux
  fraction, diagnosis.json `heldout_error`) of the configured model, and of the model with the
  changes the diagnosis named (`remaining.error`);
- named_effects: those changes' registry effects, ';'-separated;
- pointing_error_mrad, pointing_error_sigma_mrad: RMS over the dataset's sun positions of the
  angle between the mirror normal of the fitted kinematics (the physics model's `tracking`) and
  of the ideal one, and its standard deviation over draws of the tracking parameters from the fit's
  covariance (models/uncertainty.py; empty where the fit has none);
- canting_rms_mrad, surface_rms_mm: RMS of the fitted facet tilts (without their mean) and of the
  fitted surface heights (without each facet's plane), as the heliostat takes them
  (physics.scene.effective_tensors; empty where the model fits none), each with its sigma
  (canting_rms_sigma_mrad, surface_rms_sigma_mm: the standard deviation of the RMS over draws of the
  entries from the fit's covariance; empty where the fit has none);
- flags: ';'-separated: `pointing > <limit> mrad` (config plant.pointing_limit_mrad),
  `tracking not determined`, `canting not determined`, `surface not determined` (entries the fit
  cannot pin down, models/uncertainty.py), `residual <k> x noise` (what the diagnosis could not explain),
  `own widening unnamed (...)` (`unnamed_widening`: its diagnosis named nothing but its kinematics,
  while its own value of a shared width in the plant fit lies beyond WIDENED of its sigma above the
  plant's lower envelope: a widening of its own, a canting or slope error, that the shared level may
  have taken). `pointing`, `residual` and `own widening` say the heliostat is off (`is_off`); "not
  determined" says how sure the fit is.
"""

from __future__ import annotations

import csv
import io
import json
import os
from typing import Any

import numpy as np
import torch

from helioflow.data.hdf5 import read_dataset
from helioflow.errors import DataError
from helioflow.io import write_text_atomic
from helioflow.models.registry import load_fitted_model
from helioflow.physics.effects import TENSOR_EFFECTS
from helioflow.physics.heliostat import Heliostat
from helioflow.physics.scene import effective_tensors
from helioflow.scoring.recovery import pointing_angles_mrad, surface_heights

COLUMNS = ("plant", "heliostat", "dataset", "east_m", "north_m", "images", "heldout_error_ideal",
           "heldout_error_calibrated", "named_effects", "pointing_error_mrad", "pointing_error_sigma_mrad",
           "canting_rms_mrad", "canting_rms_sigma_mrad", "surface_rms_mm", "surface_rms_sigma_mm", "flags")
DRAWS = 512  # tracking draws from the covariance for the pointing error's sigma
OFF = ("pointing >", "residual ", "own widening")  # the flags (heliostat_row) that say a heliostat is off, not how sure
#                                                  its fit is
WIDENED = 2.0  # sigma of its own value above the plant's lower envelope: a heliostat's own widening (unnamed_widening)


def is_off(flags: str) -> bool:
    """Whether a plant table row's flags say the heliostat is off: its pointing beyond the limit, or
    a residual its diagnosis could not explain (not: an entry its fit does not determine)."""
    return any(flag.startswith(OFF) for flag in flags.split(";"))


def pointing_error(heliostat: Heliostat, tracking_mrad: torch.Tensor, covariance: np.ndarray | None,
                   azimuth_deg, elevation_deg, aim_m, seed: int = 0) -> tuple[float, float | None]:
    """(RMS pointing error (mrad) of the fitted kinematics against the ideal over the sun positions,
    its standard deviation over DRAWS draws of the tracking parameters from `covariance` ((5, 5)
    mrad^2; None: no sigma))."""
    rms = float(pointing_angles_mrad(heliostat, tracking_mrad, azimuth_deg, elevation_deg, aim_m)
                .pow(2).mean().sqrt())
    if covariance is None:
        return rms, None
    rng = np.random.default_rng(seed)
    draws = rng.multivariate_normal(np.asarray(tracking_mrad, dtype=np.float64), covariance, DRAWS,
                                    check_valid="ignore")
    spread = pointing_angles_mrad(heliostat, torch.as_tensor(draws), azimuth_deg, elevation_deg, aim_m)
    return rms, float(spread.pow(2).mean(-1).sqrt().std())


def tensor_rms(effective: torch.Tensor, key: str, uncertainty, seed: int = 0, heights: bool = False
               ) -> tuple[float, float | None, bool]:
    """(RMS of a fitted tensor as the heliostat takes it (`effective`: canting (F, 2) mrad, or surface
    control heights (F, C, C) mm, `heights`: of the surface they span, scoring.recovery.surface_heights),
    its standard deviation over DRAWS draws of the tensor's entries from the fit's covariance (None
    where it has none of them), whether any entry is not determined)."""
    def rms(t: torch.Tensor) -> torch.Tensor:  # over the tensor's own dimensions, leading ones kept
        return (surface_heights(t) if heights else t).pow(2).flatten(-effective.dim()).mean(-1).sqrt()

    value = float(rms(effective))
    prefix = f"{key}.{TENSOR_EFFECTS[key].key}["
    at = [k for k, n in enumerate(uncertainty.names) if n.startswith(prefix)] if uncertainty is not None else []
    if not at:
        return value, None, False
    flat = [int(np.ravel_multi_index(tuple(int(i) for i in uncertainty.names[k][len(prefix):-1].split(",")),
                                     effective.shape)) for k in at]
    rng = np.random.default_rng(seed)
    draws = rng.multivariate_normal(uncertainty.values[at], uncertainty.covariance[np.ix_(at, at)], DRAWS,
                                    check_valid="ignore")
    tensors = effective.reshape(1, -1).repeat(DRAWS, 1).double()
    tensors[:, flat] = torch.as_tensor(draws)
    spread = float(rms(tensors.reshape(DRAWS, *effective.shape)).std())
    return value, spread, any(uncertainty.names[k] in uncertainty.undetermined for k in at)


def unnamed_widening(heliostat: str, named: list[str], shared: dict | None) -> str | None:
    """The flag `own widening unnamed (...)` (module docstring) of a heliostat whose diagnosis `named`
    only its kinematics (or nothing), from its plant's entry of plant/shared.json (`shared`; None: no
    plant fit): the first shared width whose value this heliostat alone (diagnosis.shared, its fit
    with the width free) lies beyond WIDENED of its sigma above the plant's level, the lower envelope of
    all heliostats' values; None when none does, or the heliostat was not among those the plant fit took."""
    if shared is None or set(named) - {"tracking"}:
        return None
    for effect in shared.get("shared", []):
        for name, value in effect.get("values", {}).items():
            alone = value.get("alone", {}).get(heliostat)
            if alone is None or not alone["sigma"] > 0:
                continue  # not among the heliostats the plant fit took
            z = (alone["value"] - value["value"]) / alone["sigma"]
            if z > WIDENED:
                return (f"own widening unnamed ({name} {alone['value']:.4g} +- {alone['sigma']:.2g} alone, "
                        f"{z:.1f} sigma above the plant's envelope {value['value']:.4g})")
    return None


def heliostat_row(plant: str, heliostat: str, dataset: str, dataset_path: str | os.PathLike,
                  model_path: str | os.PathLike, diagnosis_path: str | os.PathLike, pointing_limit_mrad: float,
                  shared: dict | None = None) -> dict:
    """One row of the plant table (module docstring) from a heliostat's dataset, physics model and
    diagnosis, and its plant's entry of plant/shared.json (`shared`; None: no plant fit)."""
    ds = read_dataset(dataset_path)
    model, geometry, _ = load_fitted_model(model_path, "the plant table")
    fitted = model.fitted
    try:
        with open(diagnosis_path) as f:
            diagnosis = json.load(f)
    except (OSError, ValueError) as exc:
        raise DataError(f"{diagnosis_path}: cannot read the diagnosis: {exc}") from None
    tensors = {k: v.detach().cpu().double() for k, v in fitted.tensors.items()}
    u = fitted.uncertainty
    flags = []
    pivot = ds.attrs.get("heliostat_position_m") or ["", ""]
    row: dict[str, Any]
    row = {"plant": plant, "heliostat": heliostat, "dataset": dataset,
           "east_m": pivot[0] if pivot[0] == "" else round(float(pivot[0]), 2),
           "north_m": pivot[1] if pivot[1] == "" else round(float(pivot[1]), 2),
           "images": len(ds.images), "heldout_error_ideal": round(float(diagnosis["heldout_error"]), 5),
           "heldout_error_calibrated": round(float(diagnosis["remaining"]["error"]), 5),
           "named_effects": ";".join(dict.fromkeys(c.split(":")[0] for c in diagnosis["remaining"]["changes"])),
           **dict.fromkeys(COLUMNS[COLUMNS.index("pointing_error_mrad"):-1], "")}
    if "tracking" in tensors:
        at = [k for k, n in enumerate(u.names) if n.startswith("tracking.")] if u is not None else []
        covariance = u.covariance[np.ix_(at, at)] if u is not None and len(at) == 5 else None
        rms, sigma = pointing_error(geometry, tensors["tracking"].reshape(5), covariance, ds.azimuth_deg,
                                    ds.elevation_deg, ds.attrs["target_center_m"])
        row["pointing_error_mrad"] = round(rms, 4)
        row["pointing_error_sigma_mrad"] = "" if sigma is None else round(sigma, 4)
        if rms > pointing_limit_mrad:
            flags.append(f"pointing > {pointing_limit_mrad:g} mrad")
        if u is not None and any(n.startswith("tracking.") for n in u.undetermined):
            flags.append("tracking not determined")
    effective = effective_tensors(tensors)
    for key, column, digits in (("canting", "canting_rms", 4), ("surface", "surface_rms", 5)):
        if key in effective:
            value, sigma, undetermined = tensor_rms(effective[key], key, u, heights=key == "surface")
            unit = "mrad" if key == "canting" else "mm"
            row[f"{column}_{unit}"] = round(value, digits)
            row[f"{column}_sigma_{unit}"] = "" if sigma is None else round(sigma, digits)
            if undetermined:
                flags.append(f"{key} not determined")
    if not diagnosis["remaining"]["explained"]:  # the diagnosis' own verdict against its noise floor
        flags.append(f"residual {float(diagnosis['remaining']['over_noise']):.1f} x noise")
    widened = unnamed_widening(heliostat, row["named_effects"].split(";") if row["named_effects"] else [], shared)
    if widened:
        flags.append(widened)
    row["flags"] = ";".join(flags)
    return row


def write_plant_table(spec: dict, output_csv: str | os.PathLike) -> list[dict]:
    """The plant table of `spec` ({"pointing_limit_mrad": float, "heliostats": [{plant, heliostat, dataset,
    and the paths dataset_path, model_path, diagnosis_path, shared_path (plant/shared.json; "" without a
    plant fit)}]}) written to `output_csv`; returns its rows (its plan figure: scoring.plant_figure)."""
    fits: dict[str, dict] = {}
    for path in {h.get("shared_path") for h in spec["heliostats"]} - {None, ""}:
        try:
            with open(path) as f:
                fits[path] = json.load(f)
        except (OSError, ValueError) as exc:
            raise DataError(f"{path}: cannot read the plant fit: {exc}") from None
    rows = [heliostat_row(h["plant"], h["heliostat"], h["dataset"], h["dataset_path"], h["model_path"],
                          h["diagnosis_path"], spec["pointing_limit_mrad"],
                          fits[h["shared_path"]].get(h["plant"]) if h.get("shared_path") else None)
            for h in spec["heliostats"]]
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(output_csv, text.getvalue())
    return rows
